"""The per-chirp decisions of one model: the one record every path returns."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Predictions"]


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
