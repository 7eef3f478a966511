"""The SVM baseline on model inputs (selected bins), with its detector and per-location force.

This is :class:`sonicskin.skin.SkinSVM` with the OSPA step factored out, so the SVM and the
network see exactly the same inputs and the SVM exports to a 2-node ONNX graph
(scaler + ``SVC(decision_function_shape="ovo")``); per-location scores come from
:func:`sonicskin.baseline.ovr_scores_from_ovo` in numpy.
"""

from __future__ import annotations

import numpy as np
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from .baseline import ovr_scores_from_ovo
from .calibration import TouchDetector
from .force import PerLocationForce, PooledForce, energy_db

__all__ = ["DETECTOR_BINS", "fit_svm_head", "ovo_decision", "score_vector", "touch_statistic"]


def ovo_decision(pipe: Pipeline, X: np.ndarray, block: int = 2048) -> np.ndarray:
    """``pipe.decision_function(X)`` of a fitted scaler + RBF ``SVC(decision_function_shape="ovo")``, with the
    kernel matrix from one BLAS product per block of chirps (libsvm's own loop is 10-20x slower on thousands of
    bins).  Equal to scikit-learn's up to float64 rounding (``tests/test_reproduce.py`` checks it)."""
    svc = pipe[-1]
    Z = np.asarray(pipe[:-1].transform(X), np.float64)
    S = np.asarray(svc.support_vectors_, np.float64)
    coef, icpt, nsv = np.asarray(svc.dual_coef_), np.asarray(svc.intercept_), np.asarray(svc.n_support_)
    k = len(nsv)
    start = np.r_[0, np.cumsum(nsv)]
    s2 = np.einsum("ij,ij->i", S, S)
    out = np.empty((len(Z), k * (k - 1) // 2))
    for lo in range(0, len(Z), block):
        z = Z[lo:lo + block]
        d2 = np.einsum("ij,ij->i", z, z)[:, None] + s2[None, :] - 2.0 * (z @ S.T)
        K = np.exp(-svc._gamma * np.maximum(d2, 0.0))
        p = 0
        for i in range(k):
            for j in range(i + 1, k):
                si, sj = slice(start[i], start[i + 1]), slice(start[j], start[j + 1])
                out[lo:lo + block, p] = K[:, si] @ coef[j - 1, si] + K[:, sj] @ coef[i, sj] + icpt[p]
                p += 1
    return out[:, 0] if k == 2 else out  # binary: scikit-learn's public coef and intercept are already sign-flipped


def _pairwise(ovo: np.ndarray, n_locations: int) -> np.ndarray:
    """Pairwise decision values (n, K (K-1) / 2) in libsvm's sign convention, from scikit-learn or skl2onnx."""
    ovo = np.asarray(ovo, np.float64)
    if n_locations == 2:
        d = ovo[:, 0] if ovo.ndim == 2 else ovo  # scikit-learn's d (n,) or skl2onnx's [d, -d]
        return -d[:, None]
    return ovo


def score_vector(ovo: np.ndarray, n_locations: int, inputs: np.ndarray) -> np.ndarray:
    """Per chirp ``[S_1..S_K, inputs]``: what Alg. 2 calibrates, with one reference for both."""
    S = ovr_scores_from_ovo(_pairwise(ovo, n_locations), n_locations)
    return np.column_stack([S, np.asarray(inputs, np.float64)])


#: The input-RMS detector reads the first (best, OSPA order) bins only, at most the paper's 300: with a gamma chosen
#: for localization (up to every usable bin) the extra bins are the motion-sensitive ones, and a statistic over
#: 1,884 bins missed 56 % of a moving random rig's touches where the 300-bin one missed none (design seed 1).
DETECTOR_BINS = 300


def touch_statistic(V_cal: np.ndarray, n_locations: int, n_bins: int | None = None) -> np.ndarray:
    """Touch detection statistic: RMS change (dB) of the model inputs from the no-touch reference.

    The paper thresholds the calibrated per-location score ``max(S - S_c)``.  An RBF SVM trained
    on touches only gives the same decision values (its intercepts) to every input far from its
    training touches, at rest or under an unusually firm press, so a press at the location that
    wins the vote at rest goes unseen (measured: a 12 N press missed for 2 s on a 3-marker rig).
    How far the OSPA bins moved from rest is what a touch does physically; that is thresholded.
    ``n_bins``: over the first ``n_bins`` inputs only (the best bins, see :data:`DETECTOR_BINS`); ``None``: all.
    """
    inputs = V_cal[:, n_locations:] if n_bins is None else V_cal[:, n_locations:n_locations + n_bins]
    return np.sqrt(np.mean(np.square(inputs), axis=1))


def fit_svm_head(X: np.ndarray, cls: np.ndarray, force: np.ndarray, quiet: np.ndarray, *, n_locations: int,
                 location_ids, C: float = 10.0, kernel_gamma="scale", force_model: str = "fourier1",
                 force_alpha: float = 10.0) -> tuple[Pipeline, dict]:
    """Fit scaler + SVC on touch chirps (``cls < n_locations``), then the Alg. 2 reference scores,
    the detection threshold and the force model (per-location curves, or ``"pooled-ridge"`` over the
    inputs and the location, see :class:`sonicskin.force.PooledForce`).  Returns the sklearn pipeline
    and its JSON-able parameters."""
    touch = cls < n_locations
    pipe = Pipeline([("scale", StandardScaler()), ("svc", SVC(kernel="rbf", C=C, gamma=kernel_gamma,
                                                              decision_function_shape="ovo"))])
    pipe.fit(X[touch], cls[touch])
    classes = pipe.classes_
    if len(classes) != n_locations:
        raise ValueError(f"training data touches {len(classes)} of the {n_locations} locations; "
                         f"record every location at least once")
    V = score_vector(ovo_decision(pipe, X), n_locations, X)
    # A table of touches only has no rest: no Alg. 2 reference (zero) and no detector (threshold 0 on a
    # statistic >= 0: every chirp is a touch); "detection": false says so in skin.json.
    rest = quiet.sum() >= 2 and (~touch).any()
    ref = V[quiet].mean(axis=0) if rest else np.zeros(V.shape[1])
    n_det = min(DETECTOR_BINS, X.shape[1])
    stat = touch_statistic(V - ref, n_locations, n_det)[:, None]
    det = TouchDetector().fit(stat[touch], stat[~touch]) if rest else None
    all_bins = np.arange(X.shape[1])
    e_ref = float(energy_db(X[quiet], all_bins).mean()) if rest else 0.0
    E = energy_db(X, all_bins) - e_ref
    ids = np.asarray(location_ids)
    has_f = touch & np.isfinite(force)  # recordings without a force sensor carry NaN forces
    fm = PooledForce(force_alpha) if force_model == PooledForce.NAME else PerLocationForce(force_model)
    if has_f.sum() >= 8 and len(np.unique(cls[has_f])) == n_locations and np.ptp(force[has_f]) > 0:
        if isinstance(fm, PooledForce):
            fm.fit(X[has_f], force[has_f], ids[cls[has_f]])
        else:
            fm.fit(E[has_f], force[has_f], ids[cls[has_f]])
    else:
        fm = PerLocationForce("fourier1")  # no force sensor (or a constant force): force is absent (NaN), never 0 N
        fm.curves_ = {}
    params = {"reference_scores": ref.tolist(), "threshold": det.threshold_ if rest else 0.0, "detector": "input-rms",
              "detector_bins": n_det,
              "detection": bool(rest), "energy_ref_db": e_ref,
              "train_false_touch_rate": det.false_touch_rate_ if rest else None,
              "train_missed_touch_rate": det.missed_touch_rate_ if rest else None,
              "force": fm.to_dict()}
    return pipe, params
