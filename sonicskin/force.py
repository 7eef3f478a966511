"""Touch-force estimation (paper Sec. III-D): energy over the OSPA bins -> curve model per location.

``E = 10 log10(sum |H|^2 / sum |H_0|^2)`` over the selected bins (the rig's gain drops out).  The curve models
(Fig. 13) are fitted by variable projection: a grid over the nonlinear parameter, refined by least squares."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import least_squares

__all__ = ["energy_db", "CurveModel", "MODELS", "fit_curve", "PerLocationForce", "PooledForce", "PooledSVR", "POOLED",
           "force_from_dict", "r2_score"]


def energy_db(X_db: np.ndarray, bins: np.ndarray, ref_db: np.ndarray | None = None) -> np.ndarray:
    """``E^O`` in dB over ``bins`` of ``X_db``, relative to the no-touch reference ``ref_db`` if given."""
    X = np.asarray(X_db, dtype=np.float64)[:, bins]
    e = 10 * np.log10(np.mean(10 ** (X / 10), axis=1))
    if ref_db is not None:
        r = np.asarray(ref_db, dtype=np.float64)
        r = r.mean(axis=0) if r.ndim == 2 else r
        e = e - 10 * np.log10(np.mean(10 ** (r[bins] / 10)))
    return e


def r2_score(y: np.ndarray, yhat: np.ndarray) -> float:
    ss_res = float(np.sum((y - yhat) ** 2))
    ss_tot = float(np.sum((y - np.mean(y)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0


@dataclasses.dataclass(frozen=True)
class CurveModel:
    """``F = sum_j c_j g_j(u; theta)`` on normalised energy ``u`` with at most one nonlinear ``theta``."""

    name: str
    basis: Callable[[np.ndarray, float], np.ndarray]  # (u, theta) -> (n, n_coef)
    theta_grid: np.ndarray | None  # None: linear model

    def design(self, u: np.ndarray, theta: float) -> np.ndarray:
        return self.basis(np.asarray(u, float), theta)


def _fourier(order: int):
    def basis(u, w):
        cols = [np.ones_like(u)]
        for k in range(1, order + 1):
            cols += [np.cos(k * w * u), np.sin(k * w * u)]
        return np.column_stack(cols)
    return basis


def _poly(order: int):
    return lambda u, _: np.vander(u, order + 1, increasing=True)


# u is energy scaled to about [-1, 1]; omega up to 3 pi covers 1.5 periods over the data.
MODELS: dict[str, CurveModel] = {
    "fourier1": CurveModel("fourier1", _fourier(1), np.linspace(0.05, 3 * np.pi, 60)),
    "fourier2": CurveModel("fourier2", _fourier(2), np.linspace(0.05, 1.5 * np.pi, 60)),
    "poly1": CurveModel("poly1", _poly(1), None),
    "poly2": CurveModel("poly2", _poly(2), None),
    "poly3": CurveModel("poly3", _poly(3), None),
    "exp": CurveModel("exp", lambda u, b: np.column_stack([np.ones_like(u), np.exp(b * u)]),
                      np.r_[np.linspace(-6, -0.05, 30), np.linspace(0.05, 6, 30)]),
    # Power law on u shifted to be positive (u + 2 >= 1 on the training range).
    "power": CurveModel("power", lambda u, b: np.column_stack([np.ones_like(u), np.power(np.maximum(u + 2, 1e-6), b)]),
                        np.r_[np.linspace(-4, -0.05, 30), np.linspace(0.05, 4, 30)]),
}


@dataclasses.dataclass
class FittedCurve:
    """A fitted curve model; JSON-serialisable through :meth:`to_dict`."""

    model: str
    theta: float
    coef: np.ndarray
    center: float
    scale: float
    r2: float
    e_lo: float = -np.inf
    e_hi: float = np.inf

    def predict(self, E: np.ndarray) -> np.ndarray:
        """Force at energy ``E``, held at its edge value outside the training range (a curve from one press swings wildly)."""
        u = (np.clip(np.asarray(E, float), self.e_lo, self.e_hi) - self.center) / self.scale
        return MODELS[self.model].design(u, self.theta) @ self.coef

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "theta": float(self.theta), "coef": [float(c) for c in self.coef],
                "center": float(self.center), "scale": float(self.scale), "r2": float(self.r2),
                "e_lo": float(self.e_lo), "e_hi": float(self.e_hi)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FittedCurve:
        if d["model"] not in MODELS:
            raise ValueError(f"unknown force model {d['model']!r}; known: {sorted(MODELS)}")
        return cls(d["model"], float(d["theta"]), np.asarray(d["coef"], float), float(d["center"]),
                   float(d["scale"]), float(d["r2"]), float(d.get("e_lo", -np.inf)), float(d.get("e_hi", np.inf)))


def fit_curve(E: np.ndarray, F: np.ndarray, model: str = "fourier1") -> FittedCurve:
    """Least-squares fit of one curve model ``F ~ f(E)`` (a key of :data:`MODELS`; paper Eq. 5 for ``fourier1``)."""
    if model not in MODELS:
        raise ValueError(f"unknown force model {model!r}; choose one of {sorted(MODELS)}")
    E = np.asarray(E, float)
    F = np.asarray(F, float)
    if E.shape != F.shape or E.ndim != 1:
        raise ValueError(f"E and F must be 1-D of equal length, got {E.shape} and {F.shape}")
    if not (np.isfinite(E).all() and np.isfinite(F).all()):
        raise ValueError("E or F contains NaN or inf")
    m = MODELS[model]
    n_coef = m.design(np.zeros(1), 1.0).shape[1]
    if E.size < n_coef + (m.theta_grid is not None) + 1:
        raise ValueError(f"{model} needs more than {n_coef + 1} force samples, got {E.size}")
    center = float(np.median(E))
    scale = float(np.max(np.abs(E - center))) or 1.0
    u = (E - center) / scale

    def solve(theta):
        A = m.design(u, theta)
        coef, *_ = np.linalg.lstsq(A, F, rcond=None)
        return coef, float(np.sum((A @ coef - F) ** 2))

    if m.theta_grid is None:
        theta = 0.0
        coef, _ = solve(theta)
    else:
        sse = [solve(t)[1] for t in m.theta_grid]
        theta = float(m.theta_grid[int(np.argmin(sse))])
        coef, _ = solve(theta)
        res = least_squares(lambda p: m.design(u, p[0]) @ p[1:] - F, np.r_[theta, coef], method="lm")
        if np.isfinite(res.x).all() and np.sum(res.fun ** 2) <= np.sum((m.design(u, theta) @ coef - F) ** 2):
            theta, coef = float(res.x[0]), res.x[1:]
    fitted = FittedCurve(model, theta, np.asarray(coef, float), center, scale, 0.0, float(E.min()), float(E.max()))
    fitted.r2 = r2_score(F, fitted.predict(E))
    return fitted


class PerLocationForce:
    """One curve per touch location (the paper's parameter set S in R^{N x 4} for Fourier-1)."""

    def __init__(self, model: str = "fourier1"):
        if model not in MODELS:
            raise ValueError(f"unknown force model {model!r}; choose one of {sorted(MODELS)}")
        self.model = model

    def fit(self, E: np.ndarray, F: np.ndarray, location: np.ndarray) -> PerLocationForce:
        E, F, location = np.asarray(E, float), np.asarray(F, float), np.asarray(location)
        if not (E.shape == F.shape == location.shape):
            raise ValueError(f"E, F and location must have equal length, got {E.size}, {F.size}, {location.size}")
        self.curves_ = {int(k): fit_curve(E[location == k], F[location == k], self.model) for k in np.unique(location)}
        return self

    def predict(self, E: np.ndarray, location: np.ndarray, inputs: np.ndarray | None = None) -> np.ndarray:
        """Force at energy ``E`` for each chirp's ``location`` (``inputs`` unused: the pooled model's)."""
        E, location = np.asarray(E, float), np.asarray(location)
        out = np.full(E.shape, np.nan)
        for k, curve in self.curves_.items():
            sel = location == k
            if sel.any():
                out[sel] = curve.predict(E[sel])
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "curves": {str(k): c.to_dict() for k, c in self.curves_.items()}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PerLocationForce | PooledForce | PooledSVR:
        if d.get("model") in POOLED:
            return POOLED[d["model"]].from_dict(d)
        obj = cls(d["model"])
        obj.curves_ = {int(k): FittedCurve.from_dict(c) for k, c in d["curves"].items()}
        return obj


class PooledForce:
    """One linear model for every location, ``F = inputs . coef + loc_coef[location] + intercept`` (a ridge)."""

    NAME = "pooled-ridge"

    def __init__(self, alpha: float = 10.0):
        self.alpha = float(alpha)
        self.model = self.NAME

    def fit(self, inputs: np.ndarray, F: np.ndarray, location: np.ndarray) -> PooledForce:
        from sklearn.linear_model import Ridge
        from sklearn.preprocessing import StandardScaler

        X, F, location = np.asarray(inputs, float), np.asarray(F, float), np.asarray(location)
        if X.ndim != 2 or not (X.shape[0] == F.size == location.size):
            raise ValueError(f"inputs (n, B), F and location must have n rows, got {X.shape}, {F.size}, {location.size}")
        ids = np.unique(location)
        D = np.column_stack([X, (location[:, None] == ids[None]).astype(float)])
        sc = StandardScaler().fit(D)
        r = Ridge(alpha=self.alpha).fit(sc.transform(D), F)
        w = r.coef_ / sc.scale_
        b = float(r.intercept_ - np.sum(w * sc.mean_))
        B = X.shape[1]
        self.coef_ = w[:B]
        self.loc_coef_ = {int(k): float(v) for k, v in zip(ids, w[B:])}
        self.intercept_ = b
        return self

    def predict(self, E: np.ndarray, location: np.ndarray, inputs: np.ndarray | None = None) -> np.ndarray:
        if inputs is None:
            raise ValueError("the pooled force model reads the model inputs; pass inputs=")
        location = np.asarray(location)
        loc = np.array([self.loc_coef_.get(int(k), 0.0) for k in location.ravel()]).reshape(location.shape)
        return np.asarray(inputs, float) @ self.coef_ + loc + self.intercept_

    def padded(self, n_in: int) -> PooledForce:
        """The same model over ``n_in`` >= its inputs: zero weight on the inputs after the ones it was fitted on."""
        self.coef_ = np.r_[self.coef_, np.zeros(n_in - self.coef_.size)]
        return self

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.NAME, "curves": {}, "pooled": {"alpha": self.alpha, "coef": [float(c) for c in self.coef_],
                "loc_coef": {str(k): v for k, v in self.loc_coef_.items()}, "intercept": self.intercept_}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PooledForce:
        p = d["pooled"]
        obj = cls(p["alpha"])
        obj.coef_ = np.asarray(p["coef"], float)
        obj.loc_coef_ = {int(k): float(v) for k, v in p["loc_coef"].items()}
        obj.intercept_ = float(p["intercept"])
        return obj


class PooledSVR:
    """One RBF support-vector regression for every location over the first inputs, each standardised: scikit-learn's
    ``SVR()`` (C 1, epsilon 0.1 N, gamma "scale"), the pooled SVR floor of issue 36, kept as numbers so the runtime
    evaluates it without scikit-learn (support vectors rounded to 1e-4 standard deviations before use, so what
    validation scored is what runs)."""

    NAME = "pooled-svr"
    #: at most this many inputs (OSPA's first) and training chirps (evenly spaced): its support vectors are stored in
    #: skin.json, once per model that uses it (every bin of a wide rig made a 95 MB skin.json)
    MAX_INPUTS, MAX_ROWS = 300, 1500

    def __init__(self):
        self.model = self.NAME

    def fit(self, inputs: np.ndarray, F: np.ndarray, location: np.ndarray | None = None) -> PooledSVR:
        from sklearn.svm import SVR

        X, F = np.asarray(inputs, float)[:, :self.MAX_INPUTS], np.asarray(F, float)
        if X.ndim != 2 or X.shape[0] != F.size or X.shape[0] < 2:
            raise ValueError(f"inputs (n, B) and F must have n >= 2 rows, got {X.shape} and {F.size}")
        if X.shape[0] > self.MAX_ROWS:
            keep = np.unique(np.round(np.linspace(0, X.shape[0] - 1, self.MAX_ROWS)).astype(int))
            X, F = X[keep], F[keep]
        self.mean_, sd = X.mean(axis=0), X.std(axis=0)
        self.scale_ = np.where(sd > 0, sd, 1.0)  # StandardScaler's convention for a constant input
        Z = (X - self.mean_) / self.scale_
        self.gamma_ = float(1.0 / (Z.shape[1] * Z.var())) if Z.var() > 0 else 1.0  # gamma="scale"
        r = SVR(gamma=self.gamma_).fit(Z, F)
        self.sv_ = np.round(r.support_vectors_, 4)
        self.dual_, self.intercept_ = r.dual_coef_.ravel().astype(float), float(r.intercept_[0])
        self._sv_sq = np.sum(self.sv_ ** 2, axis=1)
        return self

    def predict(self, E: np.ndarray, location: np.ndarray, inputs: np.ndarray | None = None) -> np.ndarray:
        if inputs is None:
            raise ValueError("the pooled SVR force model reads the model inputs; pass inputs=")
        Z = (np.asarray(inputs, float)[:, :self.mean_.size] - self.mean_) / self.scale_
        d2 = np.sum(Z * Z, axis=1)[:, None] + self._sv_sq[None, :] - 2.0 * Z @ self.sv_.T  # per chirp in the live loop
        return np.exp(-self.gamma_ * np.maximum(d2, 0.0)) @ self.dual_ + self.intercept_

    def padded(self, n_in: int) -> PooledSVR:
        return self  # it reads its first inputs only

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.NAME, "curves": {}, "svr": {
            "mean": self.mean_.tolist(), "scale": self.scale_.tolist(), "gamma": self.gamma_, "intercept": self.intercept_,
            "dual": self.dual_.tolist(), "support_vectors": self.sv_.tolist()}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PooledSVR:
        p, obj = d["svr"], cls()
        obj.mean_, obj.scale_ = np.asarray(p["mean"], float), np.asarray(p["scale"], float)
        obj.gamma_, obj.intercept_ = float(p["gamma"]), float(p["intercept"])
        obj.dual_ = np.asarray(p["dual"], float)
        obj.sv_ = np.asarray(p["support_vectors"], float).reshape(obj.dual_.size, obj.mean_.size)
        obj._sv_sq = np.sum(obj.sv_ ** 2, axis=1)
        return obj


#: the force models over every location, by their ``model`` name in ``skin.json``
POOLED = {PooledForce.NAME: PooledForce, PooledSVR.NAME: PooledSVR}


def force_from_dict(d: dict[str, Any]) -> PerLocationForce | PooledForce | PooledSVR:
    """The force model a ``skin.json`` force section describes (per-location curves or pooled)."""
    return PerLocationForce.from_dict(d)
