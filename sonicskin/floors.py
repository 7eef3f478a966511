"""The plain scikit-learn floors every accuracy claim is printed beside (a result below them is not a result).

Fitted on the training sessions' touch chirps, scored on every test touch chirp, default parameters: ``svc``
(``StandardScaler + SVC()``) and ``lda`` (``LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto")``) on every
usable bin, ``normalized_svc`` (``Normalizer + StandardScaler + SVC(C=10)``) on OSPA's 300 bins; force: a pooled
``StandardScaler + SVR()`` and the training mean.  Inputs: dB minus each session's boot reference.
"""

from __future__ import annotations

import time

import numpy as np

from .features import FeatureSpec, touch_mask
from .ospa import select_bins

__all__ = ["plain_floors", "FLOOR_NAMES"]

#: floor key -> how reports name it
FLOOR_NAMES = {"svc": "SVC floor (all bins)", "lda": "shrinkage LDA floor (all bins)",
               "normalized_svc": "normalized SVC floor (OSPA 300)", "svr": "pooled SVR floor", "mean": "training-mean floor"}


def boot_relative(t, rig) -> np.ndarray:
    """Every usable bin of every chirp minus its session's boot reference (the first ``beta`` chirps)."""
    beta = FeatureSpec((0,), "relative").reference(rig.chirps_per_s).beta
    X = t.X[:, rig.allowed_mask].astype(np.float64)
    for s in np.unique(t["session"]):
        idx = np.flatnonzero(t["session"] == s)
        X[idx] -= X[idx[:beta]].mean(axis=0)
    return X


def plain_floors(t, rig, *, train, test, min_force_n: float = 0.5) -> dict:
    """The floors on the feature table ``t`` (sessions ``train`` fit, ``test`` score); keys ``<floor>_accuracy`` and
    ``svr_force_rmse_n``/``mean_force_rmse_n`` (absent without a force sensor)."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import Normalizer, StandardScaler
    from sklearn.svm import SVC, SVR

    X = boot_relative(t, rig)
    touch = touch_mask(t, min_force_n)
    tr = touch & np.isin(t["session"], list(train))
    te = touch & np.isin(t["session"], list(test))
    loc, f = t["location"], t["force_n"]
    t0 = time.perf_counter()
    allowed = np.flatnonzero(rig.allowed_mask)
    pos = np.full(rig.n_band, -1)
    pos[allowed] = np.arange(allowed.size)
    ospa = pos[select_bins(t.select(np.isin(t["session"], list(train))), rig, min(300, allowed.size), min_force_n)]
    models = {"svc": (make_pipeline(StandardScaler(), SVC()), slice(None)),
              "lda": (LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto"), slice(None)),
              "normalized_svc": (make_pipeline(Normalizer(), StandardScaler(), SVC(C=10)), ospa)}
    out = {}
    for name, (model, cols) in models.items():
        model.fit(X[tr][:, cols], loc[tr])
        out[f"{name}_accuracy"] = float(np.mean(model.predict(X[te][:, cols]) == loc[te]))
    a, b = tr & np.isfinite(f), te & np.isfinite(f)
    if a.sum() >= 8 and b.any() and np.ptp(f[a]) > 0:
        svr = make_pipeline(StandardScaler(), SVR()).fit(X[a], f[a])
        out["svr_force_rmse_n"] = float(np.sqrt(np.mean((np.clip(svr.predict(X[b]), 0, None) - f[b]) ** 2)))
        out["mean_force_rmse_n"] = float(np.sqrt(np.mean((f[a].mean() - f[b]) ** 2)))
    return {**out, "n_bins": int(X.shape[1]), "n_train_touch": int(tr.sum()), "n_test_touch": int(te.sum()),
            "fit_s": time.perf_counter() - t0}
