"""Torch networks over the OSPA-selected bins."""

from .kernel import KernelVotes
from .lda import LDASkinNet
from .net import SkinNet

__all__ = ["KernelVotes", "LDASkinNet", "SkinNet"]
