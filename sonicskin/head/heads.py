"""Model outputs -> :class:`Predictions`: the one place a touch, a location, a position and a force are decided.

A head is built from an artifact's model entry (``skin.json``) and its marker layout; :meth:`decide`
takes the outputs of the model's ONNX graph on a block of model inputs and the stream's Alg. 2
reference.  Nothing here runs a model: :class:`sonicskin.runtime.SkinRuntime` runs the graph,
:class:`~sonicskin.head.stream.Stream` keeps the reference.
"""

from __future__ import annotations

import functools

import numpy as np

from ..force import energy_db, force_from_dict
from ..rig import Layout
from .predictions import Predictions

__all__ = ["SVMHead", "NetHead", "make_head", "score_vector", "touch_statistic", "ovr_scores_from_ovo",
           "DETECTOR_BINS", "DETECTORS", "centroid"]

#: The input-RMS detector reads the first (best, OSPA order) bins only, at most the paper's 300: with a gamma chosen
#: for localization (up to every usable bin) the extra bins are the motion-sensitive ones, and a statistic over
#: 1,884 bins missed 56 % of a moving random rig's touches where the 300-bin one missed none (design seed 1).
DETECTOR_BINS = 300

#: Touch detectors of the SVM head: ``input-rms`` (how far the inputs moved from the no-touch reference, the
#: default) or ``paper`` (the paper's rule: the largest calibrated score ``max(S - S_c)`` above a threshold).
DETECTORS = ("input-rms", "paper")

#: Touch decisions of the network head: its own touch logit (plus a validated ``bias``), the input-RMS detector
#: the SVM uses, or ``either`` of the two.
NET_DETECTORS = ("head", "input-rms", "either")


def ovr_scores_from_ovo(ovo: np.ndarray, n_classes: int) -> np.ndarray:
    """Per-class scores from the ``K (K-1) / 2`` pairwise SVM decision values.

    The same transform scikit-learn applies for ``decision_function_shape="ovr"``: votes plus the summed
    pairwise confidences squashed into ``(-1/3, 1/3)``, vectorised.  Computing it outside the model keeps the
    ONNX graph tiny (2 nodes for ovo vs ~2,400 for ovr).

    Parameters
    ----------
    ovo : (n, K (K-1) / 2) pairwise decision values, libsvm pair order; for K = 2 also scikit-learn's
        1-D binary decision values or skl2onnx's ``[d, -d]``.
    n_classes : K.

    Returns
    -------
    scores : (n, K) float64.
    """
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
    """For libsvm's pair order (0,1), (0,2), ..., (1,2), ...: ``P`` (+1 for the pair's first class, -1 for its second),
    and the one-hot first (``Vi``) and second (``Vj``) class of each pair; built once per class count (the live loop
    calls :func:`ovr_scores_from_ovo` every chirp of every link)."""
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


def score_vector(ovo: np.ndarray, n_locations: int, inputs: np.ndarray) -> np.ndarray:
    """Per chirp ``[S_1..S_K, inputs]``: what Alg. 2 calibrates, with one reference for both."""
    S = ovr_scores_from_ovo(pairwise(ovo, n_locations), n_locations)
    return np.column_stack([S, np.asarray(inputs, np.float64)])


def touch_statistic(V_cal: np.ndarray, n_locations: int, n_bins: int | None = None, *, detector: str = "input-rms"
                    ) -> np.ndarray:
    """The touch detection statistic of calibrated score vectors ``V_cal = V - S_c`` (:func:`score_vector`).

    ``input-rms`` (default): the RMS change (dB) of the model inputs from the no-touch reference.  The paper
    thresholds the calibrated per-location score ``max(S - S_c)`` (``paper``).  An RBF SVM trained on touches only
    gives the same decision values (its intercepts) to every input far from its training touches, at rest or under
    an unusually firm press, so a press at the location that wins the vote at rest goes unseen (measured: a 12 N
    press missed for 2 s on a 3-marker rig).  How far the OSPA bins moved from rest is what a touch does
    physically; that is thresholded.  ``n_bins``: over the first ``n_bins`` inputs only (the best bins, see
    :data:`DETECTOR_BINS`); ``None``: all.
    """
    V_cal = np.asarray(V_cal, np.float64)
    if detector == "paper":
        return np.max(V_cal[:, :n_locations], axis=1)
    if detector != "input-rms":
        raise ValueError(f"detector must be one of {DETECTORS}, got {detector!r}")
    inputs = V_cal[:, n_locations:] if n_bins is None else V_cal[:, n_locations:n_locations + n_bins]
    return np.sqrt(np.mean(np.square(inputs), axis=1))


