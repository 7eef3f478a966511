"""Torch networks over the OSPA-selected bins."""

from .net import SkinNet

__all__ = ["SkinNet"]
