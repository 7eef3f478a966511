"""The paper's model: OSPA's bins -> scaler -> RBF SVM (one-vs-one), the Alg. 2 reference on its scores, the touch
detector and the force model around it (:mod:`.closed`).  Torch-free: ``fit-svm`` builds it on a robot's own PC."""

from __future__ import annotations

import functools
import time
import warnings

import numpy as np
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from ..dataset import write_file
from ..head import ScoreHead
from ..head.heads import softmax
from ..parity import decisions_parity, ort_session, parity_bound, require_parity
from ..selection import detection_on_validation, select_on_inputs
from . import Fitted, ModelKind, register
from .closed import SCORE_KEYS, check_score_entry, score_entry

__all__ = ["SVMKind", "SVMHead", "ovr_scores_from_ovo", "pairwise", "ovo_decision", "fit_pipeline", "export_pipeline"]


def ovr_scores_from_ovo(ovo: np.ndarray, n_classes: int) -> np.ndarray:
    """Per-class scores (n, K) from pairwise decision values: scikit-learn's ``ovr`` transform, outside the ONNX graph."""
    ovo = np.asarray(ovo, dtype=np.float64)
    if n_classes == 2 and ovo.ndim == 2 and ovo.shape[1] == 2:
        ovo = ovo[:, 0]  # skl2onnx's binary SVM output is [d, -d] with scikit-learn's d
    if ovo.ndim == 1:
        # scikit-learn's binary decision value is positive for classes_[1]; libsvm's pair value for the pair's first
        ovo = -ovo[:, None]
    P, Vi, Vj = _pair_matrices(int(n_classes))
    if ovo.ndim != 2 or ovo.shape[1] != P.shape[0]:
        raise ValueError(f"expected (n, {P.shape[0]}) pairwise scores for {n_classes} classes, got {ovo.shape}")
    conf = ovo @ P
    win_i = (ovo > 0).astype(np.float64)  # libsvm votes for i when the decision value is positive
    votes = win_i @ Vi + (1.0 - win_i) @ Vj
    return votes + conf / (3.0 * (np.abs(conf) + 1.0))


