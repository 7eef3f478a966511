"""The closed-form model: shrinkage LDA on OSPA's best bins, each chirp's level removed or scaled to unit length.

One within-marker covariance shared by every marker learns what varies between two presses at one marker from all
markers at once, which an RBF SVM with one press per marker cannot.  The network's ``lda`` layer is this model, frozen."""

from __future__ import annotations

import numbers
import time

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.linear_model._base import LinearClassifierMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import validate_data

from ..dataset import write_file
from ..head import ScoreHead
from ..parity import decisions_parity, ort_session, require_parity
from . import BASELINE, Fitted, ModelKind, register
from .closed import SCORE_KEYS, check_score_entry, score_entry

__all__ = ["LDAKind", "LDAHead", "ShrinkageLDA", "NORMS", "DEFAULTS", "normalize", "linear_scores", "fit_lda",
           "lda_candidates", "ledoit_wolf_shrinkage_gram"]

#: per-chirp normalisations: none, the chirp's mean dB removed (a gain or a firmer press moves every bin alike),
#: the chirp scaled to unit length (its shape, not its strength)
NORMS = {"none": "as measured", "level": "level removed", "unit": "unit length"}
#: bins the candidates read (OSPA's order; None: every usable bin)
BIN_GRID = (1000, None)
#: The configuration when nothing can validate (one session, one press per marker), per input mode: the best mean and
#: worst case over the 30 design rigs of the random family, train s000, test s002 s003 (benchmarks/bench_default.py,
#: stored result ``default``): relative inputs 1000 bins unit length 92.4 % (worst 64 %; every bin as measured 90.3 %,
#: the package SVM 82.8 %); absolute inputs (touch-only tables) every bin unit length 87.2 % (as measured 81.2 %).
#: Folds inside the one session (each press's early chirps against its late ones) chose worse there (-0.1, -0.7 points).
DEFAULTS = {"relative": (1000, "unit"), "absolute": (None, "unit")}


def ledoit_wolf_shrinkage_gram(Z: np.ndarray) -> float:
    """Ledoit-Wolf shrinkage of the centred rows ``Z`` (n, d) from the Gram matrix: sklearn's value in O(n^2 d)."""
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
    """Linear discriminant analysis with a shrunk within-class covariance: scikit-learn's
    ``LinearDiscriminantAnalysis(solver="lsqr", shrinkage=shrinkage)`` (same covariance, same ``coef_`` and
    ``intercept_`` up to rounding, ``tests/test_lda.py``), solved with the Woodbury identity in the space of the
    training samples, so 5,000 bins and a few hundred chirps take milliseconds instead of seconds and hundreds of MB.
    ``shrinkage``: "auto" (Ledoit-Wolf per class on standardised features) or a fixed value in [0, 1]; ``priors``:
    default the class proportions.  Fitted: ``classes_``, ``means_``, ``priors_``, ``shrinkage_`` (per class),
    ``coef_``, ``intercept_``, ``n_features_in_``."""

    def __init__(self, shrinkage="auto", priors=None):
        self.shrinkage = shrinkage
        self.priors = priors

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



def normalize(X: np.ndarray, norm: str) -> np.ndarray:
    X = np.asarray(X, np.float64)
    if norm == "level":
        return X - X.mean(axis=1, keepdims=True)
    if norm == "unit":
        return X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-12)
    return X