def input_rms(inputs: np.ndarray, reference: np.ndarray | None, n_bins: int) -> np.ndarray:
    """RMS change (dB) of the first ``n_bins`` model inputs from ``reference`` (the no-touch inputs' mean)."""
    x = np.asarray(inputs, np.float64)[:, :n_bins]
    if reference is not None:
        x = x - np.asarray(reference, np.float64)[:n_bins]
    return np.sqrt(np.mean(np.square(x), axis=1))


def _softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=1, keepdims=True)


def centroid(w: np.ndarray, layout: Layout, k: int = 3) -> np.ndarray:
    """Probability-weighted centroid (n, 2) of the ``k`` most likely markers (wrapping around a tube)."""
    k = min(k, w.shape[1])
    top = np.argsort(w, axis=1)[:, -k:]
    ww = w[np.arange(len(w))[:, None], top]
    ww = ww / np.maximum(ww.sum(axis=1, keepdims=True), 1e-12)
    xy = layout.xy_cm[top]  # (n, k, 2)
    best = xy[:, -1:, :]
    d = xy - best
    C = layout.circumference_cm
    if C:
        d[..., 0] = (d[..., 0] + C / 2) % C - C / 2
    out = best[:, 0] + np.sum(ww[..., None] * d, axis=1)
    if C:
        out[:, 0] %= C
    return out


class SVMHead:
    """The SVM's decisions from its ONNX outputs ``[label, pairwise scores]``.

    Location: the argmax of the raw per-location scores ``S`` (votes plus confidences; subtracting ``S_c`` scrambles
    their argmax: measured 96 % raw vs 33 % calibrated on the simulated moving robot).  Touch: the detector
    (:data:`DETECTORS`) on ``S - S_c`` (Alg. 2: ``S_c`` from the stream, or the training session's).  Force: the
    artifact's force model at the chosen location.  Confidence: the share of pairwise votes won.
    """

    kind = "svm"

    def __init__(self, entry: dict, layout: Layout):
        self.layout, self.K = layout, len(layout)
        self.ids = np.asarray(layout.ids)
        self.detector = entry.get("detector", "input-rms")
        if self.detector not in DETECTORS:
            raise ValueError(f"SVM detector must be one of {DETECTORS}, got {self.detector!r}")
        self.detector_bins = entry.get("detector_bins")
        self.threshold = float(entry["threshold"])
        self.reference_scores = np.asarray(entry["reference_scores"], np.float64)
        self.energy_ref_db = float(entry["energy_ref_db"])
        self.force_model = force_from_dict(entry["force"])

    def scores(self, outputs: list[np.ndarray], inputs: np.ndarray) -> np.ndarray:
        """The score vector ``[S_1..S_K, inputs]`` of each chirp (what Alg. 2's ``S_c`` averages)."""
        return score_vector(outputs[1], self.K, inputs)

    def decide(self, outputs: list[np.ndarray], inputs: np.ndarray, *, score_reference: np.ndarray | None = None,
               input_reference: np.ndarray | None = None) -> Predictions:
        V = self.scores(outputs, inputs)
        S = V[:, :self.K]
        idx = np.argmax(S, axis=1)
        V_cal = V - (self.reference_scores if score_reference is None else score_reference)
        touch = touch_statistic(V_cal, self.K, self.detector_bins, detector=self.detector) >= self.threshold
        E = energy_db(inputs, np.arange(inputs.shape[1])) - self.energy_ref_db
        f = self.force_model.predict(E, self.ids[idx], inputs=inputs)
        conf = np.clip(np.max(S, axis=1) / max(self.K - 1, 1), 0, 1)  # share of pairwise votes won
        w = _softmax(4.0 * S)  # S counts votes: sharpen so the centroid stays among neighbours
        f = np.where(touch, np.clip(f, 0, None), 0.0)
        return Predictions(touch, self.ids[idx], centroid(w, self.layout), f, conf, V_cal[:, :self.K])


