"""Optimal Spectrum Prorating Algorithm (OSPA, paper Alg. 1) as a scikit-learn selector."""

from __future__ import annotations

import numbers

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.feature_selection import SelectorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from .features import light_touches, quiet_mask, touch_mask, usable_bins

__all__ = ["OSPA", "select_bins"]


class OSPA(SelectorMixin, BaseEstimator):
    """Keep the ``gamma`` spectral bins most sensitive to touch and least sensitive to motion (paper Alg. 1): ``VC =
    MV / TV`` (Eq. 3, 4, ``vc_``, ``inf`` on disallowed bins); ``selected_`` holds the bins of smallest ``VC``, best first."""

    def __init__(self, gamma: int = 300, allowed: np.ndarray | None = None):
        self.gamma = gamma
        self.allowed = allowed

    def fit(self, X, y=None, X_moving=None):
        X = validate_data(self, X, dtype=np.float64, ensure_min_samples=2)
        n_features = X.shape[1]
        if not isinstance(self.gamma, numbers.Integral) or self.gamma < 1:
            raise ValueError(f"gamma must be a positive integer number of bins, got {self.gamma!r}")
        allowed = np.ones(n_features, dtype=bool) if self.allowed is None else np.asarray(self.allowed, dtype=bool)
        if allowed.shape != (n_features,):
            raise ValueError(
                f"allowed mask has shape {allowed.shape} but X has {n_features} features; "
                f"build it for the same bins (rig.allowed_mask covers rig.band_bins)"
            )
        n_allowed = int(allowed.sum())
        if self.gamma > n_allowed:
            raise ValueError(
                f"gamma={self.gamma} is larger than the {n_allowed} bins left after the matched filter "
                f"(n_features = {n_features}); lower gamma or narrow the dropped PWM bands"
            )
        tv = X.var(axis=0)
        if X_moving is None:
            mv = np.ones(n_features)
        else:
            Xm = np.asarray(X_moving, dtype=np.float64)
            if Xm.ndim != 2 or Xm.shape[1] != n_features:
                raise ValueError(f"X_moving must be (n_chirps, {n_features}), got shape {Xm.shape}")
            if Xm.shape[0] < 2:
                raise ValueError("X_moving needs at least 2 chirps to estimate the moving variance")
            if not np.isfinite(Xm).all():
                raise ValueError("X_moving contains NaN or inf")
            mv = Xm.var(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            vc = np.where(tv > 0, mv / np.where(tv > 0, tv, 1.0), np.inf)
        vc = np.where(allowed, vc, np.inf)
        order = np.argsort(vc, kind="stable")
        self.tv_, self.mv_, self.vc_ = tv, mv, vc
        self.selected_ = order[: self.gamma]
        return self

    def _get_support_mask(self):
        check_is_fitted(self, "selected_")
        mask = np.zeros(self.n_features_in_, dtype=bool)
        mask[self.selected_] = True
        return mask

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = False
        return tags


def select_bins(t, rig, n_bins: int | None = None, min_force_n: float = 0.5, *, log=None) -> np.ndarray:
    """OSPA (Alg. 1) on a training table: touch chirps vs moving no-touch chirps (quiet ones when the robot never
    moved; none: the largest touch variance), over the rig's matched-filter mask; band-bin indices, best first
    (``n_bins`` clamped, :func:`usable_bins`)."""
    touch = touch_mask(t, min_force_n)
    moving = (t["location"] < 0) & (t["moving"] > 0)
    ref = moving if moving.sum() >= 2 else quiet_mask(t)
    if touch.sum() < 2:
        why = light_touches(t["force_n"], t["location"] >= 0, min_force_n)
        raise ValueError(f"OSPA needs touch chirps in the training split; got {int(touch.sum())}" + (f" ({why})" if why else ""))
    gamma = usable_bins(rig, n_bins, log=log)
    X_ref = t.X[ref] if ref.sum() >= 2 else None
    return OSPA(gamma=gamma, allowed=rig.allowed_mask).fit(t.X[touch], X_moving=X_ref).selected_
