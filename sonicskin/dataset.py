"""On-disk dataset format (version 1): received audio + per-chirp labels + rig metadata.

Layout of a dataset folder::

    dataset.json                  format, version, rig, layout, source (scenario or recorder)
    <session>/part-00000.flac     a piece of the session's continuous received stream (24-bit FLAC)
    <session>/part-00000.csv      labels of the chirps that start inside that piece
    <session>/part-00001.flac ...

A *session* is one continuous recording; its parts concatenate into the stream, which starts
at an arbitrary point of the chirp train (the reader finds the chirps by cross-correlation,
exactly as for a live recording).  Each label row is one chirp: ``t_s`` is where it starts in
the session stream, in seconds.  Parts are written atomically (temporary file, then rename;
the CSV last), so an interrupted run keeps every part already written and a reader never
sees half a part.  Label columns: see :data:`COLUMNS`.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .dsp import frame_stream, log_magnitude_db, rig_chirp
from .errors import SonicskinError
from .rig import Layout, Rig

__all__ = ["FORMAT", "VERSION", "COLUMNS", "DatasetError", "DatasetWriter", "Dataset", "FeatureTable"]

FORMAT = "sonicskin-dataset"
VERSION = 1
# name -> dtype; location -1 and NaN coordinates mean no touch.
COLUMNS: dict[str, type] = {
    "chirp": int, "t_s": float, "time_s": float, "segment": str, "location": int, "x_cm": float,
    "y_cm": float, "force_n": float, "moving": float, "temperature_c": float, "subject": int,
}
_PART = re.compile(r"part-(\d{5})\.csv$")


class DatasetError(SonicskinError):
    """A dataset folder that cannot be read as it is; the message says what and where."""


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _atomic_write_json(path: Path, obj: Any) -> None:
    _atomic_write_bytes(path, (json.dumps(obj, indent=2) + "\n").encode())


class DatasetWriter:
    """Create (or resume) a dataset folder and append session parts to it.

    Parameters
    ----------
    root : folder to write.
    rig, layout : stored in ``dataset.json``; resuming checks they match.
    source : free metadata (scenario config, recorder settings).
    mode : ``"create"`` (fails if the folder holds a dataset), ``"overwrite"`` or ``"resume"``.
    """

    def __init__(self, root: str | Path, rig: Rig, layout: Layout, *, source: dict | None = None,
                 mode: str = "create"):
        self.root, self.rig, self.layout = Path(root), rig, layout
        meta_path = self.root / "dataset.json"
        meta = {"format": FORMAT, "version": VERSION, "rig": rig.to_dict(), "layout": layout.to_dict(),
                "source": source or {}}
        if meta_path.exists():
            if mode == "create":
                raise FileExistsError(f"{self.root} already holds a dataset; pass --resume to continue it "
                                      f"or --overwrite to replace it")
            if mode == "overwrite":
                import shutil
                shutil.rmtree(self.root)
            elif mode == "resume":
                old = Dataset(self.root)
                diffs = old.rig.mismatch(rig)
                if diffs or old.layout != layout or old.meta.get("source") != meta["source"]:
                    raise DatasetError(f"cannot resume {self.root}: it was made with other settings "
                                       f"({'; '.join(diffs) or 'layout or source differ'})")
            else:
                raise ValueError(f"mode must be create, overwrite or resume, got {mode!r}")
        self.root.mkdir(parents=True, exist_ok=True)
        if not meta_path.exists():
            _atomic_write_json(meta_path, meta)

    def session_done(self, session: str) -> bool:
        return (self.root / session / "session.json").exists()

    def write_part(self, session: str, part: int, audio: np.ndarray, labels: dict[str, np.ndarray]) -> Path:
        """Write part ``part`` of ``session``: ``audio`` (n_samples,) in [-1, 1] and its chirps' labels."""
        import soundfile as sf

        d = self.root / session
        d.mkdir(exist_ok=True)
        missing = set(COLUMNS) - set(labels)
        if missing:
            raise ValueError(f"labels lack columns {sorted(missing)}")
        n = {len(np.atleast_1d(v)) for v in labels.values()}
        if len(n) != 1:
            raise ValueError(f"label columns have different lengths {sorted(n)}")
        buf = io.BytesIO()
        sf.write(buf, np.asarray(audio, dtype=np.float32), int(self.rig.fs_hz), format="FLAC", subtype="PCM_24")
        _atomic_write_bytes(d / f"part-{part:05d}.flac", buf.getvalue())
        text = io.StringIO()
        w = csv.writer(text, lineterminator="\n")
        w.writerow(COLUMNS)
        cols = [np.atleast_1d(labels[c]) for c in COLUMNS]
        for row in zip(*cols):
            w.writerow([f"{v:.9g}" if isinstance(v, (float, np.floating)) else v for v in row])
        _atomic_write_bytes(d / f"part-{part:05d}.csv", text.getvalue().encode())
        return d / f"part-{part:05d}.csv"

    def finish_session(self, session: str, info: dict | None = None) -> None:
        _atomic_write_json(self.root / session / "session.json", {"complete": True, **(info or {})})


