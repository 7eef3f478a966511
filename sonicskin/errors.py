"""The package's user-error types, and the checks of user values every reader makes.  Every error a user can cause
derives from :class:`SonicskinError` (a ``ValueError``; subclasses keep the built-in type they replaced)."""

from __future__ import annotations

import math
import os
import reprlib

__all__ = ["SonicskinError", "UsageError", "ConfigNotFoundError", "ArtifactError", "ResourceError", "brief", "is_number",
           "check_memory", "available_bytes", "human_bytes"]

_REPR = reprlib.Repr()
_REPR.maxlevel = 2
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = _REPR.maxfrozenset = _REPR.maxdeque = _REPR.maxarray = 4
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = 60


def is_number(v, *, integer: bool = False, finite: bool = True) -> bool:
    """A number given as one, never a bool: an ``int`` with ``integer``, else an int or a float, finite unless ``finite=False``."""
    if isinstance(v, bool) or not isinstance(v, int if integer else (int, float)):
        return False
    return not finite or isinstance(v, int) or math.isfinite(v)


def brief(value, limit: int = 100) -> str:
    """``repr(value)`` for an error message, bounded: never materialised whole (a YAML alias bomb, a 4 MB string)."""
    s = _REPR.repr(value)
    return s if len(s) <= limit else s[:limit - 3] + "..."


class SonicskinError(ValueError):
    """Bad input from the user; the message names the problem and the fix."""


class UsageError(SonicskinError):
    """A combination of command-line options that cannot work (checked before anything runs)."""


class ConfigNotFoundError(SonicskinError, FileNotFoundError):
    """A rig, scenario or links config name (or YAML path) that names no config; the message lists the known names."""


class ArtifactError(SonicskinError):
    """An artifact that cannot run here; the message names the field, what does not fit and what to do."""


# -- resource bounds checked before allocating: a size option or a file that asks for more memory than the machine
# has (MemAvailable on Linux, physical memory elsewhere) is refused in one line, not a MemoryError or a swap storm
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
