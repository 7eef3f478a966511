"""The closed-form model: shrinkage LDA on OSPA's best bins, each chirp's level removed or scaled to unit length.

Linear discriminant analysis with one within-marker covariance shared by every marker (Ledoit-Wolf shrunk, as
scikit-learn's ``LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto")``, computed in the sample space:
:class:`sonicskin.nuisance.ShrinkageLDA`) learns what varies between two presses at one marker from all markers at
once, which an RBF SVM with one press per marker cannot.  Its bins (the first ``k`` in OSPA's order) and the per-chirp
normalisation (none, the chirp's mean dB removed, or the chirp scaled to unit length) are chosen on the validation
presses (:meth:`sonicskin.fit.TrainingData.folds`); with none, the default measured across the random rig family
(:data:`DEFAULTS`).  Its scores go through the same head as the SVM's (:class:`~sonicskin.head.ScoreHead`), and the
network starts from it (its ``LDA`` location layer is this model, frozen).
"""

from __future__ import annotations

import time

import numpy as np

from ..dataset import write_file
from ..head import ScoreHead
from ..nuisance import ShrinkageLDA
from ..parity import decisions_parity, ort_session, require_parity
from . import BASELINE, Fitted, ModelKind, register
from .closed import SCORE_KEYS, check_score_entry, score_entry

__all__ = ["LDAKind", "LDAHead", "NORMS", "DEFAULTS", "normalize", "linear_scores", "fit_lda", "lda_candidates"]

#: per-chirp normalisations: none, the chirp's mean dB removed (a gain or a firmer press moves every bin alike),
#: the chirp scaled to unit length (its shape, not its strength)
NORMS = {"none": "as measured", "level": "level removed", "unit": "unit length"}
#: bins the candidates read (OSPA's order; None: every usable bin)
BIN_GRID = (1000, None)
#: The configuration when nothing can validate (one session, one press per marker), per input mode: the best mean and
#: worst case over the 30 design rigs of the random family, train s000, test s002 s003 (benchmarks/bench_default.py,
#: stored result ``default``): relative inputs 1000 bins unit length 92.4 % (worst 64 %; every bin as measured 90.3 %,
#: the package SVM 82.8 %); absolute inputs (touch-only tables) every bin unit length 87.2 % (as measured 81.2 %).
DEFAULTS = {"relative": (1000, "unit"), "absolute": (None, "unit")}


def normalize(X: np.ndarray, norm: str) -> np.ndarray:
    X = np.asarray(X, np.float64)
    if norm == "level":
        return X - X.mean(axis=1, keepdims=True)
    if norm == "unit":
        return X / np.maximum(np.linalg.norm(X, axis=1, keepdims=True), 1e-12)
    return X


def linear_scores(lda) -> tuple[np.ndarray, np.ndarray]:
    """``(W (K, d), b (K,))``: the LDA's per-class scores ``x W' + b`` (a binary LDA's one row expanded)."""
    W, b = np.asarray(lda.coef_, np.float64), np.asarray(lda.intercept_, np.float64)
    if W.shape[0] == 1:  # scikit-learn's binary convention: one row, positive for classes_[1]
        W, b = np.vstack([-W / 2, W / 2]), np.r_[-b / 2, b / 2]
    return W, b


def fit_lda(X: np.ndarray, y: np.ndarray, k: int, norm: str):
    """Shrinkage LDA on the first ``k`` inputs of the touch chirps ``X``, normalised by ``norm``."""
    return ShrinkageLDA().fit(normalize(np.asarray(X)[:, :k], norm), y)


def _name(k: int, n_in: int, norm: str) -> str:
    return f"{'every bin' if k >= n_in else f'{k} bins'}, {NORMS[norm]}"


def lda_candidates(n_in: int) -> list[tuple[int, str]]:
    """``(k, norm)`` of every candidate on ``n_in`` inputs (each once)."""
    ks = dict.fromkeys(n_in if b is None else min(b, n_in) for b in BIN_GRID)
    return [(k, norm) for k in ks for norm in NORMS]


def choose(data, log=None) -> dict:
    """The bins and normalisation chosen on presses not trained on (:meth:`sonicskin.fit.TrainingData.folds`): the
    best mean accuracy compared at whole percent, ties to the measured default; the default without folds."""
    n_in, n = data.X.shape[1], data.n_locations
    dk, dnorm = DEFAULTS[data.spec.mode]
    default = (n_in if dk is None else min(dk, n_in), dnorm)
    folds, how = data.folds()
    if not folds:
        return {"status": "default", "k": default[0], "norm": default[1], "name": _name(default[0], n_in, default[1]),
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
        return {"status": "default", "k": default[0], "norm": default[1], "name": _name(default[0], n_in, default[1]),
                "how": f"{how}: a fold lacks a location, the measured default"}
    best = max(scores, key=lambda c: (round(100 * scores[c]), c == default))
    return {"status": "validated", "k": int(best[0]), "norm": best[1], "name": _name(best[0], n_in, best[1]),
            "accuracy": scores[best], "scores": {_name(k, n_in, nm): v for (k, nm), v in scores.items()}, "how": how}


class LDAHead(ScoreHead):
    """The LDA's decisions from its ONNX output (its per-location scores): location the best score, confidence its
    probability (softmax), touch and force as the SVM's (:class:`~sonicskin.head.ScoreHead`)."""

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
        W, b = linear_scores(lda)
        svm = fitted.get(BASELINE)
        fsel = (svm.selection.get("force") or {}) if svm is not None else {}
        entry = score_entry(normalize(X, norm) @ W.T + b, X, cls, data.force[train], data.quiet[train], n_locations=n,
                            location_ids=data.layout.ids, force_model=fsel.get("model", "fourier1"),
                            force_alpha=fsel.get("alpha") or 10.0, force_cols=data.n_svm)
        return Fitted(lda, {**entry, "norm": norm}, k, {"lda": sel}, time.perf_counter() - t0)

    def export(self, fit, path, X_check):
        """The LDA as an ONNX graph (the normalisation, then one Gemm), then parity of its scores and location on
        ``X_check`` against numpy's."""
        import onnx
        from onnx import TensorProto, helper, numpy_helper

        W, b = linear_scores(fit.model)
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
        nodes.append(helper.make_node("Gemm", [x, "W", "b"], ["scores"], transB=1))
        init = [numpy_helper.from_array(W.astype(np.float32), "W"), numpy_helper.from_array(b.astype(np.float32), "b"),
                numpy_helper.from_array(np.array([1e-12], np.float32), "eps")]
        graph = helper.make_graph(nodes, "shrinkage_lda", [helper.make_tensor_value_info("inputs", TensorProto.FLOAT, ["batch", d])],
                                  [helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["batch", K])], init)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="sonicskin")
        onnx.checker.check_model(model)
        write_file(path, model.SerializeToString())
        sess = ort_session(path)
        got = sess.run(None, {sess.get_inputs()[0].name: X_check.astype(np.float32)})[0]
        ref = normalize(X_check.astype(np.float32), norm) @ W.T + b
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
