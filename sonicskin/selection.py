"""Model selection on the user's own presses: gamma, C, kernel width, force model and detection threshold.

The paper's defaults are chosen here by validation on the *training* data only: on a validation session when there
is one, else by cross-validation over *passes* (the k-th press of every location), else the paper's values with a
warning.  A *press* is a run of touch chirps at one location within one session and segment (:func:`press_ids`)."""

from __future__ import annotations

import math
import textwrap
import warnings

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, TransformerMixin, clone
from sklearn.model_selection import GridSearchCV, PredefinedSplit
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from .features import FeatureSpec, quiet_mask, touch_mask
from .force import PerLocationForce, PooledForce, PooledSVR, energy_db
from .head import DETECTOR_BINS, touch_statistic
from .metrics import t_interval
from .ospa import OSPA
from .plots import pyplot

__all__ = ["PAPER", "press_ids", "press_passes", "gamma_grid", "make_cv", "select_localizer", "select_force",
           "select_threshold", "learning_curve_by_pass", "MovingVarOSPA", "KernelWidth"]

#: the paper's values: the fallback when the data cannot validate anything.
PAPER = {"n_bins": 300, "C": 10.0, "kernel_width": 1.0}
C_GRID = (10.0, 1.0, 100.0)  # the paper's value first: GridSearchCV breaks ties by grid order
WIDTH_GRID = (1.0, 0.3, 3.0)  # RBF gamma = width / n_bins on standardised inputs (1.0 is scikit-learn's "scale")
ALPHA_GRID = (1.0, 10.0, 100.0, 1000.0)
#: The force model when nothing can validate (one session, one press per marker): on the 30 design rigs of the random
#: family trained on one session, a pooled ridge over the SVM's 300 bins with alpha 100 had RMSE 2.7 N against alpha
#: 10's 3.0 N, the per-location Fourier-1's 3.9 N (the paper's), the network's own head's 3.4 N and the pooled SVR
#: floor's 2.9 N (benchmarks/bench_default.py, result default).
UNVALIDATED_FORCE_ALPHA = 100.0
MAX_FOLDS = 5


# -- presses ---------------------------------------------------------------------------------------
def press_ids(location: np.ndarray, session: np.ndarray, segment: np.ndarray | None = None) -> np.ndarray:
    """One id per press (consecutive chirps at one location within one session and segment), from 0; no-touch: -1."""
    loc = np.asarray(location)
    key = [np.asarray(session).astype(str)]
    if segment is not None:
        key.append(np.asarray(segment).astype(str))
    new = np.ones(loc.size, bool)
    if loc.size > 1:
        same = loc[1:] == loc[:-1]
        for k in key:
            same &= k[1:] == k[:-1]
        new[1:] = ~same
    starts = new & (loc >= 0)
    ids = np.cumsum(starts) - 1
    return np.where(loc >= 0, ids, -1)


def press_passes(press: np.ndarray, location: np.ndarray) -> np.ndarray:
    """Pass index per chirp: the k-th press (in time) at a location is in pass k; -1 for no touch."""
    press, location = np.asarray(press), np.asarray(location)
    out = np.full(press.shape, -1)
    for loc in np.unique(location[press >= 0]):
        ps = [p for p in dict.fromkeys(press[(location == loc) & (press >= 0)])]  # in time order
        for k, p in enumerate(ps):
            out[press == p] = k
    return out


def gamma_grid(n_allowed: int, lo: int = 100, n: int = 5) -> list[int]:
    """OSPA bin counts from about ``lo`` to every usable bin (geometric), with the paper's 300."""
    if n_allowed <= lo:
        return [int(n_allowed)]
    g = set(np.round(np.geomspace(lo, n_allowed, n)).astype(int).tolist()) | {int(n_allowed)}
    if PAPER["n_bins"] < n_allowed:
        g.add(PAPER["n_bins"])
    paper = [PAPER["n_bins"]] if PAPER["n_bins"] in g else []
    return paper + sorted(g - set(paper))  # the paper's first: ties go to it


# -- estimators --------------------------------------------------------------------------------------
class MovingVarOSPA(OSPA):
    """:class:`~sonicskin.ospa.OSPA` with ``MV`` given at construction, so a grid search refits it from touch chirps alone."""

    def __init__(self, gamma: int = 300, allowed: np.ndarray | None = None, moving_var: np.ndarray | None = None):
        super().__init__(gamma=gamma, allowed=allowed)
        self.moving_var = moving_var

    def fit(self, X, y=None):
        if self.moving_var is None:
            return super().fit(X, y)
        s = np.sqrt(np.asarray(self.moving_var, np.float64))
        return super().fit(X, y, X_moving=np.stack([s, -s]))  # two rows whose variance is exactly moving_var


