"""Run a deployment artifact with onnxruntime only (no torch): frames or features -> touches, after checking it against
the rig and its integrity (:func:`sonicskin.integrity.check_integrity`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from . import kinds
from .artifact import load_skin, read_model_file
from .artifact_schema import ARTIFACT_FORMAT
from .drift import DriftTracker
from .errors import ArtifactError, is_number
from .features import FeatureSpec
from .head import Predictions, Stream
from .head.stream import band_rows, finite_rows
from .integrity import check_integrity, check_layout, check_rig, check_session
from .rig import Layout, Rig

__all__ = ["ArtifactError", "SkinRuntime", "Stream", "Predictions", "ARTIFACT_FORMAT"]


class SkinRuntime:
    """Load ``folder`` and serve its ``model``; ``rig`` and ``layout`` (``None``: not checked) must be the artifact's."""

    def __init__(self, folder: str | Path, model: str = kinds.NETWORK, *, rig: Rig | None = None, layout: Layout | None = None,
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
        if not is_number(threads, integer=True) or not 1 <= threads <= 1024:
            raise ArtifactError(f"threads must be an integer from 1 to 1024 (onnxruntime's intra-op threads), got {threads!r}")
        self.folder = Path(folder)
        self.meta = load_skin(self.folder)  # the whole document against the schema (sonicskin.artifact_schema)
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
        # The model reads the first n_in of the artifact's bins (OSPA order): its inputs are those bins only.
        self.spec = dataclasses.replace(self.spec, bins=self.spec.bins[:int(self.m["n_in"])])
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
        self.head = kinds.get(model).head(self.m, self.layout)  # model outputs -> touch, location, xy, force (sonicskin.head)
        self.drift = self.meta.get("drift")  # drift tracking's training reference (each stream tracks its own stretch)

    # -- features ----------------------------------------------------------------------
    def inputs(self, X_band: np.ndarray, *, reference: np.ndarray | None = None) -> np.ndarray:
        """Model inputs from band features: the artifact's bins, minus ``reference`` in ``relative`` mode."""
        X = band_rows(X_band, self.rig.n_band)[:, list(self.spec.bins)]
        if self.spec.mode == "absolute":
            return X
        if reference is None:
            raise ValueError("relative features need a no-touch reference; run a stream (SkinRuntime.stream / replay)")
        ref = np.asarray(reference, np.float32)
        return X - (ref[list(self.spec.bins)] if ref.shape[-1] == self.rig.n_band else ref)

    def stream(self) -> Stream:
        """A new stream: Alg. 2's online reference and the per-chirp path (see :class:`sonicskin.head.Stream`)."""
        drift = None
        if self.drift is not None:
            drift = DriftTracker.from_dict(self.drift, self.rig)
        return Stream(self.run, self.head, self.spec, self.rig, drift=drift)

    def replay(self, X_band: np.ndarray, time_s: np.ndarray) -> Predictions:
        """Predict a recorded stream in order, as the live loop would (see :meth:`sonicskin.head.Stream.replay`)."""
        return self.stream().replay(X_band, time_s)

    # -- models ------------------------------------------------------------------------
    def run(self, inputs: np.ndarray) -> list[np.ndarray]:
        x = np.ascontiguousarray(inputs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != len(self.spec.bins):
            raise ArtifactError(f"expected model inputs (n, {len(self.spec.bins)}) (the artifact's bins; "
                                f"SkinRuntime.inputs makes them from band features), got {x.shape}")
        finite_rows(x, "the model inputs", "drop those chirps (the live loop skips them)")
        return self.session.run(None, {self.input_name: x})

    def predict_inputs(self, inputs: np.ndarray, *, score_reference: np.ndarray | None = None) -> Predictions:
        """Predictions from model inputs outside a stream (``S_c``: ``score_reference`` or the training session's)."""
        return self.head.decide(self.run(inputs), np.asarray(inputs, np.float32), score_reference=score_reference)
