"""What both models see: the OSPA-selected bins, absolute or relative to the no-touch reference.

``mode="absolute"``: dB magnitudes of the selected bins (the paper's input).
``mode="relative"``: the same minus the running no-touch reference of the stream, i.e. Alg. 2's
online updating applied to the *features* (mean of 3 s of rest, refreshed every 20 min), so
a slow drift of the channel is removed before either model sees it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import uuid
import warnings
import zipfile
from pathlib import Path

import numpy as np

from .calibration import OnlineReference
from .dataset import Dataset, FeatureTable

__all__ = ["FeatureSpec", "Split", "relative_features", "load_features_cached", "quiet_mask", "touch_mask",
           "select_bins", "usable_bins", "rest_beta", "MIN_REST_CHIRPS"]

MODES = ("absolute", "relative")
DEFAULT_N_BINS = 300  # the paper's gamma


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
        """A fresh Alg. 2 reference for one stream (``kw``: ``score_fn``, or ``relative`` to override the mode's)."""
        kw.setdefault("relative", self.mode == "relative")
        return OnlineReference.from_seconds(beta_s=self.beta_s, alpha_s=self.alpha_s, chirps_per_s=chirps_per_s, **kw)

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


def _code_version() -> bytes:
    """What the cached values depend on in the code: the package version and the bytes of the modules
    that compute them (reading and framing in dataset.py, the spectra in dsp.py)."""
    from . import __version__, dataset, dsp

    h = hashlib.sha256(f"sonicskin {__version__}".encode())
    for mod in (dataset, dsp):
        try:
            h.update(Path(mod.__file__).read_bytes())
        except (OSError, TypeError):  # a frozen build without sources: the version alone
            h.update(mod.__name__.encode())
    return h.digest()


def _signature(ds: Dataset) -> str:
    """Cache key of a dataset's features: the sha256 of everything that changes their values: the code
    (:func:`_code_version`), ``dataset.json`` (rig, layout), and per session the bytes of every part's
    FLAC and CSV and of ``session.json`` (which parts count)."""
    h = hashlib.sha256(_code_version())
    h.update(ds.meta_sha256.encode())
    ds.check_distinct()  # a copied session: refused before a cache could hide it
    for s in ds.sessions:
        d = ds.root / s
        info = d / "session.json"
        h.update(f"session {s} {len(ds.parts(s))}\n".encode())
        if info.is_file():
            h.update(hashlib.sha256(info.read_bytes()).digest())
        for p in ds.parts(s):
            for ext in ("flac", "csv"):
                f = d / f"part-{p:05d}.{ext}"
                fh = hashlib.sha256()
                with open(f, "rb") as stream:
                    for block in iter(lambda: stream.read(1 << 20), b""):
                        fh.update(block)
                h.update(f"{p}.{ext}".encode() + fh.digest())
    return h.hexdigest()


def _content_digest(t: FeatureTable) -> str:
    """sha256 of a feature table's arrays (features and every label column), in a fixed order."""
    h = hashlib.sha256(np.ascontiguousarray(t.X).tobytes())
    for k in sorted(t.labels):
        v = np.asarray(t.labels[k])
        h.update(k.encode() + str(v.dtype).encode() + np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


def _cache_differs(ds: Dataset, t: FeatureTable, cache: Path) -> str | None:
    """Why a loaded cache is not what the dataset holds (``""``: an older cache without a digest), or ``None``.

    The key binds the cache to the recordings' bytes, not the cache's own content: a cache whose labels were edited
    with its key kept was trusted (``fit-svm`` then wrote another ``svm.onnx`` from the same recordings).  Here the
    label rows are checked against the label CSVs (a session's last one or two rows may be missing: a recording that
    stops inside its last chirp), and the whole content against the digest stored when the cache was written."""
    from .dataset import COLUMNS

    stored = FeatureTable.stored_content(cache)
    if stored is None:  # written by an older sonicskin (no digest): rebuilt once, nothing to warn about
        return ""
    if stored != _content_digest(t):
        return "its content does not match the digest stored with it"
    for s in ds.sessions:
        rows = t["session"] == s
        parts = [ds._read_labels(ds.root / s / f"part-{p:05d}.csv") for p in ds.parts(s)]
        if not parts:
            continue
        n, n_csv = int(rows.sum()), sum(len(q["chirp"]) for q in parts)
        if not n_csv - 2 <= n <= n_csv:
            return f"it holds {n} chirps of session {s}, whose labels list {n_csv}"
        for c in COLUMNS:
            want = np.concatenate([q[c] for q in parts])[:n]
            got = t[c][rows]
            same = (np.array_equal(got, want, equal_nan=True) if want.dtype.kind == "f" else
                    np.array_equal(got.astype(want.dtype), want))
            if not same:
                return f"its column {c!r} of session {s} differs from the session's label CSVs"
    return None


def load_features_cached(ds: Dataset, *, progress: bool = True) -> FeatureTable:
    """:meth:`Dataset.features`, cached as plain arrays in ``<dataset>/.cache``.

    The cache is keyed by content (:func:`_signature`: code, dataset.json, the bytes of every part's
    audio and labels), so editing a label or replacing a part rebuilds it; a cache file that is
    damaged, of other data or inconsistent (a label column one short) is rebuilt, never trusted; one whose
    content was edited (its key kept) is rebuilt with a warning (:func:`_cache_differs`).
    """
    key = _signature(ds)
    cache = ds.root / ".cache" / f"features-{key[:16]}.npz"
    if cache.is_file():
        try:
            t = FeatureTable.load_npz(cache, key=key, n_features=ds.rig.n_band)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # damaged or stale cache: rebuilt from the audio below
            pass
        else:
            why = _cache_differs(ds, t, cache)
            if why is None:
                return t
            if why:
                warnings.warn(f"{cache}: {why}; the cache was edited (its key kept): rebuilt from the recordings",
                              stacklevel=2)
    t = ds.features(progress=progress)
    # Several processes may build the cache at once (DDP ranks, parallel `compare` runs): each writes its
    # own temporary file and renames it atomically; stale caches of other signatures are removed after.
    tmp = cache.parent / f".{cache.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.npz"
    try:
        cache.parent.mkdir(exist_ok=True)
        t.save_npz(tmp, key=key, content=_content_digest(t))
        os.replace(tmp, cache)
    except OSError:  # a read-only dataset, a full disk, a file named .cache: features are simply not cached
        return t
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    for old in cache.parent.glob("features-*.npz"):
        if old.name != cache.name:
            old.unlink(missing_ok=True)
    return t


def training_targets(t: FeatureTable, layout, min_force_n: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Class per chirp (layout row of the touched location, ``len(layout)`` = no touch) and which chirps
    may train: light presses (0 < F < ``min_force_n``) are neither a clear touch nor no touch."""
    loc = t["location"]
    cls = np.where(loc >= 0, layout.index_of(np.where(loc >= 0, loc, layout.ids[0])), len(layout))
    return cls.astype(np.int64), (loc < 0) | touch_mask(t, min_force_n)


def usable_bins(rig, n_bins: int | None, *, log=None) -> int:
    """OSPA's gamma for this rig: ``n_bins``, or every bin the matched filter leaves when fewer are there.

    ``None`` asks for the paper's 300.  A larger gamma than the rig has bins (a 165-bin table) is
    clamped with a warning, so a default never turns into an error.
    """
    n_allowed = int(rig.allowed_mask.sum())
    want = DEFAULT_N_BINS if n_bins is None else int(n_bins)
    if want > n_allowed:
        msg = f"gamma {want} is more than the {n_allowed} bins of this rig's band; using all {n_allowed}"
        (log or (lambda m: warnings.warn(m, stacklevel=3)))(msg)
        return n_allowed
    return want


def select_bins(t: FeatureTable, rig, n_bins: int | None = 300, min_force_n: float = 0.5, *, log=None) -> np.ndarray:
    """OSPA (Alg. 1) on a training table: touch chirps vs moving no-touch chirps (quiet ones when
    the robot never moved), over the matched-filter mask of the rig.  Returns band-bin indices,
    best first.

    Without no-touch chirps (a table of touches only) the moving variance is taken as 1, as
    :class:`~sonicskin.ospa.OSPA` documents: the bins with the largest touch variance are kept.
    ``n_bins`` larger than the rig's bins is clamped (:func:`usable_bins`).
    """
    from .ospa import OSPA

    touch = touch_mask(t, min_force_n)
    moving = (t["location"] < 0) & (t["moving"] > 0)
    ref = moving if moving.sum() >= 2 else quiet_mask(t)
    if touch.sum() < 2:
        raise ValueError(f"OSPA needs touch chirps in the training split; got {int(touch.sum())}")
    gamma = usable_bins(rig, n_bins, log=log)
    X_ref = t.X[ref] if ref.sum() >= 2 else None
    return OSPA(gamma=gamma, allowed=rig.allowed_mask).fit(t.X[touch], X_moving=X_ref).selected_


# A no-touch reference averages at least this many chirps.  Alg. 2's beta is 3 s (28 chirps on the
# paper's rig); a recording whose rest is shorter (3 s that start inside a chirp hold 27 whole ones)
# uses the rest it has, with a warning, down to this minimum.  The std of a 10-chirp mean is a third
# of one chirp's, about 0.1 dB on the simulated rig.
MIN_REST_CHIRPS = 10


def rest_runs(quiet: np.ndarray, session: np.ndarray) -> dict[str, int]:
    """Longest run of consecutive no-touch chirps at rest, per session."""
    out = {}
    for s in np.unique(session):
        edges = np.diff(np.r_[0, np.asarray(quiet)[np.asarray(session) == s].astype(np.int8), 0])
        out[str(s)] = int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1), initial=0))
    return out


def rest_beta(t: FeatureTable, beta_chirps: int, *, log=None) -> int | None:
    """Alg. 2's beta for these streams: ``beta_chirps``, or the longest rest every session has when that
    is shorter but at least :data:`MIN_REST_CHIRPS` (with a warning).  ``None``: some session has less
    rest than the minimum (no online reference can be measured; use absolute features)."""
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
            raise ValueError(f"training sessions {sorted(unknown)} are not in the dataset ({', '.join(sessions)})")
        rest = [s for s in sessions if s not in train]
        if val_sessions is None:
            val = rest[:1] if len(rest) >= 2 else []
        else:  # never a session that trains (validation would score training data) or one the data lacks
            val = list(val_sessions)
            for bad, why in ((sorted(set(val) - set(sessions)), "are not in the dataset"),
                             (sorted(set(val) & set(train)), "are training sessions too")):
                if bad:
                    raise ValueError(f"validation sessions {', '.join(map(str, bad))} {why} (train {', '.join(train)}); "
                                     f"validate on sessions that do not train: {', '.join(rest) or 'none left'}")
        test = [s for s in rest if s not in val]
        if not test and not allow_no_test:
            raise ValueError(f"no session left to test on (sessions {', '.join(sessions)}; train {', '.join(train)}; val "
                             f"{', '.join(val) or 'none'}): leave one out of the training and validation sessions")
        return cls(tuple(train), tuple(val), tuple(test))

    def mask(self, t: FeatureTable, part: str) -> np.ndarray:
        return np.isin(t["session"], getattr(self, part))

    def to_dict(self) -> dict:
        return {"train": list(self.train), "val": list(self.val), "test": list(self.test)}
