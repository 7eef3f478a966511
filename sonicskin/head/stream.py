"""One stream through one model: band features -> bins -> Alg. 2 reference -> model -> head, chirp by chirp
(:meth:`Stream.frame`) or replayed vectorised between reference refreshes (:meth:`Stream.replay`), same decisions."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..dsp import log_magnitude_db
from ..errors import ArtifactError
from .heads import Predictions

__all__ = ["Stream", "band_rows", "finite_rows"]


def finite_rows(X: np.ndarray, what: str, fix: str) -> None:
    """Refuse rows with NaN/inf in one line (they gave silently wrong predictions, or a NaN reference)."""
    bad = ~np.isfinite(X).all(axis=tuple(range(1, X.ndim)))
    if bad.any():
        raise ArtifactError(f"{what} hold NaN or infinite values in {int(bad.sum())} of {len(X)} chirps (the first at row "
                            f"{int(np.argmax(bad))}); {fix}")


def band_rows(X, n_band: int) -> np.ndarray:
    """Band features (n, n_band) as float32, checked: shape and finite values."""
    X = np.asarray(X, np.float32)
    if X.ndim != 2 or X.shape[1] != n_band:
        raise ArtifactError(f"expected band features (n, {n_band}), got {X.shape}")
    finite_rows(X, "the band features", "drop those chirps (the live loop skips them) or compute the features again")
    return X


class Stream:
    """Alg. 2's online reference and the per-chirp path of one model: :meth:`chirp` and :meth:`replay` share one
    :class:`~sonicskin.calibration.OnlineReference` fed by this model's own detector, no label.  ``run``: the ONNX graph;
    ``drift``: a :class:`~sonicskin.drift.DriftTracker` mapping every chirp back onto the training frequency axis."""

    def __init__(self, run: Callable[[np.ndarray], list[np.ndarray]], head, spec, rig, *, drift=None):
        self.run, self.head, self.spec, self.rig, self.drift = run, head, spec, rig, drift
        self.bins = list(spec.bins)
        if drift is None:
            score_fn = (lambda x: head.scores(run(x), x)) if head.calibrated else None
            self.reference = spec.reference(rig.chirps_per_s, score_fn=score_fn)
        else:  # the reference holds band rows; inputs are formed here, on the warped axis
            self._bins = np.asarray(self.bins, np.int64)
            self._ref_inputs = np.zeros(len(self.bins), np.float32)
            self.reference = spec.reference(rig.chirps_per_s, relative=False, score_fn=self._on_reference)

    def _inputs(self, x: np.ndarray) -> np.ndarray:
        """Model inputs of rows the reference holds (drift tracking: band rows mapped back), minus it in relative mode."""
        if self.drift is None:
            return self.reference.inputs(x)
        z = self.drift.warp_bins(x, self._bins)
        return z - self._ref_inputs if self.spec.mode == "relative" else z

    def _on_reference(self, block: np.ndarray) -> np.ndarray:
        """A new reference took effect: estimate the stretch from its band rows, then the scores Alg. 2 averages (``S_c``)."""
        self.drift.update(block)
        self._ref_inputs = self.drift.warp_bins(self.reference.features, self._bins)
        inputs = self._inputs(block)
        if self.head.calibrated:
            return self.head.scores(self.run(inputs), inputs)
        return np.zeros((len(block), 1))

    @property
    def calibrating(self) -> bool:
        """In a boot calibration (the first, or a re-boot after a pause longer than alpha)."""
        return self.reference.calibrating

    def predict(self, inputs: np.ndarray) -> Predictions:
        """Decisions on model inputs under the current reference."""
        ref = self.reference
        input_ref = None
        if not self.head.calibrated and ref.ready:
            if self.drift is not None:
                input_ref = np.zeros(len(self.bins)) if self.spec.mode == "relative" else self._ref_inputs
            else:
                input_ref = np.zeros(len(self.bins)) if ref.relative else ref.features
        return self.head.decide(self.run(inputs), inputs, score_reference=ref.scores, input_reference=input_ref)

    def frame(self, frame: np.ndarray, t_s: float) -> Predictions | None:
        """One chirp-aligned frame (n_chirp,) at stream time ``t_s``; ``None`` during the boot calibration."""
        frame = np.asarray(frame)
        if frame.shape != (self.rig.n_chirp,):
            raise ArtifactError(f"expected one chirp-aligned frame of {self.rig.n_chirp} samples (the artifact's rig), "
                                f"got shape {frame.shape}")
        return self.chirp(log_magnitude_db(frame[None], self.rig, check=False)[0], t_s)

    def chirp(self, x_band: np.ndarray, t_s: float) -> Predictions | None:
        """One chirp's band features (n_band,); ``None`` during the boot calibration."""
        x = np.asarray(x_band, np.float32)
        if x.shape != (self.rig.n_band,):
            raise ArtifactError(f"expected one chirp's band features ({self.rig.n_band},), got shape {x.shape}")
        if not np.isfinite(x).all():  # it would become the reference (boot) or a prediction from NaN
            raise ArtifactError("the chirp's band features hold NaN or infinite values (a NaN, silent or clipped frame); "
                                "skip that chirp, as the live loop does")
        if self.drift is None:
            x = x[self.bins]
        if self.reference.booting_at(t_s):  # the first boot, or a re-boot after a pause longer than alpha
            self.reference.step(x, t_s, None)
            return None
        p = self.predict(self._inputs(x[None]))
        self.reference.step(x, t_s, bool(p.touched_for_reference()[0]))
        return p

    def replay(self, X_band: np.ndarray, time_s: np.ndarray) -> Predictions:
        """Every chirp of a recorded stream (n, n_band), vectorised between reference refreshes, as :meth:`chirp` gives them."""
        X = band_rows(X_band, self.rig.n_band)
        if self.drift is None:
            X = X[:, self.bins]
        time_s = np.asarray(time_s, np.float64)
        if time_s.shape != (len(X),):
            raise ArtifactError(f"time_s must hold one time per chirp ({len(X)},), got shape {time_s.shape}")
        if not np.isfinite(time_s).all() or np.any(np.diff(time_s) < 0):
            raise ArtifactError("time_s must be finite and non-decreasing (the stream clock of each chirp, in order): "
                                "replay one stream at a time, in recording order")
        parts, n = [], len(X)
        # OnlineReference.replay hands each block through its own inputs(): the bins minus the reference, or (drift
        # tracking, a reference of band rows) the rows unchanged, mapped to model inputs here.  Boot chirps (the
        # first, and a re-boot after a pause longer than alpha) come as out None.
        predict = self.predict if self.drift is None else (lambda x: self.predict(self._inputs(x)))
        for i, j, out in self.reference.replay(X, time_s, predict):
            if out is None:
                parts.append(Predictions.boot(j - i, self.head.K))
            else:
                part = out.take(slice(0, j - i))
                part.calibrating = np.zeros(j - i, bool)
                parts.append(part)
        return Predictions.concat(parts) if parts else Predictions.boot(n, self.head.K)