class KernelWidth(TransformerMixin, BaseEstimator):
    """Multiply standardised inputs by ``sqrt(factor)``: an RBF SVC with ``gamma="scale"`` then has ``factor / n_features``."""

    def __init__(self, factor: float = 1.0):
        self.factor = factor

    def fit(self, X, y=None):
        self.n_features_in_ = np.asarray(X).shape[1]
        return self

    def transform(self, X):
        return np.asarray(X) * math.sqrt(self.factor)


def localizer_pipeline(*, allowed=None, moving_var=None) -> Pipeline:
    return Pipeline([("ospa", MovingVarOSPA(allowed=allowed, moving_var=moving_var)), ("scale", StandardScaler()),
                     ("width", KernelWidth()), ("svc", SVC(kernel="rbf", decision_function_shape="ovo"))])


class FourierPerLocation(RegressorMixin, BaseEstimator):
    """The paper's per-location Fourier-1 on column 0 (``E^O``, dB) with the location in column 1."""

    def fit(self, Z, y):
        Z = np.asarray(Z, float)
        self.model_ = PerLocationForce("fourier1").fit(Z[:, 0], np.asarray(y, float), Z[:, 1].astype(int))
        return self

    def predict(self, Z):
        Z = np.asarray(Z, float)
        f = self.model_.predict(Z[:, 0], Z[:, 1].astype(int))
        return np.where(np.isfinite(f), f, 0.0)


class PooledRidge(RegressorMixin, BaseEstimator):
    """One ridge over every location: the touch's relative bins (columns 2:) and the location one-hot, standardised."""

    def __init__(self, alpha: float = 10.0):
        self.alpha = alpha

    def fit(self, Z, y):
        Z = np.asarray(Z, float)
        self.model_ = PooledForce(alpha=self.alpha).fit(Z[:, 2:], np.asarray(y, float), Z[:, 1].astype(int))
        return self

    def predict(self, Z):
        Z = np.asarray(Z, float)
        return self.model_.predict(Z[:, 0], Z[:, 1].astype(int), inputs=Z[:, 2:])


class PooledSVRCandidate(RegressorMixin, BaseEstimator):
    """The pooled SVR floor as a candidate: an RBF SVR over the touch's standardised inputs (columns 2:)."""

    def fit(self, Z, y):
        self.model_ = PooledSVR().fit(np.asarray(Z, float)[:, 2:], np.asarray(y, float))
        return self

    def predict(self, Z):
        Z = np.asarray(Z, float)
        return self.model_.predict(Z[:, 0], Z[:, 1].astype(int), inputs=Z[:, 2:])


# -- cross-validation ----------------------------------------------------------------------------------
def make_cv(passes: np.ndarray, val: np.ndarray | None = None, location: np.ndarray | None = None
            ) -> tuple[PredefinedSplit | None, str]:
    """The splitter (folds over ``passes``, ``val`` rows scored but never trained on) and its description, or ``None`` and why."""
    if val is not None and np.any(val):
        if np.all(val):
            return None, "every chirp is in the validation session"
        return PredefinedSplit(np.where(val, 0, -1)), "validation session"
    if location is None:
        location = np.zeros(passes.shape, int)
    n_pass = min((int(passes[location == k].max()) + 1 for k in np.unique(location)), default=0)
    if n_pass < 2:
        return None, "one press per location and no validation session"
    n_splits = min(n_pass, MAX_FOLDS)
    return PredefinedSplit(passes % n_splits), f"{n_splits}-fold cross-validation over passes"


def _subsample(press: np.ndarray, max_chirps: int) -> np.ndarray:
    """Row indices: at most ``ceil(max_chirps / n_presses)`` chirps per press, evenly spaced (every press kept)."""
    ids = np.unique(press)
    per = max(2, math.ceil(max_chirps / max(ids.size, 1)))
    keep = []
    for p in ids:
        r = np.flatnonzero(press == p)
        keep.append(r if r.size <= per else r[np.round(np.linspace(0, r.size - 1, per)).astype(int)])
    return np.sort(np.concatenate(keep)) if keep else np.zeros(0, int)


