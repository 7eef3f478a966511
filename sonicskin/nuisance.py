"""Localizers that know what varies between two presses at one marker (issue 26).

With one press per marker per session an RBF SVM sees one cloud of chirps per marker and cannot tell
which differences between two presses at the same marker are *nuisance* (how hard, which finger, where
exactly the fingertip landed, how the robot moved, how warm the link is) and which are *location*.
These estimators learn that from the whole training session at once, pooled over the markers:

- :class:`ShrinkageLDA`: linear discriminant analysis with one within-marker covariance shared by every
  marker, Ledoit-Wolf shrunk per marker exactly as scikit-learn's
  ``LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto")`` does, computed in the sample space
  (Woodbury) so thousands of bins cost milliseconds instead of minutes.  Its ``nuisance`` rows add
  known nuisance directions to that covariance: with them it is the **prototype / metric head**
  (class means compared under the Mahalanobis metric of presses, motion, warm-up and aim).
- :class:`LevelRemoval`: removes each chirp's mean level (and optionally a linear tilt over frequency)
  from its relative dB spectrum: what a firmer or softer press, or a gain change, does to every bin alike.
- :func:`nuisance_directions`: the nuisance rows, measured from the user's own training session
  (hands-off chirps while the robot moves) and from physics (frequency stretch of warm-up, gain and
  tilt, aim as interpolation toward neighbouring markers).
- :func:`make_candidates`: the candidate localizers validation chooses among (plain scikit-learn
  estimators and pipelines; ``Normalizer`` + ``SVC`` is the "shape, not strength" candidate).

Everything here is torch-free and exports to ONNX through skl2onnx (:func:`register_onnx_converters`:
:class:`ShrinkageLDA` as a linear classifier, :class:`LevelRemoval` as two MatMuls).
"""

from __future__ import annotations

import numbers

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.linear_model._base import LinearClassifierMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, validate_data

__all__ = ["ShrinkageLDA", "LevelRemoval", "nuisance_directions", "ledoit_wolf_shrinkage_gram", "make_candidates",
           "register_onnx_converters", "NUISANCE_KINDS"]


def ledoit_wolf_shrinkage_gram(Z: np.ndarray) -> float:
    """Ledoit-Wolf shrinkage of the covariance of the centred rows ``Z`` (n, d), computed from the n x n Gram
    matrix: the value of :func:`sklearn.covariance.ledoit_wolf_shrinkage` (``assume_centered=True``) in
    O(n^2 d) instead of O(n d^2)."""
    n, d = Z.shape
    if d == 1 or n == 0:
        return 0.0
    Z2 = Z * Z
    row2 = Z2.sum(axis=1)                       # |z_k|^2
    emp_trace = row2.sum() / n                  # trace of Z'Z / n
    mu = emp_trace / d
    beta_ = float(np.sum(row2 ** 2))            # sum_k |z_k|^4 = sum of <Z2', Z2>
    G = Z @ Z.T
    delta_ = float(np.sum(G * G)) / n ** 2      # |Z'Z|_F^2 / n^2
    beta = 1.0 / (d * n) * (beta_ / n - delta_)
    delta = (delta_ - 2.0 * mu * emp_trace + d * mu ** 2) / d
    beta = min(beta, delta)
    return 0.0 if beta == 0 else float(beta / delta)