@functools.lru_cache(maxsize=32)
def _pair_matrices(n_classes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """libsvm's pair order as matrices: ``P`` (+1 a pair's first class, -1 its second), one-hot ``Vi``, ``Vj``."""
    i, j = np.triu_indices(n_classes, k=1)
    rows = np.arange(i.size)
    P = np.zeros((i.size, n_classes))
    P[rows, i] = 1.0
    P[rows, j] = -1.0
    Vi = np.zeros((i.size, n_classes)); Vi[rows, i] = 1.0
    Vj = np.zeros((i.size, n_classes)); Vj[rows, j] = 1.0
    for m in (P, Vi, Vj):
        m.setflags(write=False)
    return P, Vi, Vj


def pairwise(ovo: np.ndarray, n_locations: int) -> np.ndarray:
    """Pairwise decision values (n, K (K-1) / 2) in libsvm's sign convention, from scikit-learn or skl2onnx."""
    ovo = np.asarray(ovo, np.float64)
    if n_locations == 2:
        d = ovo[:, 0] if ovo.ndim == 2 else ovo  # scikit-learn's d (n,) or skl2onnx's [d, -d]
        return -d[:, None]
    return ovo


def ovo_decision(pipe, X: np.ndarray, block: int = 2048) -> np.ndarray:
    """``pipe.decision_function(X)`` of a scaler + RBF ``SVC(ovo)``, one BLAS product per block (10-20x libsvm's speed)."""
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


class SVMHead(ScoreHead):
    """The SVM's decisions: ``S`` are votes plus confidences, the confidence the share of pairwise votes won."""

    def location_scores(self, outputs):
        return ovr_scores_from_ovo(pairwise(outputs[1], self.K), self.K)

    def confidence(self, S):
        return np.clip(np.max(S, axis=1) / max(self.K - 1, 1), 0, 1)

    def weights(self, S):
        return softmax(4.0 * S)  # S counts votes: sharpen so the centroid stays among neighbours


def fit_pipeline(X: np.ndarray, cls: np.ndarray, n_locations: int, *, C: float = 10.0, kernel_width: float | None = None):
    """Scaler + RBF ``SVC(ovo)`` on the touch chirps of ``X``, RBF gamma ``kernel_width / n_features`` (``None``: "scale")."""
    touch = cls < n_locations
    pipe = Pipeline([("scale", StandardScaler()), ("svc", SVC(kernel="rbf", C=C, decision_function_shape="ovo",
                                                              gamma="scale" if kernel_width is None else kernel_width / X.shape[1]))])
    pipe.fit(X[touch], cls[touch])
    if len(pipe.classes_) != n_locations:
        raise ValueError(f"training data touches {len(pipe.classes_)} of the {n_locations} locations; "
                         f"record every location at least once")
    return pipe


def export_pipeline(pipe, path, X_check: np.ndarray) -> dict:
    """scikit-learn scaler + SVC(ovo) -> ONNX (2 nodes), then parity on ``X_check``."""
    import sklearn
    from skl2onnx import to_onnx

    n = len(pipe.classes_)
    with warnings.catch_warnings():  # skl2onnx reads SVC's deprecated probA_/probB_
        warnings.simplefilter("ignore", FutureWarning)
        onx = to_onnx(pipe, X_check[:1].astype(np.float32), options={SVC: {"zipmap": False}}, target_opset=17)
    # skl2onnx lists the opsets in set order (it changes with PYTHONHASHSEED): sorted, the same inputs give the same bytes
    ops = sorted((o.domain, o.version) for o in onx.opset_import)
    del onx.opset_import[:]
    for domain, version in ops:
        onx.opset_import.add(domain=domain, version=version)
    write_file(path, onx.SerializeToString())
    sess = ort_session(path)
    _, ovo = sess.run(None, {sess.get_inputs()[0].name: X_check.astype(np.float32)})
    ref_ovo = pipe.decision_function(X_check.astype(np.float32))
    S, S_ref = ovr_scores_from_ovo(ovo, n), ovr_scores_from_ovo(ref_ovo, n)
    # The runtime's location is argmax S (votes, ties by confidence).  A pairwise decision within float32 rounding of
    # zero can vote the other way in onnxruntime than in scikit-learn (float64) and move a score by a whole vote: such
    # chirps are near ties, held to their decision values only.
    d, d_ref = pairwise(ovo, n), pairwise(ref_ovo, n)
    tie = (np.abs(d_ref) < parity_bound(d_ref)).any(axis=1)
    parity = decisions_parity({"scores": S, "decision": d}, {"scores": S_ref, "decision": d_ref}, label="scores",
                              vote_tie=tie, every_chirp=("decision",))
    return require_parity(parity, "svm.onnx", "scikit-learn's SVM", len(X_check),
                          f"skl2onnx wrote differently from scikit-learn {sklearn.__version__}; reinstall the package's "
                          f"dependencies (pip install -c constraints.txt -e .) and fit again")


def _finite(*v) -> bool:
    return all(x is not None and np.isfinite(x) for x in v)


class SVMKind(ModelKind):
    name, label, graph, file = "svm", "SVM", "svc-ovo", "svm.onnx"
    keys = SCORE_KEYS
    selection_keys = ("svm", "force", "detection")

    def outputs(self, n_loc):
        return [None, n_loc * (n_loc - 1) // 2 if n_loc > 2 else 2]

    def output_text(self, n_loc):
        return f"a label and {self.outputs(n_loc)[1]} pairwise decision values for {n_loc} locations"

    def declared_widths(self, k, n_loc):
        # skl2onnx declares the SVC's score output as (batch, n_classes) even with decision_function_shape="ovo"
        return (n_loc,)

    def check_entry(self, doc, m, field, *, n_in, layout_ids):
        check_score_entry(doc, m, field, n_in=n_in, layout_ids=layout_ids)

    def head(self, entry, layout):
        return SVMHead(entry, layout)

    def fit(self, data, *, fitted, selection=None, log=print, select: bool = True, C: float = 10.0,
            kernel_width: float | None = None, force_model: str = "fourier1", detector: str = "input-rms") -> Fitted:
        """Scaler + SVC on the training touch chirps, then its reference, detector and force (``select``: validated)."""
        d = data.narrow(data.n_svm)
        train, val = d.rows("train"), d.rows("val")
        n = d.n_locations
        if selection is not None:
            sel = dict(selection)
        elif select:
            sel = select_on_inputs(d.X, d.table, cls=d.cls, train_mask=train, val_mask=val, n_locations=n,
                                   location_ids=d.layout.ids, selection=d.selection, min_force_n=d.min_force_n,
                                   key=self.name, log=log)
        else:
            sel = dict(d.selection)
        chosen = select or selection is not None
        sp = (sel.get("svm") or {}).get("params", {}) if chosen else {}
        fsel = (sel.get("force") or {}) if chosen else {}
        width = sp.get("kernel_width", kernel_width)
        X, cls = d.X[train], d.cls[train]
        t0 = time.perf_counter()
        pipe = fit_pipeline(X, cls, n, C=sp.get("C", C), kernel_width=width)
        S = ovr_scores_from_ovo(pairwise(ovo_decision(pipe, X), n), n)
        entry = score_entry(S, X, cls, d.force[train], d.quiet[train], n_locations=n, location_ids=d.layout.ids,
                            force_model=fsel.get("model", force_model), force_alpha=fsel.get("alpha") or 10.0,
                            detector=detector)
        fit_s = time.perf_counter() - t0
        if select and selection is None and entry["detection"] and val.any() and detector == "input-rms":
            det = detection_on_validation(d.X, d.table, cls=d.cls, val_mask=val, n_locations=n, threshold=entry["threshold"])
            if det is not None:  # what the threshold does on the validation session
                sel["detection"] = det
        return Fitted(pipe, entry, X.shape[1], {k: v for k, v in sel.items() if k in self.selection_keys}, fit_s)

    def export(self, fit, path, X_check):
        return export_pipeline(fit.model, path, X_check)

    def selection_lines(self, sel):
        out = []
        loc = sel.get("svm") or {}
        if loc.get("status") == "validated":
            p, e = loc["params"], loc["estimate"]
            lo, hi = e["ci95"]
            ci = f", 95 % interval over presses {lo:.0%}-{hi:.0%}" if _finite(lo, hi) else ""
            paper = (f"; the paper's gamma 300 / C 10: {loc['paper_accuracy']:.0%}" if loc.get("paper_accuracy") is not None else "")
            out.append(f"chose gamma {p['n_bins']}, C {p['C']:g}, kernel width {p['kernel_width']:g} x 'scale' "
                       f"(validation accuracy {e['accuracy']:.0%} on {e['n_presses']} presses, {loc['how']}{ci}{paper})")
            lc = loc.get("learning_curve")
            if lc and lc["accuracy"]:
                pts = ", ".join(f"{k}: {a:.0%}" for k, a in zip(lc["presses_per_location"], lc["accuracy"]))
                out.append(f"learning curve (presses per location: accuracy) {pts}; {lc['verdict']}")
        elif loc:
            out.append(f"gamma {loc['params']['n_bins']} (the paper's; {loc['reason']})")
        f = sel.get("force") or {}
        if f.get("status") == "validated":
            lo, hi = f["estimate"]["press_rmse_ci95"]
            ci = f", mean per-press RMSE 95 % interval {lo:.2f}-{hi:.2f} N" if _finite(lo, hi) else ""
            name = {"pooled-ridge": f"pooled ridge (alpha {f.get('alpha') or 0:g})", "pooled-svr": "pooled SVR"}.get(
                f["model"], "per-location Fourier-1")
            out.append(f"force: {name}, expected RMSE {f['estimate']['rmse_n']:.2f} N on presses not trained on ({f['how']}"
                       f"{ci}; Fourier-1 {f['fourier1_rmse_n']:.2f} N, a constant {f['constant_rmse_n']:.2f} N)")
        elif f.get("reason"):
            out.append(f"force: {f['reason']}")
        d = sel.get("detection") or {}
        if d.get("threshold") is not None and d.get("missed_touch_rate") is not None:
            out.append(f"detection threshold {d['threshold']:.3f} dB RMS ({d['how']}: missed {d['missed_touch_rate']:.1%}, "
                       f"false {d['false_touch_rate']:.1%})")
        return out


register(SVMKind())
