"""Model outputs -> :class:`Predictions`: the one place a touch, a location, a position and a force are decided,
from an artifact's model entry and marker layout (:meth:`decide`: the graph's outputs and the stream's Alg. 2
reference).  Nothing here runs a model."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..force import energy_db, force_from_dict
from ..rig import Layout

__all__ = ["Predictions", "ScoreHead", "touch_statistic", "input_rms", "DETECTOR_BINS", "DETECTORS", "centroid", "softmax"]

#: The input-RMS detector reads the first (best, OSPA order) bins only, at most the paper's 300: beyond them are the
#: motion-sensitive bins (over 1,884 bins it missed 56 % of a moving random rig's touches, over 300 none).
DETECTOR_BINS = 300

#: Touch detectors of a closed-form head: ``input-rms`` (how far the inputs moved from the no-touch reference, the
#: default) or ``paper`` (the paper's rule: the largest calibrated score ``max(S - S_c)`` above a threshold).
DETECTORS = ("input-rms", "paper")


# -- the per-chirp decisions of one model: the one record every path returns
@dataclasses.dataclass
class Predictions:
    touch: np.ndarray        # (n,) bool
    location: np.ndarray     # (n,) location id (most likely marker); -1 during the boot calibration
    xy_cm: np.ndarray        # (n, 2) continuous estimate: probability-weighted centroid of nearby markers
    force_n: np.ndarray      # (n,) 0 where no touch is detected; NaN where the artifact has no force model
    confidence: np.ndarray   # (n,) probability of the chosen marker given a touch (net) / vote share (svm)
    scores: np.ndarray       # (n, N) per-location scores (net: probabilities; svm: calibrated S_final)
    calibrating: np.ndarray | None = None  # (n,) bool: boot calibration, no prediction (replays only)
    #: (n,) bool: the chirps Alg. 2 must not take as no-touch for its reference, where that differs from ``touch``
    #: (the network's ``either`` detector: its input-RMS part alone; None: ``touch``)
    reference_touch: np.ndarray | None = None

    def touched_for_reference(self) -> np.ndarray:
        """What Alg. 2 counts as touched when it picks the no-touch chirps of a reference refresh."""
        return self.touch if self.reference_touch is None else self.reference_touch

    def take(self, sel) -> Predictions:
        """The chirps ``sel`` (index, slice or mask)."""
        return Predictions(*(None if v is None else v[sel] for v in (getattr(self, f.name) for f in dataclasses.fields(self))))

    @classmethod
    def concat(cls, parts: list[Predictions]) -> Predictions:
        cols = [[getattr(p, f.name) for p in parts] for f in dataclasses.fields(cls)]
        return cls(*(None if any(v is None for v in c) else np.concatenate(c) for c in cols))

    @classmethod
    def boot(cls, n: int, n_locations: int) -> Predictions:
        """``n`` chirps of the boot calibration: no touch, no location (-1), no position (NaN)."""
        return cls(np.zeros(n, bool), np.full(n, -1), np.full((n, 2), np.nan), np.zeros(n), np.zeros(n),
                   np.zeros((n, n_locations)), np.ones(n, bool))

    def __len__(self) -> int:
        return len(self.touch)


def touch_statistic(V_cal: np.ndarray, n_locations: int, n_bins: int | None = None, *, detector: str = "input-rms"
                    ) -> np.ndarray:
    """The touch statistic of calibrated score vectors: ``input-rms`` (default), the RMS change (dB) of the first
    ``n_bins`` inputs from the reference (an RBF SVM gives the same scores to every input far from its training
    touches), or ``paper``, ``max(S - S_c)``."""
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


def softmax(z: np.ndarray) -> np.ndarray:
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


class ScoreHead:
    """The decisions of a closed-form model from its per-location scores ``S``; a subclass gives ``S`` and confidence."""

    calibrated = True  # Alg. 2 averages its score vectors (:meth:`scores`)

    def __init__(self, entry: dict, layout: Layout):
        self.layout, self.K = layout, len(layout)
        self.ids = np.asarray(layout.ids)
        self.detector = entry.get("detector", "input-rms")
        if self.detector not in DETECTORS:
            raise ValueError(f"detector must be one of {DETECTORS}, got {self.detector!r}")
        self.detector_bins = entry.get("detector_bins")
        self.threshold = float(entry["threshold"])
        self.reference_scores = np.asarray(entry["reference_scores"], np.float64)
        self.energy_ref_db = float(entry["energy_ref_db"])
        self.force_model = force_from_dict(entry["force"])

    def location_scores(self, outputs: list[np.ndarray]) -> np.ndarray:
        raise NotImplementedError

    def confidence(self, S: np.ndarray) -> np.ndarray:
        return softmax(S).max(axis=1)

    def weights(self, S: np.ndarray) -> np.ndarray:
        """Per-location weights of the position estimate (:func:`centroid`)."""
        return softmax(S)

    def scores(self, outputs: list[np.ndarray], inputs: np.ndarray) -> np.ndarray:
        """The score vector ``[S_1..S_K, inputs]`` of each chirp (what Alg. 2's ``S_c`` averages)."""
        return np.column_stack([self.location_scores(outputs), np.asarray(inputs, np.float64)])

    def decide(self, outputs: list[np.ndarray], inputs: np.ndarray, *, score_reference: np.ndarray | None = None,
               input_reference: np.ndarray | None = None) -> Predictions:
        V = self.scores(outputs, inputs)
        S = V[:, :self.K]
        idx = np.argmax(S, axis=1)
        V_cal = V - (self.reference_scores if score_reference is None else score_reference)
        touch = touch_statistic(V_cal, self.K, self.detector_bins, detector=self.detector) >= self.threshold
        E = energy_db(inputs, np.arange(inputs.shape[1])) - self.energy_ref_db
        f = self.force_model.predict(E, self.ids[idx], inputs=inputs)
        f = np.where(touch, np.clip(f, 0, None), 0.0)
        return Predictions(touch, self.ids[idx], centroid(self.weights(S), self.layout), f, self.confidence(S), V_cal[:, :self.K])