class ShrinkageLDA(LinearClassifierMixin, BaseEstimator):
    """Linear discriminant analysis with a shrunk within-class covariance, plus optional nuisance directions.

    Without ``nuisance`` this is ``LinearDiscriminantAnalysis(solver="lsqr", shrinkage=shrinkage)`` of
    scikit-learn (same covariance: per class standardised, Ledoit-Wolf shrunk, rescaled and averaged with the
    class priors; same ``coef_`` and ``intercept_`` up to rounding), solved with the Woodbury identity in the
    space of the training samples, so 5,000 bins and a few hundred chirps take milliseconds.

    With ``nuisance`` rows ``V`` (k, d) the covariance becomes ``Sigma + nuisance_weight * V' V``: every row is a
    direction along which two chirps of one marker may differ, scaled to its plausible size in input units
    (dB).  The decision is then the class mean nearest to the chirp under the metric ``Sigma^-1`` (plus the
    log prior): a prototype head whose metric is learned from all markers pooled and from the known nuisances.

    Parameters
    ----------
    shrinkage : "auto" or float in [0, 1], default="auto"
        Ledoit-Wolf per class (on standardised features, as scikit-learn), or a fixed shrinkage of each class's
        empirical covariance toward ``trace / d`` times the identity.
    priors : array of shape (n_classes,), optional
        Class priors; default the class proportions.
    nuisance : array of shape (k, n_features), optional
        Nuisance directions in input units (:func:`nuisance_directions`).
    nuisance_weight : float, default=1.0
        Multiplies the nuisance covariance ``V' V`` (0 = plain shrinkage LDA).

    Attributes
    ----------
    classes_, means_ (n_classes, d), priors_, shrinkage_ (per class), coef_ (n_classes, d) or (1, d) for two
    classes, intercept_, n_features_in_.
    """

    def __init__(self, shrinkage="auto", priors=None, nuisance=None, nuisance_weight: float = 1.0):
        self.shrinkage = shrinkage
        self.priors = priors
        self.nuisance = nuisance
        self.nuisance_weight = nuisance_weight

    def fit(self, X, y):
        X, y = validate_data(self, X, y, dtype=np.float64, ensure_min_samples=2)
        check_classification_targets(y)
        self.classes_, yi = np.unique(y, return_inverse=True)
        K, (n, d) = len(self.classes_), X.shape
        if K < 2:
            raise ValueError(f"ShrinkageLDA needs at least 2 classes, got {K}: record at least two locations")
        sh = self.shrinkage
        if not (sh == "auto" or (isinstance(sh, numbers.Real) and not isinstance(sh, bool) and 0 <= sh <= 1)):
            raise ValueError(f"shrinkage must be 'auto' or a number in [0, 1], got {sh!r}")
        w = self.nuisance_weight
        if not (isinstance(w, numbers.Real) and not isinstance(w, bool) and np.isfinite(w) and w >= 0):
            raise ValueError(f"nuisance_weight must be a number >= 0, got {w!r}")
        counts = np.bincount(yi, minlength=K)
        if self.priors is None:
            priors = counts / n
        else:
            priors = np.asarray(self.priors, np.float64)
            if priors.shape != (K,) or np.any(priors < 0) or not np.isclose(priors.sum(), 1.0):
                raise ValueError(f"priors must be {K} non-negative numbers summing to 1, got {self.priors!r}")
        means = np.zeros((K, d))
        lam = np.zeros(d)                  # the diagonal part of the covariance
        rows, self.shrinkage_ = [], np.zeros(K)
        for k in range(K):
            Xk = X[yi == k]
            means[k] = Xk.mean(axis=0)
            Xc = Xk - means[k]
            nk = Xk.shape[0]
            if self.shrinkage == "auto":
                scale = Xc.std(axis=0)
                scale[scale == 0] = 1.0    # StandardScaler's convention for a constant feature
                Z = Xc / scale
                s = ledoit_wolf_shrinkage_gram(Z)
                mu = float(np.sum(Z * Z)) / (nk * d)
                lam += priors[k] * s * mu * scale ** 2
            else:
                s = float(self.shrinkage)
                mu = float(np.sum(Xc * Xc)) / (nk * d)
                lam += priors[k] * s * mu
            self.shrinkage_[k] = s
            rows.append(np.sqrt(priors[k] * (1.0 - s) / nk) * Xc)
        U = np.vstack(rows)
        if self.nuisance is not None and w > 0:
            V = np.asarray(self.nuisance, np.float64)
            if V.ndim != 2 or V.shape[1] != d:
                raise ValueError(f"nuisance must be (k, {d}) directions over the same {d} inputs, got shape {V.shape}")
            if not np.isfinite(V).all():
                raise ValueError("nuisance directions contain NaN or inf")
            U = np.vstack([U, np.sqrt(w) * V])
        # A feature with no spread anywhere (and no shrinkage) would make the covariance singular: a floor far
        # below any real variance keeps the solve defined (scikit-learn's lstsq returns the minimum-norm answer).
        lam = np.maximum(lam, 1e-12 * max(float(lam.mean()), float(np.mean(U * U)) * U.shape[0], 1e-300))
        self.means_, self.priors_ = means, priors
        S_inv_M = self._solve(lam, U, means.T)            # Sigma^-1 M'  (d, K)
        coef = S_inv_M.T
        intercept = -0.5 * np.einsum("kd,kd->k", means, coef) + np.log(np.maximum(priors, 1e-300))
        if K == 2:  # scikit-learn's binary convention: one row, positive for classes_[1]
            coef, intercept = coef[1:] - coef[:1], intercept[1:] - intercept[:1]
        self.coef_, self.intercept_ = coef, intercept
        return self

    @staticmethod
    def _solve(lam: np.ndarray, U: np.ndarray, B: np.ndarray) -> np.ndarray:
        """``(diag(lam) + U' U)^-1 B`` by the Woodbury identity (U: m x d, B: d x K)."""
        Li_B = B / lam[:, None]
        W = U / lam[None, :]                               # U diag(lam)^-1
        G = np.eye(U.shape[0]) + W @ U.T                   # I + U diag(lam)^-1 U'
        return Li_B - W.T @ np.linalg.solve(G, U @ Li_B)

    def predict_proba(self, X):
        from scipy.special import softmax

        s = self.decision_function(X)
        if s.ndim == 1:
            s = np.column_stack([-s / 2, s / 2])
        return softmax(s, axis=1)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.classifier_tags.multi_class = True
        return tags


