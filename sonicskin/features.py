"""What both models see: the OSPA-selected bins, absolute (dB, the paper's input) or relative: minus the
stream's running no-touch reference (Alg. 2's online updating applied to the *features*), so a slow drift of the
channel is removed before either model sees it."""

from __future__ import annotations

import dataclasses
import warnings
from typing import TYPE_CHECKING

import numpy as np

from .calibration import OnlineReference

if TYPE_CHECKING:
    from .dataset import FeatureTable

__all__ = ["FeatureSpec", "relative_features", "quiet_mask", "touch_mask", "light_touches", "training_targets", "usable_bins",
           "rest_beta", "MIN_REST_CHIRPS"]

MODES = ("absolute", "relative")
DEFAULT_N_BINS = 300  # the paper's gamma


def quiet_mask(t: FeatureTable) -> np.ndarray:
    """No-touch chirps with the robot at rest: Alg. 2's calibration chirps."""
    return (t["location"] < 0) & (t["moving"] == 0)


def touch_mask(t: FeatureTable, min_force_n: float = 0.5) -> np.ndarray:
    """Touch chirps: a location and a force of at least ``min_force_n`` (or no force sensor: NaN)."""
    f = t["force_n"]
    return (t["location"] >= 0) & ((f >= min_force_n) | np.isnan(f))


def light_touches(force, touched, min_force_n: float = 0.5) -> str:
    """Why most labelled touches would not count as touches (their force is below ``min_force_n``), or ""."""
    f = np.asarray(force, float)[np.asarray(touched, bool)]
    light = int(np.sum(f < min_force_n))
    if not f.size or light <= f.size / 2:
        return ""
    return (f"{light} of the {f.size} labelled touch chirps have force_n below {min_force_n:g} N (median "
            f"{np.nanmedian(f):.3g} N) and do not count as touches: force_n must be in newtons (empty: no force sensor)")


@dataclasses.dataclass(frozen=True)
class FeatureSpec:
    """Model input definition, stored in every artifact."""

    bins: tuple[int, ...]          # indices into the rig's band bins (rig.band_bins[bins] are rfft bins)
    mode: str = "relative"
    beta_s: float = 3.0
    alpha_s: float = 1200.0

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"feature mode must be one of {MODES}, got {self.mode!r}")

    def reference(self, chirps_per_s: float, **kw) -> OnlineReference:
        """A fresh Alg. 2 reference for one stream (``kw``: ``score_fn``, or ``relative`` to override the mode's)."""
        kw.setdefault("relative", self.mode == "relative")
        return OnlineReference.from_seconds(beta_s=self.beta_s, alpha_s=self.alpha_s, chirps_per_s=chirps_per_s, **kw)

    def transform(self, t: FeatureTable, chirps_per_s: float, *, online: bool = True) -> np.ndarray:
        """Model inputs (n, len(bins)) float32 of every chirp of ``t``, each session relative to its labelled rest."""
        X = t.X[:, list(self.bins)]
        if self.mode == "absolute":
            return X.astype(np.float32)
        return relative_features(X, quiet_mask(t), t["session"], t["time_s"], self.reference(chirps_per_s), online=online)

    def to_dict(self) -> dict:
        return {"bins": [int(b) for b in self.bins], "mode": self.mode, "beta_s": self.beta_s, "alpha_s": self.alpha_s}

    @classmethod
    def from_dict(cls, d: dict) -> FeatureSpec:
        return cls(tuple(int(b) for b in d["bins"]), d["mode"], float(d["beta_s"]), float(d["alpha_s"]))


def relative_features(X: np.ndarray, quiet: np.ndarray, session: np.ndarray, time_s: np.ndarray,
                      calibrator: OnlineReference, *, online: bool = True) -> np.ndarray:
    """``X`` minus the running no-touch reference of its own session, from the *known* no-touch chirps: Alg. 2
    (:class:`~sonicskin.calibration.OnlineReference`, fed labels instead of a detector: boot on the first ``beta``
    consecutive ``quiet`` chirps, refreshes every ``alpha``).  For *training* sessions only; test streams are
    replayed with the model's own detection.  ``calibrator`` gives beta, alpha and the clock; ``online=False`` keeps
    the boot reference throughout."""
    beta, alpha, cps = calibrator.beta, calibrator.alpha, calibrator.cps
    X = np.asarray(X, np.float32)
    out = np.empty(X.shape, np.float32)
    for s in np.unique(session):
        idx = np.flatnonzero(session == s)
        ref = OnlineReference(beta, alpha if online else None, cps, labelled=True)
        cur = np.full(idx.size, -1)
        refs: list[np.ndarray] = []
        for k, i in enumerate(idx):
            cur[k] = len(refs) - 1
            if ref.step(X[i], time_s[i], not quiet[i]):
                refs.append(ref.features)
        if not refs:
            raise ValueError(f"session {s}: fewer than {beta} consecutive hands-off chirps to calibrate on; relative "
                             f"features need {beta} ({beta / cps:.0f} s) in every session, or use absolute features "
                             f"(--mode absolute / data.mode: absolute)")
        out[idx] = X[idx] - np.stack(refs)[np.maximum(cur, 0)]
    return out


def training_targets(t: FeatureTable, layout, min_force_n: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Class per chirp (``len(layout)`` = no touch) and which may train: presses lighter than ``min_force_n`` do not."""
    loc = t["location"]
    cls = np.where(loc >= 0, layout.index_of(np.where(loc >= 0, loc, layout.ids[0])), len(layout))
    return cls.astype(np.int64), (loc < 0) | touch_mask(t, min_force_n)


def usable_bins(rig, n_bins: int | None, *, log=None) -> int:
    """OSPA's gamma for this rig: ``n_bins`` (``None``: 300), clamped with a warning to the bins the matched filter leaves."""
    n_allowed = int(rig.allowed_mask.sum())
    want = DEFAULT_N_BINS if n_bins is None else int(n_bins)
    if want > n_allowed:
        msg = f"gamma {want} is more than the {n_allowed} bins of this rig's band; using all {n_allowed}"
        (log or (lambda m: warnings.warn(m, stacklevel=3)))(msg)
        return n_allowed
    return want


# A no-touch reference averages at least this many chirps: a recording with less rest than Alg. 2's beta uses what it
# has, with a warning, down to this (a 10-chirp mean's std is a third of one chirp's, ~0.1 dB simulated).
MIN_REST_CHIRPS = 10


def rest_runs(quiet: np.ndarray, session: np.ndarray) -> dict[str, int]:
    """Longest run of consecutive no-touch chirps at rest, per session."""
    out = {}
    for s in np.unique(session):
        edges = np.diff(np.r_[0, np.asarray(quiet)[np.asarray(session) == s].astype(np.int8), 0])
        out[str(s)] = int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1), initial=0))
    return out


def rest_beta(t: FeatureTable, beta_chirps: int, *, log=None) -> int | None:
    """Alg. 2's beta: ``beta_chirps``, or the rest every session has, down to :data:`MIN_REST_CHIRPS`; ``None`` below it."""
    runs = rest_runs(quiet_mask(t), t["session"])
    shortest = min(runs.values()) if runs else 0
    if shortest >= beta_chirps:
        return int(beta_chirps)
    if shortest < MIN_REST_CHIRPS:
        return None
    worst = min(runs, key=runs.get)
    msg = (f"session {worst} has {shortest} consecutive hands-off chirps, fewer than beta = {beta_chirps}; "
           f"the no-touch reference averages {shortest} chirps (minimum {MIN_REST_CHIRPS})")
    (log or (lambda m: warnings.warn(m, stacklevel=3)))(msg)
    return int(shortest)
