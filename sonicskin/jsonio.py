"""Plain JSON data from what the package computes: the one conversion every report, summary and artifact uses."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["json_safe", "OMIT"]

#: Returned by a ``convert`` hook: leave this dict entry or list element out.
OMIT = object()


def json_safe(obj: Any, *, keep_nonfinite: bool = False, convert: Callable[[Any], Any] | None = None) -> Any:
    """``obj`` as plain, strict JSON data (NaN and inf as ``None`` unless ``keep_nonfinite``; ``convert`` first)."""
    if convert is not None:
        new = convert(obj)
        if new is not obj:
            return OMIT if new is OMIT else json_safe(new, keep_nonfinite=keep_nonfinite, convert=convert)

    def sub(v):
        return json_safe(v, keep_nonfinite=keep_nonfinite, convert=convert)

    if isinstance(obj, dict):
        return {str(k): w for k, w in ((k, sub(v)) for k, v in obj.items()) if w is not OMIT}
    if isinstance(obj, np.ndarray):
        return sub(obj.tolist())
    if isinstance(obj, (list, tuple)):
        return [w for w in map(sub, obj) if w is not OMIT]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if keep_nonfinite or math.isfinite(obj) else None
    return obj