class LevelRemoval(TransformerMixin, BaseEstimator):
    """Remove each chirp's mean level, and optionally its linear tilt over frequency, from its dB spectrum.

    A firmer press, another finger or a gain change moves every relative bin by about the same number of dB;
    what is left after removing the chirp's own mean (and least-squares tilt) is the spectral *shape* of the
    touch, which is what the location sets.  Linear: ``X - (X B) B'`` with ``B`` an orthonormal basis of the
    constant (and of the centred frequency) vector, exported as two MatMuls.

    Parameters
    ----------
    tilt : bool, default=False
        Also remove the least-squares slope over ``freqs_hz``.
    freqs_hz : array of shape (n_features,), optional
        Frequency of every input column (needed for ``tilt``; the inputs may be in any order, e.g. OSPA's).
    """

    def __init__(self, tilt: bool = False, freqs_hz=None):
        self.tilt = tilt
        self.freqs_hz = freqs_hz

    def fit(self, X, y=None):
        X = validate_data(self, X, dtype=np.float64)
        d = X.shape[1]
        cols = [np.ones(d)]
        if self.tilt:
            if self.freqs_hz is None or np.shape(self.freqs_hz) != (d,):
                raise ValueError(f"tilt removal needs freqs_hz, the frequency of each of the {d} input columns, "
                                 f"got {None if self.freqs_hz is None else np.shape(self.freqs_hz)}")
            f = np.asarray(self.freqs_hz, np.float64)
            if d > 1 and np.ptp(f) > 0:
                cols.append(f - f.mean())
        B, _ = np.linalg.qr(np.column_stack(cols))
        self.basis_ = B
        return self

    def transform(self, X):
        check_is_fitted(self, "basis_")
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return X - (X @ self.basis_) @ self.basis_.T


# -- nuisance directions -----------------------------------------------------------------------------------
#: What :func:`nuisance_directions` can measure, and why each is physical.
NUISANCE_KINDS = {
    "motion": "hands-off chirps while the robot moves, about their mean (the session's own motion and noise)",
    "stretch": "frequency stretch of each marker's touch pattern by warm-up (the wall's modes move as sqrt(E))",
    "gain": "a constant dB offset of every bin (transducer / amplifier gain, touch strength)",
    "tilt": "a dB offset linear in frequency (bond or coupling change)",
    "aim": "the fingertip landing off the marker: interpolation toward the neighbouring markers' patterns",
    "strength": "the same touch pattern scaled up or down (a firmer or softer press, a larger or smaller finger)",
}


