"""Torch networks over the OSPA-selected bins."""

from .kernel import KernelVotes, svm_pipeline
from .net import SkinNet

__all__ = ["KernelVotes", "SkinNet", "svm_pipeline"]
