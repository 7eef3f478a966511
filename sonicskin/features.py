"""What both models see: the OSPA-selected bins, absolute or relative to the no-touch reference.

``mode="absolute"``: dB magnitudes of the selected bins (the paper's input).
``mode="relative"``: the same minus the running no-touch reference of the stream, i.e. Alg. 2's
online updating applied to the *features* (mean of 3 s of rest, refreshed every 20 min), so
a slow drift of the channel is removed before either model sees it.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from .calibration import OnlineReference
from .dataset import Dataset, FeatureTable

__all__ = ["FeatureSpec", "Split", "relative_features", "load_features_cached", "quiet_mask", "touch_mask",
           "select_bins", "model_inputs", "prepare"]

MODES = ("absolute", "relative")


def quiet_mask(t: FeatureTable) -> np.ndarray:
    """No-touch chirps with the robot at rest: Alg. 2's calibration chirps."""
    return (t["location"] < 0) & (t["moving"] == 0)


def touch_mask(t: FeatureTable, min_force_n: float = 0.5) -> np.ndarray:
    """Touch chirps: a location and a force of at least ``min_force_n`` (or no force sensor: NaN)."""
    f = t["force_n"]
    return (t["location"] >= 0) & ((f >= min_force_n) | np.isnan(f))


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
        """A fresh Alg. 2 reference for one stream (``kw``: ``score_fn``)."""
        return OnlineReference.from_seconds(beta_s=self.beta_s, alpha_s=self.alpha_s, chirps_per_s=chirps_per_s,
                                            relative=self.mode == "relative", **kw)

    def transform(self, t: FeatureTable, chirps_per_s: float, *, online: bool = True) -> np.ndarray:
        """Model inputs (n, len(bins)) float32 for every chirp of ``t`` (sessions are separate streams),
        the reference from the labelled no-touch chirps: for *training* sessions.  Test streams are
        replayed through :meth:`sonicskin.runtime.SkinRuntime.replay`."""
        X = t.X[:, list(self.bins)]
        if self.mode == "absolute":
            return X.astype(np.float32)
        return relative_features(X, quiet_mask(t), t["session"], t["time_s"], self.reference(chirps_per_s),
                                 online=online)

    def to_dict(self) -> dict:
        return {"bins": [int(b) for b in self.bins], "mode": self.mode, "beta_s": self.beta_s, "alpha_s": self.alpha_s}

    @classmethod
    def from_dict(cls, d: dict) -> FeatureSpec:
        return cls(tuple(int(b) for b in d["bins"]), d["mode"], float(d["beta_s"]), float(d["alpha_s"]))


def relative_features(X: np.ndarray, quiet: np.ndarray, session: np.ndarray, time_s: np.ndarray,
                      calibrator: OnlineReference, *, online: bool = True) -> np.ndarray:
    """``X`` minus the running no-touch reference of its own session, from the *known* no-touch chirps.

    Alg. 2 through :class:`~sonicskin.calibration.OnlineReference` (the object the live loop
    runs), fed with the labels instead of a detector: the boot reference is the first ``beta``
    consecutive ``quiet`` chirps of each session (the protocol's hands-off calibration) and
    refreshes take the next ``beta`` quiet chirps once ``alpha`` has passed.  This is for the
    *training* session(s), whose labels are the protocol; test streams are replayed with the
    model's own detection (:meth:`sonicskin.runtime.SkinRuntime.replay`) and never see labels.
    Chirps before the first reference use it too (training only).

    ``calibrator`` gives beta, alpha and the clock (a fresh reference is made per session);
    ``online=False`` keeps the boot reference throughout.
    """
    beta, alpha, cps = calibrator.beta, calibrator.alpha, calibrator.cps
    X = np.asarray(X, np.float32)
    out = np.empty(X.shape, np.float32)
    for s in np.unique(session):
        idx = np.flatnonzero(session == s)
        ref = OnlineReference(beta, alpha if online else None, cps)
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


