"""Resource bounds checked before allocating: a size option or a file that asks for more memory than
the machine has is refused with one line, instead of a MemoryError, a swap storm or a hang.

:func:`check_memory` compares an estimate of the bytes a step will hold at once with the memory
available now (``MemAvailable`` on Linux, physical memory elsewhere), less a margin.
"""

from __future__ import annotations

import os

from .errors import SonicskinError

__all__ = ["ResourceError", "available_bytes", "check_memory", "human_bytes"]

#: Fraction of the available memory one step may plan to use.
BUDGET = 0.8


class ResourceError(SonicskinError):
    """A request larger than this machine can hold; the message gives the estimate and the fix."""


def available_bytes() -> int:
    """Memory available to this process now, in bytes."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


def human_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB", "EB"):
        if abs(n) < 1000 or unit == "EB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} EB"  # pragma: no cover


def check_memory(nbytes: float, what: str, fix: str) -> None:
    """Raise :class:`ResourceError` when ``nbytes`` (an estimate) exceeds the memory budget."""
    avail = available_bytes()
    if not nbytes <= BUDGET * avail:  # also refuses NaN / inf estimates
        raise ResourceError(f"{what} would need about {human_bytes(nbytes)} of memory, more than this machine has "
                            f"available ({human_bytes(avail)}); {fix}")
