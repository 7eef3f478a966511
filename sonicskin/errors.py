"""The package's user-error types.

Every error a user can cause by what they pass in (a file that is not a dataset, an artifact for
another rig, a value out of range) derives from :class:`SonicskinError`.  ``sonicskin <verb>``
prints such an error as one line, ``sonicskin <verb>: error: <message>``, and exits with code 2;
anything else is a bug and keeps its traceback.  :class:`SonicskinError` is a ``ValueError``, so
code that caught ``ValueError`` before keeps working.
"""

from __future__ import annotations

__all__ = ["SonicskinError", "UsageError"]


class SonicskinError(ValueError):
    """Bad input from the user; the message names the problem and the fix."""


class UsageError(SonicskinError):
    """A combination of command-line options that cannot work (checked before anything runs)."""