class NetHead:
    """The network's decisions from its ONNX outputs ``[logits (n, N + 1), force (n, N)]``.

    ``logits`` are log-probabilities of the N locations and (last) no touch.  Touch: by the entry's ``detector``
    (:data:`NET_DETECTORS`; absent: the head's own ``p(touch) >= 0.5``), the input-RMS statistic measured from the
    stream's no-touch inputs as the SVM head measures it.  Location: the most likely marker; confidence its
    probability given a touch; force: the force output at that marker.
    """

    kind = "net"

    def __init__(self, entry: dict, layout: Layout):
        self.layout, self.K = layout, len(layout)
        self.ids = np.asarray(layout.ids)
        d = entry.get("detector") or {"mode": "head"}
        if d.get("mode") not in NET_DETECTORS:
            raise ValueError(f"network detector mode must be one of {NET_DETECTORS}, got {d.get('mode')!r}")
        self.mode, self.bias = d["mode"], float(d.get("bias", 0.0))
        self.threshold = float(d.get("threshold", 0.0))
        ref = d.get("reference")
        self.reference = None if ref is None else np.asarray(ref, np.float64)
        self.detector_bins = int(d.get("bins", len(ref) if ref is not None else DETECTOR_BINS))

    def touch_logit(self, logits: np.ndarray) -> np.ndarray:
        """``log p(touch) / p(no touch)`` of (n, N + 1) logits."""
        from scipy.special import logsumexp

        logits = np.asarray(logits, np.float64)
        return logsumexp(logits[:, :-1], axis=1) - logits[:, -1]

    def decide(self, outputs: list[np.ndarray], inputs: np.ndarray, *, score_reference: np.ndarray | None = None,
               input_reference: np.ndarray | None = None) -> Predictions:
        logits, force_all = outputs[0], outputs[1]
        p = _softmax(np.asarray(logits, np.float64))
        place = p[:, :-1]
        idx = np.argmax(place, axis=1)
        touch = self.touch_logit(logits) + self.bias >= 0
        by_rms = None
        if self.mode != "head":
            ref = self.reference if input_reference is None else input_reference
            by_rms = input_rms(inputs, ref, min(self.detector_bins, inputs.shape[1])) >= self.threshold
            touch = by_rms if self.mode == "input-rms" else touch | by_rms
        f = np.take_along_axis(np.asarray(force_all, np.float64), idx[:, None], axis=1)[:, 0]
        conf = place[np.arange(len(idx)), idx] / np.maximum(place.sum(axis=1), 1e-12)
        f = np.where(touch, np.clip(f, 0, None), 0.0)
        # Alg. 2's no-touch chirps by the physical statistic alone: the head's logit, trained on one session, calls rest
        # chirps touched once warm-up has moved them, and an OR with it then blocked every reference refresh (measured:
        # drift-2h simulator seed 1, from the 5th session on every rest chirp "touched", one reference in 2 h)
        return Predictions(touch, self.ids[idx], centroid(place, self.layout), f, conf, place,
                           reference_touch=by_rms if self.mode == "either" else None)


def make_head(kind: str, entry: dict, layout: Layout) -> SVMHead | NetHead:
    """The head of an artifact's model ``kind`` (``"svm"`` or ``"net"``)."""
    heads = {"svm": SVMHead, "net": NetHead}
    if kind not in heads:
        raise ValueError(f"model kind must be one of {sorted(heads)}, got {kind!r}")
    return heads[kind](entry, layout)
