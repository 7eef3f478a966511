"""The network's runtime half: its head and its ``skin.json`` entry (its fit and export need torch:
:mod:`sonicskin.training.kind`, through the ``sonicskin.kinds`` entry point)."""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from ..force import energy_db, force_from_dict
from ..head import DETECTOR_BINS, Predictions, input_rms
from ..head.heads import centroid, softmax
from ..rig import Layout
from . import BASELINE, CLOSED_FORM, ModelKind, register

__all__ = ["NetKind", "NetHead", "NET_DETECTORS", "touch_logit"]

#: Touch decisions of the network head: its own touch logit (plus a validated ``bias``), the input-RMS detector
#: the SVM uses, or ``either`` of the two.
NET_DETECTORS = ("head", "input-rms", "either")


def touch_logit(logits: np.ndarray) -> np.ndarray:
    """``log p(touch) / p(no touch)`` of (n, N + 1) logits."""
    logits = np.asarray(logits, np.float64)
    return logsumexp(logits[:, :-1], axis=1) - logits[:, -1]


class NetHead:
    """The network's decisions from its ONNX outputs ``[logits (n, N + 1), force (n, N)]``: touch by the entry's
    ``detector`` (:data:`NET_DETECTORS`; absent: ``p(touch) >= 0.5``), the most likely marker, the force there or (an
    entry with ``force``) the SVM's validated force model on the first ``force_bins`` inputs.  Training chooses the
    detector and the force by calling :meth:`touch` and :meth:`force`, so what it chooses is what runs."""

    calibrated = False  # Alg. 2 gives it the stream's no-touch inputs, not score vectors

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
        self.force_model = force_from_dict(entry["force"]) if "force" in entry else None
        self.force_bins, self.energy_ref_db = int(entry.get("force_bins", 0)), float(entry.get("energy_ref_db", 0.0))

    def force(self, force_all: np.ndarray, idx: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The force (N) at the markers ``idx``: the graph's force output there, or the closed-form model's."""
        if self.force_model is None:
            return np.take_along_axis(np.asarray(force_all, np.float64), idx[:, None], axis=1)[:, 0]
        x = np.asarray(inputs, np.float64)[:, :self.force_bins]
        E = energy_db(x, np.arange(x.shape[1])) - self.energy_ref_db
        return self.force_model.predict(E, self.ids[idx], inputs=x)

    def touch(self, logits: np.ndarray, inputs: np.ndarray, input_reference: np.ndarray | None = None):
        """``(touch, by_rms)`` per chirp: the decision and its input-RMS part (``None`` for mode ``head``)."""
        touch = touch_logit(logits) + self.bias >= 0
        by_rms = None
        if self.mode != "head":
            ref = self.reference if input_reference is None else input_reference
            by_rms = input_rms(inputs, ref, min(self.detector_bins, inputs.shape[1])) >= self.threshold
            touch = by_rms if self.mode == "input-rms" else touch | by_rms
        return touch, by_rms

    def decide(self, outputs: list[np.ndarray], inputs: np.ndarray, *, score_reference: np.ndarray | None = None,
               input_reference: np.ndarray | None = None) -> Predictions:
        logits, force_all = outputs[0], outputs[1]
        p = softmax(np.asarray(logits, np.float64))
        place = p[:, :-1]
        idx = np.argmax(place, axis=1)
        touch, by_rms = self.touch(logits, inputs, input_reference)
        f = self.force(force_all, idx, inputs)
        conf = place[np.arange(len(idx)), idx] / np.maximum(place.sum(axis=1), 1e-12)
        f = np.where(touch, np.clip(f, 0, None), 0.0)
        # Alg. 2's no-touch chirps by the physical statistic alone: the head's logit, trained on one session, calls rest
        # chirps touched once warm-up has moved them, and an OR with it then blocks every reference refresh
        return Predictions(touch, self.ids[idx], centroid(place, self.layout), f, conf, place,
                           reference_touch=by_rms if self.mode == "either" else None)


class NetKind(ModelKind):
    name, label, graph, file = "net", "network", "skinnet", "net.onnx"
    keys = frozenset({"hparams", "detector", "force", "force_bins", "energy_ref_db"})
    selection_keys = ("net",)
    requires = (BASELINE, CLOSED_FORM)  # its frozen layers are the artifact's SVM and LDA; its detector thresholds the SVM's statistic
    can_fit = False  # sonicskin.training.kind (the entry point) can

    def outputs(self, n_loc):
        return [n_loc + 1, n_loc]

    def output_text(self, n_loc):
        return f"logits (batch, {n_loc + 1}) and force (batch, {n_loc})"

    def check_entry(self, doc, m, field, *, n_in, layout_ids):
        if "hparams" in m:
            doc.obj(m["hparams"], f"{field}.hparams")
        if "detector" not in m:
            return
        f = f"{field}.detector"
        d = doc.obj(m["detector"], f)
        doc.keys(d, {"mode", "bias", "threshold", "reference", "bins"}, f)
        doc.choice(doc.get(d, "mode", f), f"{f}.mode", NET_DETECTORS)
        if "bias" in d:
            doc.num(d["bias"], f"{f}.bias", lo=-doc.MAX_SCORE, hi=doc.MAX_SCORE)
        if "threshold" in d:
            doc.num(d["threshold"], f"{f}.threshold", lo=0, hi=doc.MAX_THRESHOLD)
        elif d["mode"] != "head":
            doc.fail(f"{f}.threshold", f"is missing (mode {d['mode']!r} thresholds the input-RMS statistic)")
        if "reference" in d:
            ref = doc.list(d["reference"], f"{f}.reference", nonempty=True)
            if len(ref) > n_in:
                doc.fail(f"{f}.reference", f"has {len(ref)} values, more than the {n_in} inputs")
            for i, v in enumerate(ref):
                doc.num(v, f"{f}.reference[{i}]", lo=-doc.MAX_SCORE, hi=doc.MAX_SCORE)
        if "bins" in d:
            doc.int(d["bins"], f"{f}.bins", lo=1, hi=n_in)
        if "force" in m:  # the SVM's closed-form force model on the first force_bins inputs
            k = doc.int(doc.get(m, "force_bins", field), f"{field}.force_bins", lo=1, hi=n_in)
            doc.num(doc.get(m, "energy_ref_db", field), f"{field}.energy_ref_db", lo=-doc.MAX_SCORE, hi=doc.MAX_SCORE)
            doc.force(m["force"], f"{field}.force", layout_ids, k)

    def head(self, entry, layout):
        return NetHead(entry, layout)

    def force_rmse(self, sel):
        n = sel.get("net") or {}
        return (n.get("force_rmse") or {}).get(n.get("force"))  # the chosen force's, on the validation presses

    def selection_lines(self, sel):
        n = sel.get("net") or {}
        out = []
        if n.get("detector"):
            out.append(f"network touch decision: {n['detector']} ({n.get('how', '')})")
        if n.get("location_layer"):
            out.append(f"network location layer: {n['location_layer']} ({n.get('layer_how', '')})")
        if n.get("force"):
            what = {"head": "its own head", "the SVM's": "the SVM's force model"}.get(n["force"], "the pooled ridge")
            out.append(f"network force: {what} ({n.get('force_how', '')})")
        return out


register(NetKind())