def _oof(est, X, y, cv) -> tuple[np.ndarray, np.ndarray]:
    """Out-of-fold predictions of ``est`` on the rows each split tests (rows never tested: NaN mask)."""
    pred = np.full(len(y), np.nan if np.issubdtype(np.asarray(y).dtype, np.floating) else -1, dtype=np.asarray(y).dtype)
    tested = np.zeros(len(y), bool)
    for tr, te in cv.split(X, y):
        pred[te] = clone(est).fit(X[tr], y[tr]).predict(X[te])
        tested[te] = True
    return pred, tested


def _compact(search, keys: list[str], score_name: str, sign: float = 1.0, top: int = 12) -> list[dict]:
    r = search.cv_results_
    order = np.argsort(r["rank_test_score"], kind="stable")[:top]
    out = []
    for i in order:
        row = {k: _plain(r["params"][i].get(k)) for k in keys if k in r["params"][i]}
        row[score_name] = float(sign * r["mean_test_score"][i])
        row["std"] = float(r["std_test_score"][i])
        out.append(row)
    return out


def _plain(v):
    if isinstance(v, BaseEstimator):
        return type(v).__name__
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return v


# -- localization ----------------------------------------------------------------------------------------
def select_localizer(X: np.ndarray, y: np.ndarray, press: np.ndarray, passes: np.ndarray, *, val: np.ndarray | None = None,
                     moving_var: np.ndarray | None = None, gammas: list[int] | None = None, max_chirps: int = 600,
                     val_name: str = "", n_bins_fallback: int | None = None, log=None) -> dict:
    """Choose OSPA's gamma, C and the RBF kernel width on touch chirps; the choice as JSON data."""
    X, y, press, passes = np.asarray(X), np.asarray(y), np.asarray(press), np.asarray(passes)
    n_feat = X.shape[1]
    gammas = list(dict.fromkeys(min(int(g), n_feat) for g in (gammas or gamma_grid(n_feat))))
    fallback_bins = min(n_bins_fallback or PAPER["n_bins"], n_feat)
    cv, how = make_cv(passes, val, y)
    if val is not None and np.any(val):
        how = f"validation on {val_name or 'the validation session'}"
    base = {"grid": {"n_bins": gammas, "C": list(C_GRID), "kernel_width": list(WIDTH_GRID)}}
    if cv is None:
        msg = (f"model selection needs a validation session or at least two presses per location ({how}); "
               f"keeping the paper's gamma {fallback_bins}, C {PAPER['C']:g}, kernel width 'scale'")
        (log or (lambda m: warnings.warn(m, stacklevel=2)))(f"warning: {msg}")
        return {**base, "status": "fallback", "reason": msg, "params": {**PAPER, "n_bins": fallback_bins}}
    rows = _subsample(press, max_chirps)
    Xs, ys = X[rows], y[rows]
    if val is not None and np.any(val):
        cv = PredefinedSplit(np.where(val[rows], 0, -1))
    else:
        cv = PredefinedSplit(passes[rows] % cv.get_n_splits())
    pipe = localizer_pipeline(moving_var=moving_var)
    grid = {"ospa__gamma": gammas, "svc__C": list(C_GRID), "width__factor": list(WIDTH_GRID)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        search = GridSearchCV(pipe, grid, cv=cv, scoring="accuracy", refit=False, n_jobs=1, error_score=np.nan).fit(Xs, ys)
    bp = search.best_params_
    params = {"n_bins": int(bp["ospa__gamma"]), "C": float(bp["svc__C"]), "kernel_width": float(bp["width__factor"])}
    best = clone(pipe).set_params(**bp)
    pred, tested = _oof(best, Xs, ys, cv)
    pr = (press[rows] if val is None else np.where(val[rows], press[rows], -1))[tested]
    ok = (pred[tested] == ys[tested])
    per_press = np.array([ok[pr == p].mean() for p in np.unique(pr)])
    ci = t_interval(per_press, (0.0, 1.0))  # an accuracy stays in [0, 1]
    est = {"accuracy": float(ok.mean()), "press_accuracy_mean": float(per_press.mean()), "ci95": ci,
           "n_presses": int(per_press.size), "n_chirps": int(ok.size)}
    # the paper's point of the grid, for comparison
    paper_i = [i for i, p in enumerate(search.cv_results_["params"])
               if p["svc__C"] == PAPER["C"] and p["width__factor"] == 1.0 and p["ospa__gamma"] == min(gammas, key=lambda g: abs(g - 300))]
    paper_acc = float(search.cv_results_["mean_test_score"][paper_i[0]]) if paper_i else None
    lc = learning_curve_by_pass(best, Xs, ys, passes[rows], press[rows], val=None if val is None else val[rows])
    return {**base, "status": "validated", "how": how, "params": params, "estimate": est,
            "paper_accuracy": paper_acc, "n_candidates": len(search.cv_results_["params"]),
            "cv": _compact(search, ["ospa__gamma", "svc__C", "width__factor"], "accuracy"), "learning_curve": lc}


def learning_curve_by_pass(est, X, y, passes, press, *, val=None) -> dict:
    """Accuracy against presses per location (1..k) from the user's own data, and whether one more pass would help."""
    sizes, acc, spread = [], [], []
    if val is not None and np.any(val):
        n_pass = int(passes[~val].max()) + 1
        for k in range(1, n_pass + 1):
            tr = ~val & (passes < k)
            if np.unique(y[tr]).size < 2:
                continue
            a = float(np.mean(clone(est).fit(X[tr], y[tr]).predict(X[val]) == y[val]))
            sizes.append(k); acc.append(a); spread.append(0.0)
    else:
        n_pass = int(passes.max()) + 1
        for k in range(1, n_pass):
            scores = []
            for j in range(n_pass):
                others = [q for q in range(n_pass) if q != j][:k]
                tr, te = np.isin(passes, others), passes == j
                if np.unique(y[tr]).size < 2 or not te.any():
                    continue
                scores.append(float(np.mean(clone(est).fit(X[tr], y[tr]).predict(X[te]) == y[te])))
            if scores:
                sizes.append(k); acc.append(float(np.mean(scores))); spread.append(float(np.std(scores)))
    if len(acc) >= 2:
        gain = acc[-1] - acc[-2]
        verdict = (f"one more pass over the markers would likely help (the last pass added {gain * 100:+.1f} points)"
                   if gain > 0.01 else f"the curve has flattened (the last pass added {gain * 100:+.1f} points)")
    else:
        verdict = "one point only: record one more pass over the markers to see the trend"
    how = ("trained on the first k passes, scored on the validation session" if val is not None and np.any(val) else
           f"{n_pass} passes recorded: each point trains on k of them and scores on one held out, so k stops at {n_pass - 1}")
    return {"presses_per_location": sizes, "accuracy": acc, "std": spread, "verdict": verdict, "passes_recorded": n_pass, "how": how}


# -- force ------------------------------------------------------------------------------------------------
def force_design(E: np.ndarray, location: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    return np.column_stack([np.asarray(E, float), np.asarray(location, float), np.asarray(inputs, float)])


def select_force(E, location, inputs, force, press, passes, *, val=None, val_name: str = "", log=None) -> dict:
    """Choose the paper's per-location Fourier-1, a pooled ridge or the pooled SVR by RMSE on presses not trained on."""
    Z = force_design(E, location, inputs)
    F = np.asarray(force, float)
    cv, how = make_cv(passes, val, np.asarray(location))
    if cv is None:  # the default measured across rigs, not the paper's (benchmarks/bench_default.py)
        msg = (f"force model not validated ({how}); a pooled ridge (alpha {UNVALIDATED_FORCE_ALPHA:g}), the best "
               f"measured across the random rig family without validation")
        (log or (lambda m: warnings.warn(m, stacklevel=2)))(f"warning: {msg}")
        return {"status": "fallback", "reason": msg, "model": "pooled-ridge", "alpha": UNVALIDATED_FORCE_ALPHA}
    if val is not None and np.any(val):
        how = f"validation on {val_name or 'the validation session'}"
    else:
        cv = PredefinedSplit(passes % cv.get_n_splits())
    grid = [{"model": [FourierPerLocation()]}, {"model": [PooledRidge()], "model__alpha": list(ALPHA_GRID)},
            {"model": [PooledSVRCandidate()]}]
    pipe = Pipeline([("model", FourierPerLocation())])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        search = GridSearchCV(pipe, grid, cv=cv, scoring="neg_root_mean_squared_error", refit=False, error_score=np.nan).fit(Z, F)
    bp = search.best_params_
    best = clone(pipe).set_params(**bp)
    pred, tested = _oof(best, Z, F, cv)
    pr = press[tested]
    err = pred[tested] - F[tested]
    per_press = np.array([np.sqrt(np.mean(err[pr == p] ** 2)) for p in np.unique(pr)])
    model = {PooledRidge: PooledForce.NAME, PooledSVRCandidate: PooledSVR.NAME}.get(type(bp["model"]), "fourier1")
    res = search.cv_results_
    fourier_rmse = float(-np.nanmax([s for p, s in zip(res["params"], res["mean_test_score"])
                                     if isinstance(p["model"], FourierPerLocation)]))
    return {"status": "validated", "how": how, "model": model, "alpha": float(bp.get("model__alpha", 0.0)) or None,
            "estimate": {"rmse_n": float(np.sqrt(np.mean(err ** 2))), "press_rmse_ci95": t_interval(per_press, (0.0, np.inf)),
                         "n_presses": int(per_press.size)},
            "fourier1_rmse_n": fourier_rmse, "constant_rmse_n": float(np.std(F[tested])),
            "cv": _compact(search, ["model", "model__alpha"], "rmse_n", sign=-1.0)}


# -- detection -------------------------------------------------------------------------------------------
def select_threshold(stat_touch: np.ndarray, stat_quiet: np.ndarray, *, how: str) -> dict:
    """Detection threshold by Youden's J on validation chirps: the lowest of the best, halfway between two data values."""
    st, sq = np.asarray(stat_touch, float).ravel(), np.asarray(stat_quiet, float).ravel()
    if st.size == 0 or sq.size == 0:
        raise ValueError("need both touch and no-touch chirps to choose a detection threshold")
    v = np.unique(np.r_[st, sq])
    cand = np.r_[v[0] - 1e-9, (v[:-1] + v[1:]) / 2, v[-1] + 1e-9]
    tpr = (st[None, :] >= cand[:, None]).mean(axis=1)
    fpr = (sq[None, :] >= cand[:, None]).mean(axis=1)
    j = tpr - fpr
    thr = float(cand[np.flatnonzero(j >= j.max() - 1e-12)[0]])  # candidates ascend: the lowest of the best
    return {"how": how, "threshold": thr, "missed_touch_rate": float(np.mean(st < thr)), "false_touch_rate": float(np.mean(sq >= thr))}


def detection_on_validation(X: np.ndarray, t, *, cls: np.ndarray, val_mask: np.ndarray, n_locations: int,
                            threshold: float) -> dict | None:
    """Missed and false touches of the input-RMS detector at ``threshold`` on the validation session (``None`` without)."""
    q, touch = quiet_mask(t) & val_mask, (cls < n_locations) & val_mask
    no_touch = (t["location"] < 0) & val_mask
    if q.sum() < 2 or not touch.any():
        return None
    stat = touch_statistic(np.column_stack([np.zeros((len(X), n_locations)), X - X[q].mean(axis=0)]), n_locations,
                           min(DETECTOR_BINS, X.shape[1]))
    names = ", ".join(sorted(set(t["session"][val_mask])))
    return {"how": f"Youden's J on the training chirps; on {names}", "threshold": float(threshold),
            "missed_touch_rate": float(np.mean(stat[touch] < threshold)), "false_touch_rate": float(np.mean(stat[no_touch] >= threshold))}


# -- on a dataset's training split -----------------------------------------------------------------------------
def training_rows(t, sessions, min_force_n: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Press ids over the whole table and the touch chirps of ``sessions`` (labels only of those sessions)."""
    seg = t["segment"] if "segment" in t.labels else None
    press = press_ids(t["location"], t["session"], seg)
    return press, touch_mask(t, min_force_n) & np.isin(t["session"], list(sessions))


def select_gamma_on_table(t, rig, *, train_sessions, val_sessions=(), mode: str = "relative", min_force_n: float = 0.5,
                          log=print, max_chirps: int = 600) -> dict:
    """Choose gamma, C and kernel width on the training (and validation) sessions of a features table, only their rows read."""
    use = np.isin(t["session"], list(train_sessions) + list(val_sessions))
    tt = t.select(use)
    allowed = np.flatnonzero(rig.allowed_mask)
    spec = FeatureSpec(tuple(int(b) for b in allowed), mode)
    try:
        Xall = spec.transform(tt, rig.chirps_per_s)
    except ValueError:  # not enough rest for Alg. 2's reference: absolute inputs, as prepare() falls back
        Xall = FeatureSpec(spec.bins, "absolute").transform(tt, rig.chirps_per_s)
    press, touch = training_rows(tt, list(train_sessions) + list(val_sessions), min_force_n)
    is_tr = np.isin(tt["session"], list(train_sessions))
    moving = (tt["location"] < 0) & (tt["moving"] > 0) & is_tr
    ref = moving if moving.sum() >= 2 else quiet_mask(tt) & is_tr
    mv = Xall[ref].astype(np.float64).var(axis=0) if ref.sum() >= 2 else None
    passes = press_passes(np.where(is_tr, press, -1), tt["location"])
    rows = np.flatnonzero(touch)
    val = ~is_tr[rows] if len(val_sessions) else None
    return select_localizer(Xall[rows], tt["location"][rows], press[rows], passes[rows], val=val, moving_var=mv,
                            max_chirps=max_chirps, val_name=", ".join(val_sessions), log=log)


def select_on_inputs(X: np.ndarray, t, *, cls: np.ndarray, train_mask: np.ndarray, val_mask: np.ndarray | None,
                     n_locations: int, location_ids, selection: dict | None = None, min_force_n: float = 0.5,
                     key: str = "localizer", log=print) -> dict:
    """The rest of the choice once the inputs are fixed (C, kernel width, force, threshold), on the train/val rows only."""
    sel = dict(selection or {})
    val_mask = np.zeros(len(X), bool) if val_mask is None else np.asarray(val_mask, bool)
    seg = t["segment"] if "segment" in t.labels else None
    press = press_ids(np.where(train_mask | val_mask, t["location"], -1), t["session"], seg)  # other rows: no press
    touch = cls < n_locations
    passes = press_passes(np.where(train_mask, press, -1), t["location"])
    val_name = ", ".join(sorted(set(t["session"][val_mask]))) if val_mask.any() else ""
    rows = np.flatnonzero((train_mask | val_mask) & touch)
    val_rows = val_mask[rows] if val_mask.any() else None
    if key not in sel:  # the localizer's choice (gamma, C, kernel width) under the model's key
        sel[key] = select_localizer(X[rows], cls[rows], press[rows], passes[rows], val=val_rows, gammas=[X.shape[1]],
                                      val_name=val_name, n_bins_fallback=X.shape[1], log=log)
    # force: on touch chirps with a force reading
    f = t["force_n"].astype(float)
    fr = rows[np.isfinite(f[rows])]
    if fr.size >= 8 and np.ptp(f[fr]) > 0 and np.unique(cls[fr]).size == n_locations:
        ids = np.asarray(location_ids)
        E = energy_db(X[fr], np.arange(X.shape[1]))
        sel["force"] = select_force(E, ids[cls[fr]], X[fr], f[fr], press[fr], passes[fr],
                                    val=val_mask[fr] if val_mask.any() else None, val_name=val_name, log=log)
    else:
        sel["force"] = {"status": "absent", "reason": "absent: no force sensor (or a constant force)", "model": "fourier1"}
    # detection: the threshold stays the training chirps' (Youden's J; one chosen on a validation session missed 35 %
    # of a moving random rig's test touches): the validation session only estimates it (detection_on_validation)
    sel["detection"] = {"how": "Youden's J on the training chirps", "threshold": None}
    return sel


def save_learning_curve(sel: dict, path, *, title: str = "") -> bool:
    """The learning curve of a localizer's selection as a PNG; False without one."""
    lc = (sel or {}).get("learning_curve")
    if not lc or not lc["accuracy"]:
        return False
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    k, a, s = (np.asarray(lc[x], float) for x in ("presses_per_location", "accuracy", "std"))
    ax.errorbar(k, 100 * a, yerr=100 * s, fmt="o-", capsize=3, label="mean ± std over held-out passes")
    for kk, aa in zip(k, a):  # every point labelled: two or three points are read as numbers
        ax.annotate(f"{100 * aa:.0f} %", (kk, 100 * aa), textcoords="offset points", xytext=(0, 8), ha="center", fontsize=8)
    n_pass = int(lc.get("passes_recorded") or (k.max() if k.size else 1))
    lo = float(np.min(100 * (a - s))) if a.size else 0.0
    ax.set(xlabel="presses per location in training", ylabel="accuracy on held-out presses (%)",
           xticks=np.arange(1, max(n_pass, int(k.max()) if k.size else 1) + 1), xlim=(0.5, max(n_pass, k.max() if k.size else 1) + 0.5),
           ylim=(max(0.0, np.floor(lo / 10) * 10 - 25), 101), title=title or "learning curve")
    # The note inside the frame, wrapped: the verdict and how the points were made (why a 3-pass recording has 2)
    note = "\n".join(textwrap.wrap(lc["verdict"], 62) + textwrap.wrap(lc.get("how", ""), 62))
    ax.text(0.03, 0.04, note, transform=ax.transAxes, fontsize=7.5, va="bottom",
            bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"})
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