def linear_scores(lda, margin: float = 8.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(W, b, c)``: the LDA's scores ``(x - c) W' + b``, scaled so the best leads the second by ``margin`` at the means."""
    W, b = np.asarray(lda.coef_, np.float64), np.asarray(lda.intercept_, np.float64)
    if W.shape[0] == 1:  # scikit-learn's binary convention: one row, positive for classes_[1]
        W, b = np.vstack([-W / 2, W / 2]), np.r_[-b / 2, b / 2]
    M = np.asarray(lda.means_, np.float64)
    c = np.asarray(lda.priors_, np.float64) @ M
    b = b + W @ c
    top2 = np.sort((M - c) @ W.T + b, axis=1)[:, -2:]
    gap = float(np.median(top2[:, 1] - top2[:, 0]))
    scale = margin / gap if gap > 0 else 1.0
    return W * scale, b * scale, c


def fit_lda(X: np.ndarray, y: np.ndarray, k: int, norm: str):
    """Shrinkage LDA on the first ``k`` inputs of the touch chirps ``X``, normalised by ``norm``."""
    return ShrinkageLDA().fit(normalize(np.asarray(X)[:, :k], norm), y)


def candidate_name(k: int, n_in: int, norm: str) -> str:
    return f"{'every bin' if k >= n_in else f'{k} bins'}, {NORMS[norm]}"


def lda_candidates(n_in: int) -> list[tuple[int, str]]:
    """``(k, norm)`` of every candidate on ``n_in`` inputs (each once)."""
    ks = dict.fromkeys(n_in if b is None else min(b, n_in) for b in BIN_GRID)
    return [(k, norm) for k in ks for norm in NORMS]


def choose(data, log=None) -> dict:
    """The bins and normalisation chosen on presses not trained on (whole percent, ties to the default)."""
    n_in, n = data.X.shape[1], data.n_locations
    dk, dnorm = DEFAULTS[data.spec.mode]
    default = (n_in if dk is None else min(dk, n_in), dnorm)
    folds, how = data.folds()
    if not folds:
        return {"status": "default", "k": default[0], "norm": default[1], "name": candidate_name(default[0], n_in, default[1]),
                "how": f"{how}: the default measured across the random rig family"}
    scores = {}
    for k, norm in lda_candidates(n_in):
        accs = []
        for fit_rows, held in folds:
            tr, te = fit_rows & (data.cls < n), held & (data.cls < n)
            if np.unique(data.cls[tr]).size < n or not te.any():
                break
            accs.append(float(np.mean(fit_lda(data.X[tr], data.cls[tr], k, norm).predict(
                normalize(data.X[te][:, :k], norm)) == data.cls[te])))
        else:
            scores[(k, norm)] = float(np.mean(accs))
    if not scores:
        return {"status": "default", "k": default[0], "norm": default[1], "name": candidate_name(default[0], n_in, default[1]),
                "how": f"{how}: a fold lacks a location, the measured default"}
    best = max(scores, key=lambda c: (round(100 * scores[c]), c == default))
    return {"status": "validated", "k": int(best[0]), "norm": best[1], "name": candidate_name(best[0], n_in, best[1]),
            "accuracy": scores[best], "scores": {candidate_name(k, n_in, nm): v for (k, nm), v in scores.items()}, "how": how}


class LDAHead(ScoreHead):
    """The LDA's decisions: location the best score, confidence its softmax, touch and force as the SVM's."""

    def location_scores(self, outputs):
        return np.asarray(outputs[0], np.float64)


class LDAKind(ModelKind):
    name, label, graph, file = "lda", "LDA", "shrinkage-lda", "lda.onnx"
    keys = SCORE_KEYS | {"norm"}
    selection_keys = ("lda",)
    requires = (BASELINE,)  # its force model is the SVM's validated choice

    def outputs(self, n_loc):
        return [n_loc]

    def output_text(self, n_loc):
        return f"scores (batch, {n_loc})"

    def check_entry(self, doc, m, field, *, n_in, layout_ids):
        doc.choice(doc.get(m, "norm", field), f"{field}.norm", NORMS)
        check_score_entry(doc, m, field, n_in=n_in, layout_ids=layout_ids)

    def head(self, entry, layout):
        return LDAHead(entry, layout)

    def fit(self, data, *, fitted, selection=None, log=print) -> Fitted:
        sel = dict(selection["lda"]) if selection else choose(data, log)
        k, norm = int(min(sel["k"], data.X.shape[1])), sel["norm"]
        train = data.rows("train")
        X, cls, n = data.X[train][:, :k], data.cls[train], data.n_locations
        touch = cls < n
        t0 = time.perf_counter()
        if np.unique(cls[touch]).size != n:
            raise ValueError(f"training data touches {np.unique(cls[touch]).size} of the {n} locations; "
                             f"record every location at least once")
        lda = fit_lda(X[touch], cls[touch], k, norm)
        W, b, c = linear_scores(lda)
        svm = fitted.get(BASELINE)
        fsel = (svm.selection.get("force") or {}) if svm is not None else {}
        entry = score_entry((normalize(X, norm) - c) @ W.T + b, X, cls, data.force[train], data.quiet[train], n_locations=n,
                            location_ids=data.layout.ids, force_model=fsel.get("model", "fourier1"),
                            force_alpha=fsel.get("alpha") or 10.0, force_cols=data.n_svm)
        return Fitted(lda, {**entry, "norm": norm}, k, {"lda": sel}, time.perf_counter() - t0)

    def export(self, fit, path, X_check):
        """The LDA as an ONNX graph (normalisation, centre, one Gemm), then parity of its scores and location."""
        import onnx
        from onnx import TensorProto, helper, numpy_helper

        W, b, c = linear_scores(fit.model)
        K, d = W.shape
        norm = fit.entry["norm"]
        nodes, x = [], "inputs"
        if norm == "level":
            nodes += [helper.make_node("ReduceMean", [x], ["mean"], axes=[1], keepdims=1), helper.make_node("Sub", [x, "mean"], ["z"])]
            x = "z"
        elif norm == "unit":
            nodes += [helper.make_node("ReduceL2", [x], ["l2"], axes=[1], keepdims=1),
                      helper.make_node("Max", ["l2", "eps"], ["l2e"]), helper.make_node("Div", [x, "l2e"], ["z"])]
            x = "z"
        nodes += [helper.make_node("Sub", [x, "c"], ["zc"]), helper.make_node("Gemm", ["zc", "W", "b"], ["scores"], transB=1)]
        init = [numpy_helper.from_array(W.astype(np.float32), "W"), numpy_helper.from_array(b.astype(np.float32), "b"),
                numpy_helper.from_array(c.astype(np.float32), "c"),
                numpy_helper.from_array(np.array([1e-12], np.float32), "eps")]
        graph = helper.make_graph(nodes, "shrinkage_lda", [helper.make_tensor_value_info("inputs", TensorProto.FLOAT, ["batch", d])],
                                  [helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["batch", K])], init)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="sonicskin")
        onnx.checker.check_model(model)
        write_file(path, model.SerializeToString())
        sess = ort_session(path)
        got = sess.run(None, {sess.get_inputs()[0].name: X_check.astype(np.float32)})[0]
        ref = (normalize(X_check.astype(np.float32), norm) - c) @ W.T + b
        parity = decisions_parity({"scores": got}, {"scores": ref}, label="scores")
        return require_parity(parity, "lda.onnx", "the LDA", len(X_check),
                              f"onnx {onnx.__version__} wrote the graph differently; reinstall the package's dependencies")

    def selection_lines(self, sel):
        s = sel.get("lda") or {}
        if not s:
            return []
        if s.get("status") == "validated":
            return [f"LDA: {s['name']} ({s['how']}: " + ", ".join(f"{k} {v:.0%}" for k, v in s["scores"].items()) + ")"]
        return [f"LDA: {s['name']} ({s['how']})"]


register(LDAKind())