class FeatureTable:
    """Features of every chirp of a dataset with its labels (column arrays), in stream order."""

    def __init__(self, X: np.ndarray, labels: dict[str, np.ndarray]):
        self.X, self.labels = X, labels

    def __len__(self) -> int:
        return self.X.shape[0]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.labels[name]

    def select(self, mask: np.ndarray) -> FeatureTable:
        return FeatureTable(self.X[mask], {k: v[mask] for k, v in self.labels.items()})

    @property
    def touch(self) -> np.ndarray:
        return self.labels["location"] >= 0

    def save_npz(self, path: str | Path) -> None:
        """Plain arrays, readable with ``np.load(..., allow_pickle=False)``."""
        arrays = {f"label_{k}": v for k, v in self.labels.items()}
        np.savez(path, X=self.X, **arrays)

    @classmethod
    def load_npz(cls, path: str | Path) -> FeatureTable:
        with np.load(path, allow_pickle=False) as z:
            return cls(z["X"], {k[6:]: z[k] for k in z.files if k.startswith("label_")})


# Bounds that keep a corrupt dataset.json from asking for absurd memory (n_chirp 1e12) or time.
_MAX_N_CHIRP = 1 << 22
_MAX_FS_HZ = 10e6
_MAX_LOCATIONS = 100_000


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def check_meta(meta: Any, path: Path | str) -> tuple[Rig, Layout]:
    """Validate a parsed ``dataset.json`` completely; returns its rig and layout.

    Raises :class:`DatasetError` naming the field and what it should be.
    """
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: expected a JSON object with format, version, rig and layout, got a JSON "
                           f"{type(meta).__name__}; the file is corrupt (re-create the dataset)")
    if meta.get("format") != FORMAT:
        raise DatasetError(f"{path}: format is {meta.get('format')!r}, expected {FORMAT!r}")
    if meta.get("version") != VERSION or isinstance(meta.get("version"), bool):
        raise DatasetError(f"{path}: dataset version {meta.get('version')!r} is not supported "
                           f"(this sonicskin reads version {VERSION})")
    for key in ("rig", "layout"):
        if not isinstance(meta.get(key), dict):
            raise DatasetError(f"{path}: {key!r} must be a JSON object, got {type(meta.get(key)).__name__}")
    if not isinstance(meta.get("source", {}), dict):
        raise DatasetError(f"{path}: 'source' must be a JSON object, got {type(meta['source']).__name__}")
    r = meta["rig"]
    for k in ("fs_hz", "f_lo_hz", "f_hi_hz", "pwm_halfwidth_hz", "amplitude"):
        if k in r and not _is_number(r[k]):
            raise DatasetError(f"{path}: rig.{k} must be a finite number, got {r[k]!r}")
    if "n_chirp" in r and not (isinstance(r["n_chirp"], int) and not isinstance(r["n_chirp"], bool)
                               and 64 <= r["n_chirp"] <= _MAX_N_CHIRP):
        raise DatasetError(f"{path}: rig.n_chirp must be a whole number of samples in 64..{_MAX_N_CHIRP}, got {r['n_chirp']!r}")
    if "fs_hz" in r and not 0 < r["fs_hz"] <= _MAX_FS_HZ:
        raise DatasetError(f"{path}: rig.fs_hz must be in (0, {_MAX_FS_HZ:g}] Hz, got {r['fs_hz']!r}")
    if "pwm_hz" in r and not (isinstance(r["pwm_hz"], list) and len(r["pwm_hz"]) <= 64 and all(map(_is_number, r["pwm_hz"]))):
        raise DatasetError(f"{path}: rig.pwm_hz must be a list of frequencies in Hz, got {r['pwm_hz']!r}")
    for k in ("name", "sweep_b64"):
        if r.get(k) is not None and not isinstance(r[k], str):
            raise DatasetError(f"{path}: rig.{k} must be a text, got {r[k]!r}")
    lay = meta["layout"]
    ids, xy = lay.get("ids"), lay.get("xy_cm")
    if not (isinstance(ids, list) and 0 < len(ids) <= _MAX_LOCATIONS
            and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in ids)):
        raise DatasetError(f"{path}: layout.ids must be a non-empty list of location ids (whole numbers >= 0)")
    if not (isinstance(xy, list) and len(xy) == len(ids)
            and all(isinstance(p, list) and len(p) == 2 and all(map(_is_number, p)) for p in xy)):
        raise DatasetError(f"{path}: layout.xy_cm must list one [x, y] pair of numbers per id ({len(ids)})")
    c = lay.get("circumference_cm")
    if c is not None and not (_is_number(c) and c > 0):
        raise DatasetError(f"{path}: layout.circumference_cm must be a positive number or null, got {c!r}")
    try:
        return Rig.from_dict(r), Layout.from_dict(lay)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise DatasetError(f"{path}: bad rig or layout metadata ({e})") from None