def _freq_derivative(M: np.ndarray, freqs_hz: np.ndarray) -> np.ndarray:
    """d M / d ln f * ... : ``f dM/df`` per row over columns at ``freqs_hz`` (any order), by finite differences
    between neighbouring bins in frequency (gaps in the band: one-sided differences at their edges)."""
    order = np.argsort(freqs_hz, kind="stable")
    f = np.asarray(freqs_hz, np.float64)[order]
    D = np.gradient(M[:, order], f, axis=1)
    out = np.empty_like(D)
    out[:, order] = D * f[None, :]
    return out


def neighbour_rings(positions_cm, K: int, circumference_cm: float | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each marker's nearest ring of neighbours (at most 4, within 1.5 x the nearest distance) and their distances
    in cm; around a tube of ``circumference_cm`` the distance along the circumference is the shorter way round."""
    P = np.asarray(positions_cm, np.float64)
    if P.shape != (K, 2):
        raise ValueError(f"positions_cm must be ({K}, 2), one (x, y) per marker in label order, got {P.shape}")
    dx, dy = np.abs(P[:, None, 0] - P[None, :, 0]), np.abs(P[:, None, 1] - P[None, :, 1])
    if circumference_cm:
        dx = np.minimum(dx, circumference_cm - dx)
    D = np.hypot(dx, dy)
    rings = []
    for k in range(K):
        others = np.argsort(D[k])[1:]
        near = np.array([j for j in others if D[k, j] <= D[k, others[0]] * 1.5][:4], int)
        rings.append((near, D[k, near]))
    return rings


def nuisance_directions(X, y, *, X_rest=None, freqs_hz=None, positions_cm=None, circumference_cm: float | None = None,
                        stretch: float = 1e-3,
                        gain_db: float = 0.5, tilt_db: float = 0.5, aim_cm: float = 0.15, strength: float = 0.3,
                        max_rest: int = 200, kinds=None, random_state: int = 0) -> dict[str, np.ndarray]:
    """Nuisance directions in input units, one array of rows per kind (:data:`NUISANCE_KINDS`).

    Each row ``v`` is scaled so that ``v' v`` (summed over a kind's rows) is the covariance that nuisance adds to
    a marker's chirps, pooled over the markers like LDA's within-class covariance: per-marker directions are
    divided by ``sqrt(n_markers)``.

    Parameters
    ----------
    X, y : training touch chirps (n, d) and their marker labels (relative dB over the model inputs).
    X_rest : hands-off chirps of the training session while the robot moves (relative dB); ``motion``.
    freqs_hz : frequency of every input column; ``stretch`` and ``tilt`` (any column order).  For ``stretch``
        the inputs should be dense in frequency (every usable bin): select columns afterwards.
    positions_cm : (n_markers, 2) marker positions in the order of ``np.unique(y)``; ``aim``.
    circumference_cm : a tube's circumference (x distances wrap around it), or None for a plate.
    stretch : relative frequency stretch (e.g. 1e-3: about 3 K of warm-up on CFRP).
    gain_db, tilt_db : size of a gain change and of a tilt across the inputs' frequency span (dB).
    aim_cm : how far off the marker a press lands (std, cm).
    strength : relative spread of the touch's strength (0.3: +-30 %).
    max_rest : at most this many motion rows (evenly spaced).
    kinds : the kinds to return (default: every kind the inputs allow).
    """
    X = np.asarray(X, np.float64)
    y = np.asarray(y)
    classes, yi = np.unique(y, return_inverse=True)
    K, d = len(classes), X.shape[1]
    means = np.stack([X[yi == k].mean(axis=0) for k in range(K)])
    want = set(NUISANCE_KINDS if kinds is None else kinds)
    unknown = want - set(NUISANCE_KINDS)
    if unknown:
        raise ValueError(f"unknown nuisance kinds {sorted(unknown)}; choose from {sorted(NUISANCE_KINDS)}")
    out: dict[str, np.ndarray] = {}
    if "motion" in want and X_rest is not None and len(X_rest) >= 2:
        R = np.asarray(X_rest, np.float64)
        if R.shape[1] != d:
            raise ValueError(f"X_rest has {R.shape[1]} columns, X {d}; give both over the same inputs")
        if len(R) > max_rest:
            R = R[np.round(np.linspace(0, len(R) - 1, max_rest)).astype(int)]
        out["motion"] = (R - R.mean(axis=0)) / np.sqrt(len(R))
    if freqs_hz is not None:
        f = np.asarray(freqs_hz, np.float64)
        if f.shape != (d,):
            raise ValueError(f"freqs_hz must give the frequency of each of the {d} input columns, got shape {f.shape}")
        if "stretch" in want:
            out["stretch"] = stretch * _freq_derivative(means, f) / np.sqrt(K)
        if "tilt" in want and np.ptp(f) > 0:
            out["tilt"] = (tilt_db * (f - f.mean()) / np.ptp(f))[None, :]
    if "gain" in want:
        out["gain"] = np.full((1, d), gain_db)
    if "strength" in want:
        out["strength"] = strength * means / np.sqrt(K)
    if "aim" in want and positions_cm is not None:
        rows = []
        for k, (near, dist) in enumerate(neighbour_rings(positions_cm, K, circumference_cm)):
            for j, dj in zip(near, dist):
                rows.append((means[j] - means[k]) * min(1.0, aim_cm / dj) / np.sqrt(K * len(near)))
        if rows:
            out["aim"] = np.stack(rows)
    return out


# -- candidates -----------------------------------------------------------------------------------------------
def make_candidates(*, n_features: int | None = None, nuisance=None, C: float = 10.0) -> dict:
    """The localizer candidates validation chooses among, by name (unfitted scikit-learn estimators).

    ``nuisance``: rows of :func:`nuisance_directions` over the same inputs (stacked), for the metric head.
    """
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import Normalizer, StandardScaler
    from sklearn.svm import SVC

    cands = {
        "shrinkage LDA": ShrinkageLDA(),
        "level-removed LDA": make_pipeline(LevelRemoval(), ShrinkageLDA()),
        "normalized SVC": make_pipeline(Normalizer(), StandardScaler(), SVC(C=C)),
        "level-removed normalized SVC": make_pipeline(LevelRemoval(), Normalizer(), StandardScaler(), SVC(C=C)),
    }
    if nuisance is not None and len(nuisance):
        cands["metric head"] = make_pipeline(LevelRemoval(), ShrinkageLDA(nuisance=nuisance))
    return cands


# -- ONNX ------------------------------------------------------------------------------------------------------
def register_onnx_converters() -> None:
    """Teach skl2onnx these estimators: :class:`ShrinkageLDA` is converted as any linear classifier (its
    ``coef_`` and ``intercept_``; ``options={id(model): {"raw_scores": True}}`` gives the decision values),
    :class:`LevelRemoval` as ``X - (X B) B'``.  Call once before ``skl2onnx.to_onnx``."""
    from skl2onnx import update_registered_converter
    from skl2onnx.common.data_types import guess_numpy_type
    from skl2onnx.common.shape_calculator import calculate_linear_classifier_output_shapes
    from skl2onnx.operator_converters.linear_classifier import convert_sklearn_linear_classifier

    def level_shape(operator):
        operator.outputs[0].type = operator.inputs[0].type.__class__([None, operator.raw_operator.basis_.shape[0]])

    def level_convert(scope, operator, container):
        from skl2onnx.algebra.onnx_ops import OnnxMatMul, OnnxSub

        op = operator.raw_operator
        dtype = guess_numpy_type(operator.inputs[0].type)
        B = op.basis_.astype(dtype)
        x = operator.inputs[0]
        proj = OnnxMatMul(OnnxMatMul(x, B, op_version=container.target_opset), B.T.copy(), op_version=container.target_opset)
        OnnxSub(x, proj, op_version=container.target_opset, output_names=operator.outputs[:1]).add_to(scope, container)

    update_registered_converter(ShrinkageLDA, "SonicskinShrinkageLDA", calculate_linear_classifier_output_shapes,
                                convert_sklearn_linear_classifier, options={"zipmap": [True, False, "columns"],
                                                                            "nocl": [True, False],
                                                                            "raw_scores": [True, False]})
    update_registered_converter(LevelRemoval, "SonicskinLevelRemoval", level_shape, level_convert)
