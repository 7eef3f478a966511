"""Run a deployment artifact with onnxruntime only (no torch): frames or features -> touches.

An artifact is a folder with ``skin.json`` (rig, layout, OSPA bins, feature mode, calibration,
detector threshold, per-location force curves, checksums) and the ONNX models it names
(``net.onnx``, ``svm.onnx``).  :class:`SkinRuntime` checks the artifact against the rig it is
asked to run on and against its checksums before anything runs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .calibration import ScoreCalibrator
from .dsp import log_magnitude_db
from .features import FeatureSpec
from .force import PerLocationForce, energy_db
from .rig import Layout, Rig
from .schema import ARTIFACT_FORMAT, ArtifactError, check_layout, check_rig, check_session, load_skin, read_model_file
from .svm_head import score_vector, touch_statistic

__all__ = ["ArtifactError", "SkinRuntime", "Predictions", "ARTIFACT_FORMAT"]


@dataclasses.dataclass
class Predictions:
    touch: np.ndarray        # (n,) bool
    location: np.ndarray     # (n,) location id (most likely marker)
    xy_cm: np.ndarray        # (n, 2) continuous estimate: probability-weighted centroid of nearby markers
    force_n: np.ndarray      # (n,) 0 where no touch is detected
    confidence: np.ndarray   # (n,) probability of the chosen marker given a touch (net) / vote share (svm)
    scores: np.ndarray       # (n, N) per-location scores (net: probabilities; svm: calibrated S_final)


def _softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=1, keepdims=True)


class SkinRuntime:
    """Load ``folder`` and serve one of its models.

    Parameters
    ----------
    folder : the artifact folder.
    model : ``"net"`` or ``"svm"``.
    rig : the rig it will run on; defaults to the artifact's own.  A different sample rate,
        chirp or band raises :class:`ArtifactError`.
    layout : the marker layout of the surface it will run on (e.g. a scenario's ``make_layout()``);
        other ids or positions than the artifact's raise :class:`ArtifactError`.  ``None``: not checked.
    threads : onnxruntime intra-op threads (1: predictable latency next to the audio thread).
    """

    def __init__(self, folder: str | Path, model: str = "net", *, rig: Rig | None = None, layout: Layout | None = None,
                 threads: int = 1):
        import onnxruntime as ort

        self.folder = Path(folder)
        self.meta = load_skin(self.folder)  # the whole document against the schema (sonicskin.schema)
        self.rig = Rig.from_dict(self.meta["rig"])
        if rig is not None:
            check_rig(self.meta, rig)
        self.layout = Layout.from_dict(self.meta["layout"])
        if layout is not None:
            check_layout(self.meta, layout)
        self.spec = FeatureSpec.from_dict(self.meta["features"])
        data = read_model_file(self.folder, self.meta, model)  # confined to the folder, checksum verified
        self.kind = model
        self.m = self.meta["models"][model]
        path = self.folder / self.m["file"]
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
        so.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(data, so, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own exception types
            raise ArtifactError(f"{path} cannot be loaded by onnxruntime ({str(e).splitlines()[0][:160]}); "
                                f"export the artifact again") from None
        check_session(self.session, self.meta, model, source=str(path))
        self.input_name = self.session.get_inputs()[0].name
        self.n_locations = len(self.layout)
        self.ids = np.asarray(self.layout.ids)
        if model == "svm":
            self.force_model = PerLocationForce.from_dict(self.m["force"])
            self.reference_scores = np.asarray(self.m["reference_scores"])
        self.calibrator = self.spec.calibrator(self.rig.chirps_per_s)

    # -- features ----------------------------------------------------------------------
    def band_features(self, frames: np.ndarray) -> np.ndarray:
        """dB features of chirp-aligned frames (validated: length, NaN, silence, clipping)."""
        return log_magnitude_db(frames, self.rig)

    def inputs(self, X_band: np.ndarray, *, quiet: np.ndarray | None = None, time_s: np.ndarray | None = None,
               reference: np.ndarray | None = None) -> np.ndarray:
        """Model inputs from band features of one stream: the artifact's bins, minus the running
        no-touch reference in ``relative`` mode (from ``quiet`` chirps, or a given ``reference``)."""
        X = np.asarray(X_band, np.float32)
        if X.ndim != 2 or X.shape[1] != self.rig.n_band:
            raise ArtifactError(f"expected band features (n, {self.rig.n_band}), got {X.shape}")
        X = X[:, list(self.spec.bins)]
        if self.spec.mode == "absolute":
            return X
        if reference is not None:  # a no-touch reference over the band bins, e.g. from a live calibration
            ref = np.asarray(reference, np.float32)
            return X - (ref[list(self.spec.bins)] if ref.shape[-1] == self.rig.n_band else ref)
        if quiet is None:
            raise ValueError("relative features need the no-touch chirps of the stream (quiet) or a reference")
        return self.calibrator.run(X, quiet, time_s=time_s).astype(np.float32)

    # -- models ------------------------------------------------------------------------
    def run(self, inputs: np.ndarray) -> list[np.ndarray]:
        return self.session.run(None, {self.input_name: np.ascontiguousarray(inputs, dtype=np.float32)})

    def _centroid(self, w: np.ndarray, k: int = 3) -> np.ndarray:
        """Probability-weighted centroid of the ``k`` most likely markers (wrapping around the tube)."""
        top = np.argsort(w, axis=1)[:, -k:]
        ww = np.take_along_axis(w, top, axis=1)
        ww = ww / np.maximum(ww.sum(axis=1, keepdims=True), 1e-12)
        xy = self.layout.xy_cm[top]  # (n, k, 2)
        best = xy[:, -1:, :]
        d = xy - best
        C = self.layout.circumference_cm
        if C:
            d[..., 0] = (d[..., 0] + C / 2) % C - C / 2
        out = best[:, 0] + np.sum(ww[..., None] * d, axis=1)
        if C:
            out[:, 0] %= C
        return out

    def predict_inputs(self, inputs: np.ndarray, *, quiet: np.ndarray | None = None,
                       time_s: np.ndarray | None = None, score_reference: np.ndarray | None = None) -> Predictions:
        """Predictions from model inputs (see :meth:`inputs`).

        For the SVM, Alg. 2's ``S_c`` comes from the ``quiet`` chirps of the stream (replayed), or
        is given as ``score_reference`` (the live loop's), or is the training session's.
        """
        if self.kind == "net":
            logits, force_all = self.run(inputs)
            p = _softmax(logits)
            p_touch = 1.0 - p[:, -1]
            idx = np.argmax(p[:, :-1], axis=1)
            touch = p_touch >= 0.5
            f = np.take_along_axis(force_all, idx[:, None], axis=1)[:, 0]
            conf = p[np.arange(len(idx)), idx] / np.maximum(p_touch, 1e-12)
            w = p[:, :-1]
            scores = w
        else:
            K = self.n_locations
            V = score_vector(self.run(inputs)[1], K, inputs)
            S = V[:, :K]
            idx = np.argmax(S, axis=1)
            if quiet is not None:
                V_cal = ScoreCalibrator(self.calibrator.beta_chirps, self.calibrator.alpha_chirps,
                                        self.rig.chirps_per_s).run(V, quiet, initial=self.reference_scores, time_s=time_s)
            else:
                V_cal = V - (self.reference_scores if score_reference is None else score_reference)
            S_final = V_cal[:, :K]
            touch = touch_statistic(V_cal, K) >= self.m["threshold"]
            E = energy_db(inputs, np.arange(inputs.shape[1])) - self.m["energy_ref_db"]
            f = self.force_model.predict(E, self.ids[idx])
            conf = np.clip(np.max(S, axis=1) / max(self.n_locations - 1, 1), 0, 1)  # share of pairwise votes won
            w = _softmax(4.0 * S)  # S counts votes: sharpen so the centroid stays among neighbours
            scores = S_final
        f = np.where(touch, np.clip(f, 0, None), 0.0)
        return Predictions(touch, self.ids[idx], self._centroid(w), f, conf, scores)

    def raw_scores(self, inputs: np.ndarray) -> np.ndarray:
        """SVM score vector before calibration (for Alg. 2's reference): per-location S and the inputs."""
        if self.kind != "svm":
            raise ValueError("raw scores are the SVM's; the network needs no score reference")
        return score_vector(self.run(inputs)[1], self.n_locations, inputs)

    def predict_frames(self, frames: np.ndarray, *, quiet: np.ndarray | None = None,
                       reference: np.ndarray | None = None) -> Predictions:
        X = self.band_features(frames)
        return self.predict_inputs(self.inputs(X, quiet=quiet, reference=reference), quiet=quiet)