class Dataset:
    """Read and validate a dataset folder."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        meta_path = self.root / "dataset.json"
        if not meta_path.is_file():
            raise DatasetError(f"{self.root} is not a sonicskin dataset: dataset.json is missing "
                               f"(create one with `sonicskin simulate` or `sonicskin record`)")
        try:
            self.meta = json.loads(meta_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise DatasetError(f"{meta_path} is not valid JSON ({e}); the file is corrupt") from None
        self.rig, self.layout = check_meta(self.meta, meta_path)

    @property
    def sessions(self) -> list[str]:
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and any(p.glob("part-*.csv")))

    def parts(self, session: str) -> list[int]:
        """Complete parts of a session, contiguous from 0 (a part after a gap is ignored)."""
        nums = sorted(int(m.group(1)) for p in (self.root / session).iterdir() if (m := _PART.match(p.name)))
        out = []
        for k, n in enumerate(nums):
            if n != k or not (self.root / session / f"part-{n:05d}.flac").is_file():
                break
            out.append(n)
        return out

    def _read_labels(self, path: Path) -> dict[str, np.ndarray]:
        try:
            with open(path, newline="", encoding="utf-8") as fh:
                rows = list(csv.reader(fh))
        except (UnicodeDecodeError, csv.Error) as e:
            raise DatasetError(f"{path}: not a readable labels CSV ({e}); delete this part and the ones after it "
                               f"and record them again (--resume)") from None
        if not rows or rows[0] != list(COLUMNS):
            raise DatasetError(f"{path}: header must be {','.join(COLUMNS)}; got {','.join(rows[0]) if rows else 'nothing'}")
        body = rows[1:]
        out = {}
        for j, (name, typ) in enumerate(COLUMNS.items()):
            try:
                vals = [r[j] for r in body]
                out[name] = np.array(vals, dtype=object if typ is str else typ).astype(str if typ is str else typ)
            except (ValueError, IndexError) as e:
                raise DatasetError(f"{path}: column {name!r} has a bad value ({e})") from None
        return out

    def _check_session_json(self, session: str) -> None:
        """``session.json`` (written last, when the session is complete) must be a JSON object
        ``{"complete": true, ...}`` when present."""
        path = self.root / session / "session.json"
        if not path.exists():
            return
        try:
            info = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError, OSError) as e:
            raise DatasetError(f"{path} is corrupt ({e}); delete it to treat the session as unfinished") from None
        if not isinstance(info, dict) or info.get("complete") is not True:
            raise DatasetError(f"{path}: expected a JSON object with \"complete\": true; delete it to treat the "
                               f"session as unfinished")

    def read_session(self, session: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The session's chirp-aligned frames (n, n_chirp) float32 and their labels."""
        import soundfile as sf

        parts = self.parts(session)
        if not parts:
            raise DatasetError(f"{self.root / session}: no complete part")
        self._check_session_json(session)
        audio, labels = [], []
        for p in parts:
            fpath = self.root / session / f"part-{p:05d}.flac"
            try:
                x, sr = sf.read(fpath, dtype="float32", always_2d=True)
            except RuntimeError as e:
                raise DatasetError(f"{fpath}: unreadable audio ({e}); delete this part and the ones after it") from None
            if sr != int(self.rig.fs_hz):
                raise DatasetError(f"{fpath}: sample rate {sr} Hz, but the dataset's rig runs at {self.rig.fs_hz:g} Hz")
            if x.shape[1] != 1:
                raise DatasetError(f"{fpath}: {x.shape[1]} channels; a part holds the receiver channel only")
            audio.append(x[:, 0])
            labels.append(self._read_labels(self.root / session / f"part-{p:05d}.csv"))
        stream = np.concatenate(audio)
        lab = {k: np.concatenate([d[k] for d in labels]) for k in COLUMNS}
        L = self.rig.n_chirp
        frames, offset = frame_stream(stream, rig_chirp(self.rig))
        pos = (lab["t_s"] * self.rig.fs_hz - offset) / L
        idx = np.round(pos).astype(int)
        bad = (np.abs(pos - idx) > 0.25) | (idx < 0)
        # A recording may stop inside its last labelled chirp: that chirp is dropped, not an error.
        cut = idx >= frames.shape[0]
        if cut.any() and np.flatnonzero(cut)[0] < idx.size - 2:
            bad |= cut
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise DatasetError(
                f"{self.root / session}: label row {k} (t_s={lab['t_s'][k]:.6f}) does not fall on a chirp of the stream "
                f"(chirps start at {offset / self.rig.fs_hz:.6f} s + k * {self.rig.period_s:.6f} s); labels and audio disagree")
        keep = ~cut
        lab = {k: v[keep] for k, v in lab.items()}
        lab["session"] = np.full(int(keep.sum()), session)
        return frames[idx[keep]], lab

    def iter_sessions(self, sessions: list[str] | None = None) -> Iterator[tuple[str, np.ndarray, dict[str, np.ndarray]]]:
        for s in sessions or self.sessions:
            frames, lab = self.read_session(s)
            yield s, frames, lab

    def features(self, sessions: list[str] | None = None, *, progress: bool = True) -> FeatureTable:
        """dB-magnitude features of every labelled chirp (see :func:`sonicskin.dsp.log_magnitude_db`)."""
        from tqdm.auto import tqdm

        names = sessions or self.sessions
        if not names:
            raise DatasetError(f"{self.root}: no session with a complete part")
        Xs, labs = [], []
        for _, frames, lab in tqdm(self.iter_sessions(names), total=len(names), desc="features", unit="session",
                                   disable=not progress):
            Xs.append(log_magnitude_db(frames, self.rig))
            labs.append(lab)
        return FeatureTable(np.concatenate(Xs), {k: np.concatenate([d[k] for d in labs]) for k in labs[0]})
