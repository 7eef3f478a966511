"""Run a deployment artifact with onnxruntime only (no torch): frames or features -> touches.

An artifact is a folder with ``skin.json`` (rig, layout, OSPA bins, feature mode, calibration,
detector threshold, per-location force curves, checksums) and the ONNX models it names
(``net.onnx``, ``svm.onnx``).  :class:`SkinRuntime` checks the artifact against the rig it is
asked to run on, against its checksums, the binding inside each model file (bins, mode, rig, layout,
parameters), its digest and its probe outputs before anything runs (:func:`sonicskin.schema.check_integrity`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from .dsp import log_magnitude_db
from .features import FeatureSpec
from .force import PerLocationForce, energy_db
from .rig import Layout, Rig
from .schema import (
    ARTIFACT_FORMAT,
    ArtifactError,
    check_integrity,
    check_layout,
    check_rig,
    check_session,
    load_skin,
    read_model_file,
)
from .svm_head import score_vector, touch_statistic

__all__ = ["ArtifactError", "SkinRuntime", "SkinStream", "Predictions", "ARTIFACT_FORMAT"]


@dataclasses.dataclass
class Predictions:
    touch: np.ndarray        # (n,) bool
    location: np.ndarray     # (n,) location id (most likely marker)
    xy_cm: np.ndarray        # (n, 2) continuous estimate: probability-weighted centroid of nearby markers
    force_n: np.ndarray      # (n,) 0 where no touch is detected
    confidence: np.ndarray   # (n,) probability of the chosen marker given a touch (net) / vote share (svm)
    scores: np.ndarray       # (n, N) per-location scores (net: probabilities; svm: calibrated S_final)
    calibrating: np.ndarray | None = None  # (n,) bool: boot calibration, no prediction (replays only)

    def take(self, sel) -> Predictions:
        """The chirps ``sel`` (index, slice or mask)."""
        return Predictions(*(None if v is None else v[sel] for v in (getattr(self, f.name) for f in dataclasses.fields(self))))

    @classmethod
    def concat(cls, parts: list[Predictions]) -> Predictions:
        cols = [[getattr(p, f.name) for p in parts] for f in dataclasses.fields(cls)]
        return cls(*(None if any(v is None for v in c) else np.concatenate(c) for c in cols))


def _finite_rows(X: np.ndarray, what: str, fix: str) -> None:
    """Refuse rows with NaN/inf in one line (they gave silently wrong predictions, or a NaN reference)."""
    bad = ~np.isfinite(X).all(axis=tuple(range(1, X.ndim)))
    if bad.any():
        raise ArtifactError(f"{what} hold NaN or infinite values in {int(bad.sum())} of {len(X)} chirps (the first at row "
                            f"{int(np.argmax(bad))}); {fix}")


def _band_rows(X, n_band: int) -> np.ndarray:
    """Band features (n, n_band) as float32, checked: shape and finite values."""
    X = np.asarray(X, np.float32)
    if X.ndim != 2 or X.shape[1] != n_band:
        raise ArtifactError(f"expected band features (n, {n_band}), got {X.shape}")
    _finite_rows(X, "the band features", "drop those chirps (the live loop skips them) or compute the features again")
    return X


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
    rig : the rig it will run on (a :class:`Rig`, a rig name or a YAML path); defaults to the artifact's own.  A
        different sample rate, chirp or band raises :class:`ArtifactError`.
    layout : the marker layout of the surface it will run on (e.g. a scenario's ``make_layout()``);
        other ids or positions than the artifact's raise :class:`ArtifactError`.  ``None``: not checked.
    threads : onnxruntime intra-op threads (1: predictable latency next to the audio thread).
    """

    def __init__(self, folder: str | Path, model: str = "net", *, rig: Rig | None = None, layout: Layout | None = None,
                 threads: int = 1):
        import onnxruntime as ort

        if not isinstance(folder, (str, Path)):
            raise ArtifactError(f"folder must be the path of an artifact folder, got {folder!r}")
        if isinstance(rig, (str, Path)):  # a rig name or YAML, as everywhere else
            rig = Rig.load(rig)
        if not (rig is None or isinstance(rig, Rig)):
            raise ArtifactError(f"rig must be a sonicskin.rig.Rig, a rig name or a YAML path, got {type(rig).__name__}")
        if not (layout is None or isinstance(layout, Layout)):
            raise ArtifactError(f"layout must be a sonicskin.rig.Layout (e.g. a scenario's make_layout()), got "
                                f"{type(layout).__name__}")
        if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 1024:
            raise ArtifactError(f"threads must be an integer from 1 to 1024 (onnxruntime's intra-op threads), got {threads!r}")
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
        check_integrity(self.session, self.meta, model, data, folder=self.folder)  # binding, digest, probes
        for other in self.meta["models"]:  # the artifact is one unit: every file it names is there and intact
            if other != model:
                read_model_file(self.folder, self.meta, other)
        self.input_name = self.session.get_inputs()[0].name
        self.n_locations = len(self.layout)
        self.ids = np.asarray(self.layout.ids)
        if model == "svm":
            self.force_model = PerLocationForce.from_dict(self.m["force"])
            self.reference_scores = np.asarray(self.m["reference_scores"])

    # -- features ----------------------------------------------------------------------
    def band_features(self, frames: np.ndarray) -> np.ndarray:
        """dB features of chirp-aligned frames (validated: length, NaN, silence, clipping)."""
        return log_magnitude_db(frames, self.rig)

    def inputs(self, X_band: np.ndarray, *, reference: np.ndarray | None = None) -> np.ndarray:
        """Model inputs from band features: the artifact's bins, minus ``reference`` (over the band
        or over the bins) in ``relative`` mode.  Streams get their reference from :meth:`stream`."""
        X = _band_rows(X_band, self.rig.n_band)[:, list(self.spec.bins)]
        if self.spec.mode == "absolute":
            return X
        if reference is None:
            raise ValueError("relative features need a no-touch reference; run a stream (SkinRuntime.stream / replay)")
        ref = np.asarray(reference, np.float32)
        return X - (ref[list(self.spec.bins)] if ref.shape[-1] == self.rig.n_band else ref)

    def stream(self) -> SkinStream:
        """A new stream: Alg. 2's online reference and the per-chirp path (see :class:`SkinStream`)."""
        return SkinStream(self)

    def replay(self, X_band: np.ndarray, time_s: np.ndarray) -> Predictions:
        """Predict a recorded stream in order, as the live loop would (see :meth:`SkinStream.replay`)."""
        return SkinStream(self).replay(X_band, time_s)

    # -- models ------------------------------------------------------------------------
    def run(self, inputs: np.ndarray) -> list[np.ndarray]:
        x = np.ascontiguousarray(inputs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != len(self.spec.bins):
            raise ArtifactError(f"expected model inputs (n, {len(self.spec.bins)}) (the artifact's bins; "
                                f"SkinRuntime.inputs makes them from band features), got {x.shape}")
        _finite_rows(x, "the model inputs", "drop those chirps (the live loop skips them)")
        return self.session.run(None, {self.input_name: x})

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

    def predict_inputs(self, inputs: np.ndarray, *, score_reference: np.ndarray | None = None) -> Predictions:
        """Predictions from model inputs (see :meth:`inputs`).

        For the SVM, Alg. 2's ``S_c`` is ``score_reference`` (the stream's, see :class:`SkinStream`),
        or the training session's.
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
            V_cal = V - (self.reference_scores if score_reference is None else score_reference)
            S_final = V_cal[:, :K]
            touch = touch_statistic(V_cal, K, self.m.get("detector_bins")) >= self.m["threshold"]
            E = energy_db(inputs, np.arange(inputs.shape[1])) - self.m["energy_ref_db"]
            f = self.force_model.predict(E, self.ids[idx], inputs=inputs)
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


class SkinStream:
    """One stream through one model: band features -> Alg. 2 reference -> model -> detection -> force.

    The live loop calls :meth:`frame` (or :meth:`chirp`) once per chirp; offline evaluation calls
    :meth:`replay` on a recorded stream.  Both decide the reference with the same
    :class:`~sonicskin.calibration.OnlineReference`: the first ``beta`` seconds are the boot
    calibration (hands off, no predictions), later refreshes take ``beta`` seconds that this
    model's own detector calls no-touch, every ``alpha`` seconds.  No label reaches it.
    """

    def __init__(self, runtime: SkinRuntime):
        self.rt = runtime
        self.bins = list(runtime.spec.bins)
        self.reference = runtime.spec.reference(runtime.rig.chirps_per_s,
                                                score_fn=runtime.raw_scores if runtime.kind == "svm" else None)

    @property
    def calibrating(self) -> bool:
        return not self.reference.ready

    def _predict(self, inputs: np.ndarray) -> Predictions:
        return self.rt.predict_inputs(inputs, score_reference=self.reference.scores)

    def frame(self, frame: np.ndarray, t_s: float) -> Predictions | None:
        """One chirp-aligned frame (n_chirp,) at stream time ``t_s``; ``None`` during the boot calibration."""
        frame = np.asarray(frame)
        if frame.shape != (self.rt.rig.n_chirp,):
            raise ArtifactError(f"expected one chirp-aligned frame of {self.rt.rig.n_chirp} samples (the artifact's rig), "
                                f"got shape {frame.shape}")
        return self.chirp(log_magnitude_db(frame[None], self.rt.rig, check=False)[0], t_s)

    def chirp(self, x_band: np.ndarray, t_s: float) -> Predictions | None:
        """One chirp's band features (n_band,); ``None`` during the boot calibration."""
        x = np.asarray(x_band, np.float32)
        if x.shape != (self.rt.rig.n_band,):
            raise ArtifactError(f"expected one chirp's band features ({self.rt.rig.n_band},), got shape {x.shape}")
        if not np.isfinite(x).all():  # it would become the reference (boot) or a prediction from NaN
            raise ArtifactError("the chirp's band features hold NaN or infinite values (a NaN, silent or clipped frame); "
                                "skip that chirp, as the live loop does")
        x = x[self.bins]
        if not self.reference.ready:
            self.reference.step(x, t_s, None)
            return None
        p = self._predict(self.reference.inputs(x[None]))
        self.reference.step(x, t_s, bool(p.touch[0]))
        return p

    def replay(self, X_band: np.ndarray, time_s: np.ndarray) -> Predictions:
        """Every chirp of a recorded stream (n, n_band) in order, vectorised between reference
        refreshes; the same output as :meth:`chirp` one at a time.  Boot chirps have
        ``calibrating`` set, no touch, location -1 and NaN position."""
        X = _band_rows(X_band, self.rt.rig.n_band)[:, self.bins]
        time_s = np.asarray(time_s, np.float64)
        if time_s.shape != (len(X),):
            raise ArtifactError(f"time_s must hold one time per chirp ({len(X)},), got shape {time_s.shape}")
        if not np.isfinite(time_s).all() or np.any(np.diff(time_s) < 0):
            raise ArtifactError("time_s must be finite and non-decreasing (the stream clock of each chirp, in order): "
                                "replay one stream at a time, in recording order")
        parts, lo = [], None
        for i, j, out in self.reference.replay(X, time_s, self._predict):
            lo = i if lo is None else lo
            parts.append(out.take(slice(0, j - i)))
        n, K = len(X), self.rt.n_locations
        n_boot = n if lo is None else lo
        boot = Predictions(np.zeros(n_boot, bool), np.full(n_boot, -1), np.full((n_boot, 2), np.nan), np.zeros(n_boot),
                           np.zeros(n_boot), np.zeros((n_boot, K)))
        p = Predictions.concat([boot, *parts]) if parts else boot
        p.calibrating = np.arange(n) < n_boot
        return p
