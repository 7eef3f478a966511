"""The confidence interval every report quotes (selection's estimates, seeds' paired differences, benchmarks)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["t_interval"]


def t_interval(x, bounds: tuple[float, float] = (-math.inf, math.inf), *, level: float = 0.95) -> list[float]:
    """The Student-t interval of the mean of ``x`` at ``level`` (``[lo, hi]``), cut to the ``bounds`` the quantity
    cannot leave (an accuracy stays in [0, 1]); ``[nan, nan]`` below two values."""
    from scipy import stats

    x = np.asarray(x, float).ravel()
    if x.size < 2:
        return [math.nan, math.nan]
    half = stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    return [float(np.clip(v, *bounds)) for v in (x.mean() - half, x.mean() + half)]