def _signature(ds: Dataset) -> str:
    h = hashlib.sha256()
    for s in ds.sessions:
        for p in ds.parts(s):
            f = ds.root / s / f"part-{p:05d}.flac"
            h.update(f"{s}/{p}:{f.stat().st_size}:{f.stat().st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def load_features_cached(ds: Dataset, *, progress: bool = True) -> FeatureTable:
    """:meth:`Dataset.features`, cached as plain arrays in ``<dataset>/.cache`` (rebuilt when parts change)."""
    cache = ds.root / ".cache" / f"features-{_signature(ds)}.npz"
    if cache.is_file():
        return FeatureTable.load_npz(cache)
    t = ds.features(progress=progress)
    cache.parent.mkdir(exist_ok=True)
    for old in cache.parent.glob("features-*.npz"):
        old.unlink()
    tmp = cache.with_suffix(".tmp.npz")
    t.save_npz(tmp)
    Path(tmp).replace(cache)
    return t


def training_targets(t: FeatureTable, layout, min_force_n: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Class per chirp (layout row of the touched location, ``len(layout)`` = no touch) and which chirps
    may train: light presses (0 < F < ``min_force_n``) are neither a clear touch nor no touch."""
    loc = t["location"]
    cls = np.where(loc >= 0, layout.index_of(np.where(loc >= 0, loc, layout.ids[0])), len(layout))
    return cls.astype(np.int64), (loc < 0) | touch_mask(t, min_force_n)


def select_bins(t: FeatureTable, rig, n_bins: int = 300, min_force_n: float = 0.5) -> np.ndarray:
    """OSPA (Alg. 1) on a training table: touch chirps vs moving no-touch chirps (quiet ones when
    the robot never moved), over the matched-filter mask of the rig.  Returns band-bin indices,
    best first."""
    from .ospa import OSPA

    touch = touch_mask(t, min_force_n)
    moving = (t["location"] < 0) & (t["moving"] > 0)
    ref = moving if moving.sum() >= 2 else quiet_mask(t)
    if touch.sum() < 2 or ref.sum() < 2:
        raise ValueError(f"OSPA needs touch and no-touch chirps in the training split; got {int(touch.sum())} "
                         f"touch and {int(ref.sum())} no-touch chirps")
    return OSPA(gamma=n_bins, allowed=rig.allowed_mask).fit(t.X[touch], X_moving=t.X[ref]).selected_


@dataclasses.dataclass(frozen=True)
class Split:
    """Which sessions train, validate and test.  Never a random split of chirps: sessions (or
    people, for leave-subjects-out) are the unit, so nothing of a test press leaks into training."""

    train: tuple[str, ...]
    val: tuple[str, ...]
    test: tuple[str, ...]

    @classmethod
    def make(cls, t: FeatureTable, *, train_sessions=None, val_sessions=None, test_subjects=None,
             allow_no_test: bool = False) -> Split:
        sessions = sorted(set(t["session"]))
        if test_subjects:
            subj = {s: set(t["subject"][(t["session"] == s) & (t["location"] >= 0)]) for s in sessions}
            test = [s for s in sessions if subj[s] & set(test_subjects)]
            rest = [s for s in sessions if s not in test]
            if not test or len(rest) < 2:
                raise ValueError(f"leave-subjects-out with test subjects {list(test_subjects)} leaves "
                                 f"{len(rest)} training and {len(test)} test sessions; need >= 2 and >= 1")
            return cls(tuple(rest[:-1]), tuple(rest[-1:]), tuple(test))
        train = list(train_sessions or sessions[:1])
        unknown = set(train) - set(sessions)
        if unknown:
            raise ValueError(f"training sessions {sorted(unknown)} are not in the dataset ({sessions})")
        rest = [s for s in sessions if s not in train]
        if val_sessions is None:
            val = rest[:1] if len(rest) >= 2 else []
        else:
            val = list(val_sessions)
        test = [s for s in rest if s not in val]
        if not test and not allow_no_test:
            raise ValueError(f"no session left to test on (sessions {sessions}, train {train}, val {val})")
        return cls(tuple(train), tuple(val), tuple(test))

    def mask(self, t: FeatureTable, part: str) -> np.ndarray:
        return np.isin(t["session"], getattr(self, part))

    def to_dict(self) -> dict:
        return {"train": list(self.train), "val": list(self.val), "test": list(self.test)}


def model_inputs(data, spec: FeatureSpec, *, progress: bool = True) -> tuple[Dataset, FeatureTable, np.ndarray]:
    """A dataset's features table and the model inputs ``spec`` defines, for every chirp."""
    ds = data if isinstance(data, Dataset) else Dataset(data)
    t = load_features_cached(ds, progress=progress)
    return ds, t, spec.transform(t, ds.rig.chirps_per_s)


def prepare(data: str | Path, *, n_bins: int = 300, mode: str = "relative", train_sessions=None,
            val_sessions=None, test_subjects=None, min_force_n: float = 0.5, progress: bool = True,
            allow_no_test: bool = False) -> dict:
    """Load a dataset, split it by session/subject, select OSPA bins on the training split and build
    model inputs for every chirp.  Shared by the DataModule, the SVM baseline and ``compare``."""
    ds = Dataset(data)
    t = load_features_cached(ds, progress=progress)
    split = Split.make(t, train_sessions=train_sessions, val_sessions=val_sessions, test_subjects=test_subjects,
                       allow_no_test=allow_no_test)
    tr = t.select(split.mask(t, "train"))
    bins = select_bins(tr, ds.rig, n_bins, min_force_n)
    spec = FeatureSpec(tuple(int(b) for b in bins), mode)
    X = spec.transform(t, ds.rig.chirps_per_s)
    cls, usable = training_targets(t, ds.layout, min_force_n)
    return {"dataset": ds, "table": t, "split": split, "spec": spec, "X": X, "cls": cls,
            "force": t["force_n"].astype(np.float32), "usable": usable, "n_locations": len(ds.layout)}
