"""sonicskin: a robot link as a touch sensor with one pair of piezo discs (SonicSkin, Fan et al.).

The runtime is torch-free; training and export live in the top-level ``training``, ``models`` and ``export``
packages (``pip install sonicskin[train]``)."""

__version__ = "0.1.0"

from .api import Listener, listen  # noqa: E402
from .events import TouchEvent  # noqa: E402
from .rig import Layout, Rig  # noqa: E402

__all__ = ["Rig", "Layout", "listen", "Listener", "TouchEvent", "__version__"]
