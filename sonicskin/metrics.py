"""Evaluation metrics of the paper's Sec. V (accuracy, confusion, distance CDF, Table I) and the confidence interval every report quotes."""

from __future__ import annotations

import math

import numpy as np
from sklearn.metrics import confusion_matrix

from .rig import Layout

__all__ = ["localization_report", "force_report", "error_cdf", "speed_ratio", "t_interval"]


def error_cdf(err_cm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Empirical CDF of localization errors: sorted errors and cumulative shares."""
    e = np.sort(np.asarray(err_cm, float))
    return e, np.arange(1, e.size + 1) / max(e.size, 1)


def localization_report(y_true: np.ndarray, y_pred: np.ndarray, layout: Layout) -> dict:
    """Accuracy, confusion matrix, and surface-distance errors between predicted and true markers (share < 2 cm and < 3 cm)."""
    y_true, y_pred = np.asarray(y_true), np.asarray(y_pred)
    if y_true.shape != y_pred.shape:
        raise ValueError(f"{y_true.size} true labels but {y_pred.size} predictions")
    err = layout.distance_cm(layout.coords(y_true), layout.coords(y_pred))
    return {
        "n": int(y_true.size),
        "accuracy": float(np.mean(y_true == y_pred)) if y_true.size else float("nan"),
        "within_2cm": float(np.mean(err < 2.0)) if y_true.size else float("nan"),
        "within_3cm": float(np.mean(err < 3.0)) if y_true.size else float("nan"),
        "mean_error_cm": float(np.mean(err)) if y_true.size else float("nan"),
        "confusion": confusion_matrix(y_true, y_pred, labels=list(layout.ids)).tolist(),
        "errors_cm": err,
    }


def force_report(f_true: np.ndarray, f_pred: np.ndarray) -> dict:
    """Table I: RMSE, std of the error and the zero-lag normalised cross-correlation (1: identical traces), on the
    chirps with a measured force (``n``; ``n_unmeasured``: those without, a force sensor logging only part of the time)."""
    g, p = np.asarray(f_true, float), np.asarray(f_pred, float)
    if g.shape != p.shape:
        raise ValueError(f"{g.size} true forces but {p.size} predictions")
    measured = ~np.isnan(g)
    unmeasured = int(g.size - measured.sum())
    g, p = g[measured], p[measured]
    e = p - g
    denom = np.sqrt(np.sum(p * p) * np.sum(g * g))
    return {
        "n": int(g.size),
        "rmse_n": float(np.sqrt(np.mean(e ** 2))),
        "sigma_n": float(np.std(e)),
        "xcorr": float(np.sum(p * g) / denom) if denom > 0 else float("nan"),
        "r2": float(1 - np.sum(e ** 2) / np.sum((g - g.mean()) ** 2)) if g.size > 1 and np.ptp(g) > 0 else float("nan"),
    } | ({"n_unmeasured": unmeasured} if unmeasured else {})


def speed_ratio(t_s: float, t_ref_s: float) -> str:
    """``"2.5x faster"``, ``"1.4x slower"`` or ``"as fast"`` (within 5 %) for ``t_s`` against ``t_ref_s``."""
    r = float(t_ref_s) / float(t_s)
    if abs(r - 1) < 0.05:
        return "as fast"
    return f"{r:.1f}x faster" if r > 1 else f"{1 / r:.1f}x slower"


def t_interval(x, bounds: tuple[float, float] = (-math.inf, math.inf), *, level: float = 0.95) -> list[float]:
    """Student-t interval of the mean of ``x`` at ``level``, cut to ``bounds``; ``[nan, nan]`` below two values."""
    from scipy import stats

    x = np.asarray(x, float).ravel()
    if x.size < 2:
        return [math.nan, math.nan]
    half = stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    return [float(np.clip(v, *bounds)) for v in (x.mean() - half, x.mean() + half)]
