"""On-disk dataset format (version 1): ``dataset.json`` (rig, layout, source), and per session ``part-NNNNN.flac``
(a piece of the continuous received stream) with ``part-NNNNN.csv`` (labels of the chirps starting in it, :data:`COLUMNS`).

Parts are written atomically (the CSV last); a complete session's ``session.json`` binds its parts to each other and
to ``dataset.json`` (docs/artifact.md)."""

from __future__ import annotations

import contextlib
import csv
import ctypes
import dataclasses
import hashlib
import io
import json
import os
import re
import shutil
import sys
import warnings
import weakref
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .dsp import frame_stream, log_magnitude_db, rig_chirp
from .errors import SonicskinError, brief, check_memory, is_number
from .rig import MAX_FS_HZ, MAX_LOCATIONS, MAX_N_CHIRP, Layout, Rig

__all__ = ["FORMAT", "VERSION", "COLUMNS", "SEGMENTS", "SAFE_NAME", "MANIFEST_VERSION", "DatasetError", "DatasetWriter",
           "writer_lock", "swap_folders", "write_file", "named_os_error", "enclosing_dataset", "refuse_inside_dataset",
           "Dataset", "FeatureTable", "Split", "check_name", "check_label_values", "read_npz", "meta_digest", "load_json", "unique_keys"]

FORMAT = "sonicskin-dataset"
VERSION = 1
# name -> dtype; location -1 and NaN coordinates mean no touch.
COLUMNS: dict[str, type] = {
    "chirp": int, "t_s": float, "time_s": float, "segment": str, "location": int, "x_cm": float,
    "y_cm": float, "force_n": float, "moving": float, "temperature_c": float, "subject": int,
}
_PART = re.compile(r"part-(\d{5})\.csv$")
SEGMENTS = ("calibration", "moving", "touch", "gap")
#: Session (and other file-derived) names: a letter or digit, then letters, digits, ``.``, ``_``, ``-``;
#: at most 64 characters.  No separators, no ``..``, no hidden names: a name stays inside its folder.
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
MANIFEST_VERSION = 1
#: libFLAC compression level of the parts written (lossless at every level; 0 costs ~10 % less CPU than the default
#: 5 for ~6 % larger files).
FLAC_LEVEL = 0
MAX_FORCE_N = 1000.0      # a press on a robot link; 1e300 N is a corrupt value, not a force
MAX_ABS_CM = 1e5          # 1 km of surface
TEMPERATURE_C = (-100.0, 200.0)
REDO = "re-create the dataset (simulate/record/import again with --overwrite)"


class DatasetError(SonicskinError):
    """A dataset folder that cannot be read as it is; the message says what and where."""


def check_name(name, what: str = "session name", where: str = "") -> str:
    """``name`` if it is a plain file name (:data:`SAFE_NAME`), else a one-line :class:`DatasetError`."""
    if not isinstance(name, str) or not SAFE_NAME.fullmatch(name) or ".." in name:
        raise DatasetError(f"{where + ': ' if where else ''}{what} {name!r} is not a plain name (letters, digits, '.', '_', "
                           f"'-', starting with a letter or digit, at most 64 characters): it would be written outside "
                           f"the dataset folder or hidden; rename it")
    return name


#: what makes a simulated link's wall (scenario keys): not its touches, people, noise, clock or name
WALL_KEYS = ("material", "geometry", "tx_cm", "rx_cm", "loss_factor", "channel", "bond", "link_seed")


def wall_record(source, rig: Rig, layout: Layout) -> dict:
    """The wall a dataset was recorded on (``training.wall``): its scenario's :data:`WALL_KEYS`, else its rig and layout."""
    sc = source.get("scenario") if isinstance(source, dict) and source.get("kind") in ("simulator", "recorder") else None
    if isinstance(sc, dict):
        g = sc.get("geometry") if isinstance(sc.get("geometry"), dict) else {}
        what, text = {k: sc.get(k) for k in WALL_KEYS}, f"{sc.get('material')} {g.get('kind', 'tube')} " + " x ".join(
            f"{k[:-3]} {v:g} cm" for k, v in g.items() if k.endswith("_cm") and is_number(v))
    else:
        what, text = {"rig": rig.to_dict(), "layout": layout.to_dict()}, f"recorded on rig {rig.name}, {len(layout)} markers"
    return {"sha256": hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:16], "what": text}


def link_wall(scenario, rig: Rig, layout: Layout) -> dict:
    """:func:`wall_record` of a simulated link (its scenario)."""
    return wall_record({"kind": "simulator", "scenario": scenario.to_dict()}, rig, layout)


def other_wall(recorded, here: dict, this: str = "this one's") -> str | None:
    """How the wall ``recorded`` (a :func:`wall_record`; anything else: not recorded) differs from ``here``, said for a
    message ("another wall (...)"); None when it is the same wall or was not recorded."""
    if not isinstance(recorded, dict) or recorded.get("sha256") == here["sha256"]:
        return None
    if recorded.get("what") == here["what"]:
        return f"another {here['what']} (its wall fingerprint differs: another link or simulated wall)"
    return f"another wall ({brief(recorded.get('what'))}; {this}: {here['what']})"


def unique_keys(pairs) -> dict:
    """A JSON object's ``object_pairs_hook`` that refuses a key given twice (``json`` keeps the last one silently)."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"the key {k!r} appears twice")
        out[k] = v
    return out


def load_json(path: Path, *, max_bytes: int = 64 * 2**20, fix: str = REDO):
    """Parse a JSON file strictly: bounded size, UTF-8, no duplicated keys, no NaN/Infinity."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise DatasetError(f"{path} is {size / 2**20:.0f} MB, more than a file of its kind can be ({max_bytes / 2**20:.0f} MB); "
                               f"the file is corrupt; {fix}")
        text = path.read_bytes().decode("utf-8")

        def no_constant(c):
            raise ValueError(f"{c} is not a JSON number")
        return json.loads(text, object_pairs_hook=unique_keys, parse_constant=no_constant)
    except (ValueError, RecursionError) as e:  # JSONDecodeError, UnicodeDecodeError, duplicates
        raise DatasetError(f"{path} is not valid JSON ({str(e).splitlines()[0][:120]}); the file is corrupt; {fix}") from None


def meta_digest(meta: dict) -> str:
    """sha256 of a parsed ``dataset.json`` in canonical form (sorted keys, no spaces)."""
    return hashlib.sha256(json.dumps(meta, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def check_label_values(lab: dict[str, np.ndarray], layout: Layout, where: str) -> None:
    """Every label column in range (the ranges below): one line naming the first bad row and column, else nothing."""
    n = len(lab["chirp"])

    def bad(col: str, mask: np.ndarray, want: str) -> None:
        if np.any(mask):
            k = int(np.flatnonzero(mask)[0])
            v = lab[col][k]
            raise DatasetError(f"{where}: row {k} (chirp {lab['chirp'][k]}): {col} = {getattr(v, 'item', lambda: v)()!r} but {want}; "
                               f"fix the value or {REDO}")

    ids = np.asarray(layout.ids)
    loc = np.asarray(lab["location"])
    bad("location", (loc != -1) & ~np.isin(loc, ids), f"a location is -1 (no touch) or a layout id {ids[0]}..{ids[-1]}")
    f = np.asarray(lab["force_n"], float)
    bad("force_n", ~np.isnan(f) & ~((f >= 0) & (f <= MAX_FORCE_N)), f"a force is NaN (no sensor) or in 0..{MAX_FORCE_N:g} N")
    m = np.asarray(lab["moving"], float)
    bad("moving", ~((m >= 0) & (m <= 1)), "the motion level is a number in [0, 1]")
    for c in ("t_s", "time_s"):
        v = np.asarray(lab[c], float)
        bad(c, ~np.isfinite(v) | (np.abs(v) > 1e10), "a time is a finite number of seconds")
    bad("t_s", np.asarray(lab["t_s"], float) < 0, "a stream time is >= 0")
    for c in ("x_cm", "y_cm"):
        v = np.asarray(lab[c], float)
        bad(c, ~np.isnan(v) & ~(np.abs(v) <= MAX_ABS_CM), "a coordinate is NaN (no touch) or finite cm")
    T = np.asarray(lab["temperature_c"], float)
    bad("temperature_c", ~np.isnan(T) & ~((T >= TEMPERATURE_C[0]) & (T <= TEMPERATURE_C[1])),
        f"a temperature is NaN or in {TEMPERATURE_C[0]:g}..{TEMPERATURE_C[1]:g} C")
    bad("subject", np.asarray(lab["subject"]) < 0, "a subject is a whole number >= 0")
    seg = np.asarray(lab["segment"]).astype(str)
    bad("segment", ~np.isin(seg, SEGMENTS), f"a segment is one of {', '.join(SEGMENTS)}")
    # A touched chirp (location >= 0) lies in a touch segment, at a position: a calibration row with a location
    # would enter the no-touch reference, a touch without coordinates the distance metrics.
    touched = loc >= 0
    bad("segment", touched & (seg != "touch"), "a chirp with a location (>= 0) is in a 'touch' segment")
    for c in ("x_cm", "y_cm"):
        bad(c, touched & ~np.isfinite(np.asarray(lab[c], float)), "a touched chirp (location >= 0) has finite coordinates")
    if n and np.any(np.asarray(lab["chirp"]) < 0):
        bad("chirp", np.asarray(lab["chirp"]) < 0, "chirp numbers are >= 0")


_LOCKS: dict[str, list] = {}  # resolved folder -> [fd, depth]: the writer locks this process holds


@contextlib.contextmanager
def writer_lock(root: str | Path) -> Iterator[Path]:
    """The right to write ``root``, exclusive between processes (``flock``), reentrant within one; no ``fcntl``: no lock."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    key = os.path.realpath(root)
    held = _LOCKS.get(key)
    if held is not None:
        held[1] += 1
    else:
        try:
            import fcntl
        except ImportError:  # not POSIX: writers are not serialised
            yield root
            return
        fd = os.open(key, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise DatasetError(f"{root} is being written by another process (a `sonicskin simulate`, `record` or import "
                               f"into the same folder); wait for it to finish, or choose another --out") from None
        held = _LOCKS[key] = [fd, 1]
    try:
        yield root
    finally:
        held[1] -= 1
        if held[1] == 0:
            del _LOCKS[key]
            os.close(held[0])  # closing the descriptor releases the lock


def enclosing_dataset(path: str | Path) -> Path | None:
    """The dataset folder ``path`` lies inside (a folder above it holding ``dataset.json``), or ``None``."""
    for parent in Path(os.path.abspath(path)).parents:
        if (parent / "dataset.json").is_file():
            return parent
    return None


def refuse_inside_dataset(out: str | Path, what: str) -> None:
    """One line when the output folder ``out`` lies inside a dataset (what is written there would become part of it)."""
    ds = enclosing_dataset(out)
    if ds is not None:
        raise DatasetError(f"--out {out} is inside the dataset {ds}: {what} written there would become part of that "
                           f"dataset's folder; choose an --out outside it")


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where that is not available."""
    if sys.platform != "linux":
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    return fn(-100, os.fsencode(a), -100, os.fsencode(b), 2) == 0  # AT_FDCWD, RENAME_EXCHANGE


def swap_folders(new: Path, old: Path) -> None:
    """Put the folder ``new`` in place of ``old``: one ``renameat2(RENAME_EXCHANGE)`` where Linux offers it, else two renames."""
    if not old.exists():
        os.rename(new, old)
    elif _exchange(new, old):  # new now holds the old folder
        shutil.rmtree(new, ignore_errors=True)
    else:
        aside = old.parent / f".{old.name}.old-{os.getpid()}"
        shutil.rmtree(aside, ignore_errors=True)
        os.rename(old, aside)
        os.rename(new, old)
        shutil.rmtree(aside, ignore_errors=True)


def _empty_folder(root: Path) -> None:
    """Remove everything inside ``root``, keeping the folder (its writer lock is on the folder itself)."""
    for p in root.iterdir():
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


def named_os_error(e: OSError, path: str | Path) -> OSError:
    """``e`` with the path it happened on (a write to an open file names no file: a full disk said no more than ENOSPC)."""
    if e.filename is not None:
        return e
    if e.errno == 28:  # ENOSPC
        return OSError(e.errno, "No space left on device (free some space there, or write elsewhere)", str(path))
    return OSError(e.errno, e.strerror or str(e), str(path))


def write_file(path: str | Path, data: bytes | str) -> None:
    """``Path.write_bytes``/``write_text`` whose errors name ``path`` (:func:`named_os_error`)."""
    try:
        if isinstance(data, str):
            Path(path).write_text(data)
        else:
            Path(path).write_bytes(data)
    except OSError as e:
        raise named_os_error(e, path) from None


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise named_os_error(e, path) from None


def _atomic_write_json(path: Path, obj: Any) -> None:
    _atomic_write_bytes(path, (json.dumps(obj, indent=2) + "\n").encode())


def _settings(source) -> dict:
    """What of a dataset's ``source`` a resumed writer must match: not a recording's ``scenario`` (the wall the simulated
    device played, informative only; recordings made before sonicskin stored it have none)."""
    src = source if isinstance(source, dict) else {}
    return {k: v for k, v in src.items() if not (k == "scenario" and src.get("kind") == "recorder")}


class DatasetWriter:
    """Create (``mode``: create, overwrite, resume) the dataset folder ``root`` and append checked session parts to it."""

    def __init__(self, root: str | Path, rig: Rig, layout: Layout, *, source: dict | None = None,
                 mode: str = "create"):
        self.root, self.rig, self.layout = Path(root), rig, layout
        meta_path = self.root / "dataset.json"
        meta = {"format": FORMAT, "version": VERSION, "rig": rig.to_dict(), "layout": layout.to_dict(), "source": source or {}}
        if mode not in ("create", "overwrite", "resume"):
            raise ValueError(f"mode must be create, overwrite or resume, got {mode!r}")
        refuse_inside_dataset(self.root, "a dataset")
        # Held while this writer lives (and by the caller's own `with writer_lock(root)`, if any): no other process
        # writes, overwrites or cleans up the folder meanwhile.
        lock = writer_lock(self.root)
        lock.__enter__()
        weakref.finalize(self, lock.__exit__, None, None, None)
        if not meta_path.exists() and any(p.name != ".cache" for p in self.root.iterdir()):
            # (an artifact, a project folder: --overwrite would later empty it as a dataset)
            raise FileExistsError(f"{self.root} holds files but no dataset; write the dataset into a new or empty "
                                  f"folder (choose another --out)")
        if meta_path.exists():
            if mode == "create":
                raise FileExistsError(f"{self.root} already holds a dataset; pass --resume to continue it "
                                      f"or --overwrite to replace it")
            if mode == "overwrite":
                _empty_folder(self.root)
            elif mode == "resume":
                old = Dataset(self.root)
                diffs = old.rig.mismatch(rig)
                if diffs or old.layout != layout or _settings(old.meta.get("source")) != _settings(json.loads(json.dumps(meta["source"]))):
                    raise DatasetError(f"cannot resume {self.root}: it was made with other settings "
                                       f"({'; '.join(diffs) or 'layout or source differ'})")
        self.root.mkdir(parents=True, exist_ok=True)
        if not meta_path.exists():
            _atomic_write_json(meta_path, meta)
        self.meta_sha256 = meta_digest(load_json(meta_path))
        self._written: dict[str, dict[int, dict]] = {}  # session -> part -> manifest entry of what this writer wrote

    def session_done(self, session: str) -> bool:
        return (self.root / check_name(session) / "session.json").exists()

    def write_part(self, session: str, part: int, audio: np.ndarray, labels: dict[str, np.ndarray]) -> Path:
        """Write part ``part`` of ``session``: ``audio`` in [-1, 1] or int32 24-bit codes in the upper 24 bits, and its labels."""
        import soundfile as sf

        d = self.root / check_name(session)
        if not (isinstance(part, (int, np.integer)) and 0 <= part <= 99_999):
            raise ValueError(f"part must be a whole number 0..99999, got {part!r}")
        missing = set(COLUMNS) - set(labels)
        if missing:
            raise ValueError(f"labels lack columns {sorted(missing)}")
        n = {len(np.atleast_1d(v)) for v in labels.values()}
        if len(n) != 1:
            raise ValueError(f"label columns have different lengths {sorted(n)}")
        audio = np.asarray(audio)
        if audio.dtype != np.int32:
            audio = audio.astype(np.float32, copy=False)
        if audio.ndim != 1 or (audio.dtype == np.float32 and not np.isfinite(audio).all()):
            raise DatasetError(f"{d}/part-{part:05d}: the audio must be one finite channel (NaN, inf or several "
                               f"channels are not recordings)")
        check_label_values({c: np.atleast_1d(labels[c]) for c in COLUMNS}, self.layout, f"{d}/part-{part:05d}.csv")
        d.mkdir(exist_ok=True)
        buf = io.BytesIO()
        sf.write(buf, audio, int(self.rig.fs_hz), format="FLAC", subtype="PCM_24", compression_level=FLAC_LEVEL / 8)
        flac = buf.getvalue()
        text = io.StringIO()
        w = csv.writer(text, lineterminator="\n")
        w.writerow(COLUMNS)
        cols = [np.atleast_1d(labels[c]) for c in COLUMNS]
        for row in zip(*cols):
            w.writerow([f"{v:.9g}" if isinstance(v, (float, np.floating)) else v for v in row])
        data = text.getvalue().encode()
        _atomic_write_bytes(d / f"part-{part:05d}.flac", flac)
        _atomic_write_bytes(d / f"part-{part:05d}.csv", data)
        self._written.setdefault(session, {})[int(part)] = {
            "part": f"part-{part:05d}", "chirps": int(n.pop()), "flac_sha256": _sha(flac), "csv_sha256": _sha(data)}
        return d / f"part-{part:05d}.csv"

    def finish_session(self, session: str, info: dict | None = None) -> None:
        """Mark ``session`` complete: its ``session.json`` lists every part with its chirp count and hashes."""
        d = self.root / check_name(session)
        nums = sorted(int(m.group(1)) for p in d.iterdir() if (m := _PART.match(p.name)))
        if nums != list(range(len(nums))) or not nums:
            raise DatasetError(f"{d}: parts {nums} are not numbered 0..k without a gap; cannot mark the session complete")
        written = self._written.get(session, {})
        parts = []
        for k in nums:
            entry = written.get(k)
            if entry is None:  # a part written by an earlier run: bound as it is on disk
                flac, data = (d / f"part-{k:05d}.flac").read_bytes(), (d / f"part-{k:05d}.csv").read_bytes()
                rows = max(0, len(data.decode("utf-8", "replace").splitlines()) - 1)
                entry = {"part": f"part-{k:05d}", "chirps": rows, "flac_sha256": _sha(flac), "csv_sha256": _sha(data)}
            parts.append(entry)
        total = sum(p["chirps"] for p in parts)
        _atomic_write_json(d / "session.json", {**(info or {}), "complete": True, "manifest": MANIFEST_VERSION,
                                                 "n_chirps": total, "dataset_sha256": self.meta_sha256, "parts": parts})


def _npy_header(fh) -> tuple[tuple[int, ...], np.dtype]:
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, _, dtype = fmt.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _, dtype = fmt.read_array_header_2_0(fh)
    else:
        raise ValueError(f"unsupported .npy format version {version}")
    return tuple(shape), dtype


def read_npz(path: str | Path, names: dict[str, tuple[str, int | None]], *, optional: tuple[str, ...] = (),
             max_bytes: int | None = None, what: str = "table") -> dict[str, np.ndarray]:
    """Read only the arrays ``names`` (name -> (dtype kinds, ndim)) of an ``.npz``, each checked from its header first."""
    path = Path(path)
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            members = {n[:-4]: n for n in zf.namelist() if n.endswith(".npy")}
            missing = [k for k in names if k not in members and k not in optional]
            if missing:
                raise DatasetError(f"{path}: missing arrays {missing}; the {what} needs {', '.join(k for k in names if k not in optional)}")
            total = 0
            for k, (kinds, ndim) in names.items():
                if k not in members:
                    continue
                info = zf.getinfo(members[k])
                with zf.open(info) as fh:
                    shape, dtype = _npy_header(fh)
                if dtype.hasobject or dtype.kind not in kinds:
                    want = "numbers" if "f" in kinds else "whole numbers" if "i" in kinds else "text"
                    raise DatasetError(f"{path}: array {k!r} has dtype {dtype}, expected {want}")
                if ndim is not None and len(shape) != ndim:
                    raise DatasetError(f"{path}: array {k!r} has shape {shape}, expected {ndim} dimension(s)")
                nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if info.file_size < nbytes:
                    raise DatasetError(f"{path}: array {k!r} is cut short ({info.file_size} of {nbytes} bytes); the file is damaged")
                total += nbytes
                if max_bytes is not None and total > max_bytes:
                    raise DatasetError(f"{path}: array {k!r} {shape} is larger than a {what} of this kind can be")
                check_memory(2 * total, f"the arrays of {path}", "split the table into smaller files")
            with np.load(path, allow_pickle=False) as z:
                for k in names:
                    if k in members:
                        out[k] = z[k]
    except DatasetError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile) as e:
        raise DatasetError(f"{path}: not a readable .npz {what} ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__})") from None
    return out


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

    def save_npz(self, path: str | Path, *, key: str = "", content: str = "") -> None:
        """Plain arrays (``np.load(..., allow_pickle=False)``), with ``key`` and the arrays' ``content`` digest."""
        arrays = {f"label_{k}": v for k, v in self.labels.items()}
        np.savez(path, X=self.X, key=np.array(key), content=np.array(content), **arrays)

    @staticmethod
    def stored_content(path: str | Path) -> str | None:
        """The ``content`` digest stored by :meth:`save_npz`, or ``None`` (none stored, or unreadable)."""
        try:
            z = read_npz(path, {"content": ("U", 0)}, optional=("content",), what="feature cache")
        except DatasetError:
            return None
        return str(z["content"]) if "content" in z else None

    @classmethod
    def load_npz(cls, path: str | Path, *, key: str | None = None, n_features: int | None = None) -> FeatureTable:
        """Load a table saved by :meth:`save_npz`, every column checked (and ``key`` when given); else a :class:`DatasetError`."""
        names = {"X": ("f", 2), "key": ("U", 0)}
        names.update({f"label_{c}": ("iuf" if t in (int, float) else "U", 1) for c, t in COLUMNS.items()})
        names["label_session"] = ("U", 1)
        z = read_npz(path, names, optional=("key",), what="feature cache")
        X = z["X"]
        if key is not None and str(z.get("key", "")) != key:
            raise DatasetError(f"{path}: a feature cache of other data (key {str(z.get('key', ''))[:16]!r})")
        if n_features is not None and X.shape[1] != n_features:
            raise DatasetError(f"{path}: {X.shape[1]} features per chirp, expected {n_features}")
        labels = {k[6:]: z[k] for k in names if k.startswith("label_")}
        short = [k for k, v in labels.items() if v.shape != (X.shape[0],)]
        if short:
            raise DatasetError(f"{path}: label {short[0]!r} has {labels[short[0]].shape[0]} values for {X.shape[0]} rows")
        if not np.isfinite(X).all():
            raise DatasetError(f"{path}: features hold NaN or inf")
        return cls(X, labels)


@dataclasses.dataclass(frozen=True)
class Split:
    """Which sessions train, validate and test: sessions (or people) are the unit, never a random split of chirps."""

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



def check_meta(meta: Any, path: Path | str) -> tuple[Rig, Layout]:
    """Validate a parsed ``dataset.json`` completely (one :class:`DatasetError` line naming the field); returns its rig and layout."""
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
        if k in r and not is_number(r[k]):
            raise DatasetError(f"{path}: rig.{k} must be a finite number, got {r[k]!r}")
    if "n_chirp" in r and not (is_number(r["n_chirp"], integer=True) and 64 <= r["n_chirp"] <= MAX_N_CHIRP):
        raise DatasetError(f"{path}: rig.n_chirp must be a whole number of samples in 64..{MAX_N_CHIRP}, got {r['n_chirp']!r}")
    if "fs_hz" in r and not 0 < r["fs_hz"] <= MAX_FS_HZ:
        raise DatasetError(f"{path}: rig.fs_hz must be in (0, {MAX_FS_HZ:g}] Hz, got {r['fs_hz']!r}")
    if "pwm_hz" in r and not (isinstance(r["pwm_hz"], list) and len(r["pwm_hz"]) <= 64 and all(map(is_number, r["pwm_hz"]))):
        raise DatasetError(f"{path}: rig.pwm_hz must be a list of frequencies in Hz, got {r['pwm_hz']!r}")
    for k in ("name", "sweep_b64"):
        if r.get(k) is not None and not isinstance(r[k], str):
            raise DatasetError(f"{path}: rig.{k} must be a string, got {r[k]!r}")
    lay = meta["layout"]
    ids, xy = lay.get("ids"), lay.get("xy_cm")
    if not (isinstance(ids, list) and 0 < len(ids) <= MAX_LOCATIONS and all(is_number(i, integer=True) and i >= 0 for i in ids)):
        raise DatasetError(f"{path}: layout.ids must be a non-empty list of location ids (whole numbers >= 0)")
    if not (isinstance(xy, list) and len(xy) == len(ids)
            and all(isinstance(p, list) and len(p) == 2 and all(map(is_number, p)) for p in xy)):
        raise DatasetError(f"{path}: layout.xy_cm must list one [x, y] pair of numbers per id ({len(ids)})")
    c = lay.get("circumference_cm")
    if c is not None and not (is_number(c) and c > 0):
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
        self.meta = load_json(meta_path)
        self.rig, self.layout = check_meta(self.meta, meta_path)
        self.meta_sha256 = meta_digest(self.meta)
        self._warned_old = False

    @property
    def sessions(self) -> list[str]:
        """Session folders (a labels CSV or a session.json); one with an unsafe name is refused, not skipped."""
        out = sorted(p.name for p in self.root.iterdir() if p.is_dir() and (any(p.glob("part-*.csv")) or (p / "session.json").is_file()))
        for name in out:
            check_name(name, "session folder", str(self.root))
        return out

    def _session_dir(self, session: str) -> Path:
        d = self.root / check_name(session, where=str(self.root))
        if not d.is_dir():
            raise DatasetError(f"{self.root}: no session {session!r} (sessions: {', '.join(self.sessions) or 'none'})")
        return d

    def parts(self, session: str) -> list[int]:
        """Complete parts of a session, contiguous from 0 (up to a gap; :meth:`read_session` refuses a gap)."""
        d = self._session_dir(session)
        nums = sorted(int(m.group(1)) for p in d.iterdir() if (m := _PART.match(p.name)))
        out = []
        for k, n in enumerate(nums):
            if n != k or not (d / f"part-{n:05d}.flac").is_file():
                break
            out.append(n)
        return out

    def _read_labels(self, path: Path, data: bytes | None = None) -> dict[str, np.ndarray]:
        fix = "delete this part and the ones after it (and session.json) and record them again (--resume)"
        try:
            text = (path.read_bytes() if data is None else data).decode("utf-8")
            rows = [r for r in csv.reader(io.StringIO(text, newline=""))]
        except (UnicodeDecodeError, csv.Error) as e:
            raise DatasetError(f"{path}: not a readable labels CSV ({e}); {fix}") from None
        if not rows or rows[0] != list(COLUMNS):
            raise DatasetError(f"{path}: header must be {','.join(COLUMNS)}; got {','.join(rows[0]) if rows else 'nothing'}; {fix}")
        body = [r for r in rows[1:] if r]
        short = [i for i, r in enumerate(body) if len(r) != len(COLUMNS)]
        if short:
            raise DatasetError(f"{path}: row {short[0]} has {len(body[short[0]])} values, expected {len(COLUMNS)}; {fix}")
        out = {}
        for j, (name, typ) in enumerate(COLUMNS.items()):
            try:
                vals = [r[j] for r in body]
                out[name] = np.array(vals, dtype=object if typ is str else typ).astype(str if typ is str else typ)
            except (ValueError, IndexError, OverflowError) as e:
                raise DatasetError(f"{path}: column {name!r} has a bad value ({e}); {fix}") from None
        return out

    def manifest(self, session: str) -> dict | None:
        """The session's ``session.json`` checked as a manifest, or ``None`` for an unfinished session."""
        path = self._session_dir(session) / "session.json"
        if not path.exists():
            return None
        fix = "delete it to treat the session as unfinished (--resume records it again), or re-create the dataset"
        info = load_json(path, max_bytes=16 * 2**20, fix=fix)
        if not isinstance(info, dict) or info.get("complete") is not True:
            raise DatasetError(f"{path}: expected a JSON object with \"complete\": true; {fix}")
        if "parts" not in info and "manifest" not in info:
            return info  # written before manifests (sonicskin < 0.9): checked by its label rows only
        parts = info.get("parts")
        ok = (info.get("manifest") == MANIFEST_VERSION and isinstance(parts, list) and parts
              and isinstance(info.get("dataset_sha256"), str))
        if ok:
            for k, e in enumerate(parts):
                if not (isinstance(e, dict) and e.get("part") == f"part-{k:05d}"
                        and is_number(e.get("chirps"), integer=True) and e["chirps"] >= 0
                        and all(isinstance(e.get(h), str) and re.fullmatch(r"[0-9a-f]{64}", e[h])
                                for h in ("flac_sha256", "csv_sha256"))):
                    ok = False
                    break
        if not ok:
            raise DatasetError(f"{path}: not a session manifest of version {MANIFEST_VERSION} (parts numbered from 0, "
                               f"each with chirps, flac_sha256 and csv_sha256; dataset_sha256); {fix}")
        if info.get("n_chirps", sum(e["chirps"] for e in parts)) != sum(e["chirps"] for e in parts):
            raise DatasetError(f"{path}: n_chirps {info['n_chirps']!r} is not the sum of its parts' chirps; {fix}")
        if info["dataset_sha256"] != self.meta_sha256:
            raise DatasetError(f"{path} was written for another dataset.json (its rig, layout or source changed since); "
                               f"restore the dataset.json that came with the data, or {REDO}")
        return info

    def _part_bytes(self, session: str, manifest: dict | None) -> list[tuple[int, bytes, bytes]]:
        """(part, FLAC bytes, CSV bytes) of every part, checked against the manifest when there is one."""
        d = self._session_dir(session)
        parts = self.parts(session)
        out = []
        if manifest is None or "parts" not in manifest:
            # Writers write parts in order (FLAC, then CSV): a run killed mid-way leaves at most a FLAC without
            # its CSV at the end.  A part missing before later ones is damage, not an interruption.
            later = sorted(p.name for p in d.iterdir() if (m := _PART.match(p.name)) and int(m.group(1)) > len(parts))
            if later:
                raise DatasetError(f"{d / f'part-{len(parts):05d}'}.flac/.csv is missing but {later[0]} comes after it: the "
                                   f"session is damaged; restore the part, or delete the parts after the gap and record them "
                                   f"again (--resume)")
            for p in parts:
                out.append((p, (d / f"part-{p:05d}.flac").read_bytes(), (d / f"part-{p:05d}.csv").read_bytes()))
            return out
        listed = manifest["parts"]
        fix = f"restore the session's files from a copy, or delete {d} and re-create it (--resume)"
        for e in listed:
            for ext in ("flac", "csv"):
                if not (d / f"{e['part']}.{ext}").is_file():
                    raise DatasetError(f"{d / (e['part'] + '.' + ext)} is missing but session.json lists it "
                                       f"({len(listed)} parts); {fix}")
        extra = sorted(p.name for p in d.iterdir() if (m := _PART.match(p.name)) and int(m.group(1)) >= len(listed))
        extra += sorted(p.name for p in d.glob("part-*.flac") if not re.fullmatch(r"part-\d{5}\.flac", p.name)
                        or int(p.name[5:10]) >= len(listed))
        if extra:
            raise DatasetError(f"{d / extra[0]} is not in session.json ({len(listed)} parts); remove it, or {fix}")
        by_hash = {(ext, e[f"{ext}_sha256"]): e["part"] for e in listed for ext in ("flac", "csv")}
        for k, e in enumerate(listed):
            got = []
            for ext in ("flac", "csv"):
                path = d / f"{e['part']}.{ext}"
                data = path.read_bytes()
                h = _sha(data)
                if h != e[f"{ext}_sha256"]:
                    other = by_hash.get((ext, h))
                    why = (f"it holds the content of {other}.{ext} (parts swapped or renamed)" if other
                           else "the file was edited, replaced or damaged")
                    raise DatasetError(f"{path} does not match its sha256 in session.json: {why}; {fix}")
                got.append(data)
            out.append((k, got[0], got[1]))
        return out

    def read_session(self, session: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The session's chirp-aligned frames (n, n_chirp) float32 and their labels."""
        import soundfile as sf

        d = self._session_dir(session)
        manifest = self.manifest(session)
        if not self.parts(session) and (manifest is None or "parts" not in manifest):
            self._part_bytes(session, manifest)  # refuses a gap before later parts
            raise DatasetError(f"{d}: no complete part")
        if manifest is not None and "parts" not in manifest and not self._warned_old:
            self._warned_old = True
            warnings.warn(f"{self.root}: written by an older sonicskin, its session.json files bind no content hashes; "
                          f"its parts are checked by their label rows only ({REDO} to bind them)", stacklevel=2)
        audio, labels = [], []
        fix = "delete this part and the ones after it (and session.json) and record them again (--resume)"
        for p, flac, text in self._part_bytes(session, manifest):
            fpath = d / f"part-{p:05d}.flac"
            try:
                x, sr = sf.read(io.BytesIO(flac), dtype="float32", always_2d=True)
            except (RuntimeError, TypeError, ValueError, AssertionError) as e:  # soundfile.LibsndfileError is a RuntimeError
                raise DatasetError(f"{fpath}: unreadable audio ({str(e).splitlines()[0] if str(e) else type(e).__name__}); {fix}") from None
            if sr != int(self.rig.fs_hz):
                raise DatasetError(f"{fpath}: sample rate {sr} Hz, but the dataset's rig runs at {self.rig.fs_hz:g} Hz")
            if x.shape[1] != 1:
                raise DatasetError(f"{fpath}: {x.shape[1]} channels; a part holds the receiver channel only")
            if not np.isfinite(x).all():
                raise DatasetError(f"{fpath}: audio holds NaN or inf; {fix}")
            lab = self._read_labels(d / f"part-{p:05d}.csv", text)
            if manifest is not None and "parts" in manifest and len(lab["chirp"]) != manifest["parts"][p]["chirps"]:
                raise DatasetError(f"{d / f'part-{p:05d}.csv'}: {len(lab['chirp'])} label rows but session.json counts "
                                   f"{manifest['parts'][p]['chirps']} chirps; {fix}")
            audio.append(x[:, 0])
            labels.append(lab)
        stream = np.concatenate(audio)
        lab = {k: np.concatenate([part[k] for part in labels]) for k in COLUMNS}
        if manifest is not None and isinstance(manifest.get("n_chirps"), int) and lab["chirp"].size != manifest["n_chirps"]:
            raise DatasetError(f"{d}: {lab['chirp'].size} label rows but session.json counts {manifest['n_chirps']} chirps; "
                               f"a part or row was removed or added; restore the files or {REDO}")
        self._check_rows(d, lab)
        L = self.rig.n_chirp
        frames, offset = frame_stream(stream, rig_chirp(self.rig))
        pos = (lab["t_s"] * self.rig.fs_hz - offset) / L
        idx = np.round(pos).astype(np.int64)
        bad = (np.abs(pos - idx) > 0.25) | (idx < 0)
        # A recording may stop inside its last labelled chirp: that chirp is dropped, not an error.
        cut = idx >= frames.shape[0]
        if cut.any() and np.flatnonzero(cut)[0] < idx.size - 2:
            bad |= cut
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise DatasetError(
                f"{d}: label row {k} (t_s={lab['t_s'][k]:.6f}) does not fall on a chirp of the stream "
                f"(chirps start at {offset / self.rig.fs_hz:.6f} s + k * {self.rig.period_s:.6f} s); labels and audio disagree")
        step = np.flatnonzero(np.diff(idx) != 1)
        if step.size:
            k = int(step[0]) + 1
            how = ("label the same chirp of the stream, or go back in time" if idx[k] <= idx[k - 1] else
                   f"skip {idx[k] - idx[k - 1] - 1} chirp(s) of the stream: a label row was removed")
            raise DatasetError(f"{d}: label rows {k - 1} and {k} (t_s {lab['t_s'][k - 1]:.6f} and {lab['t_s'][k]:.6f}) {how}; "
                               f"every chirp of a session is labelled once, in order; {REDO}")
        keep = ~cut
        lab = {k: v[keep] for k, v in lab.items()}
        lab["session"] = np.full(int(keep.sum()), session)
        return frames[idx[keep]], lab

    def _check_rows(self, d: Path, lab: dict[str, np.ndarray]) -> None:
        """Label rows of a whole session: chirps numbered 0, 1, 2, ... (each once, in order, no gap), values in range."""
        chirp = lab["chirp"]
        expect = np.arange(chirp.size)
        wrong = np.flatnonzero(chirp != expect)
        if wrong.size:
            k = int(wrong[0])
            how = ("labelled twice" if k and chirp[k] <= chirp[k - 1] else
                   f"a gap: chirp {expect[k]} has no label row" if chirp[k] > expect[k] else "out of order")
            raise DatasetError(f"{d}: label row {k} is chirp {chirp[k]}, expected {expect[k]} ({how}); every chirp of a "
                               f"session is labelled once, in order; restore the files or {REDO}")
        check_label_values(lab, self.layout, str(d))

    def unfinished(self, sessions: list[str] | None = None) -> list[str]:
        """Sessions without a ``session.json``: stopped before they were complete (``--resume`` records the rest)."""
        return [s for s in sessions or self.sessions if not (self._session_dir(s) / "session.json").is_file()]

    def check_distinct(self, sessions: list[str] | None = None) -> None:
        """Refuse two sessions holding the same recording (a copied session counts twice): their first parts' FLAC compared."""
        seen: dict[str, str] = {}
        for s in sessions or self.sessions:
            d = self._session_dir(s)
            info = self.manifest(s)
            if info is not None and isinstance(info.get("parts"), list) and info["parts"]:
                h = info["parts"][0]["flac_sha256"]
            elif (d / "part-00000.flac").is_file():
                h = _sha((d / "part-00000.flac").read_bytes())
            else:
                continue
            if h in seen:
                raise DatasetError(f"{self.root}: sessions {seen[h]} and {s} hold the same recording (identical "
                                   f"part-00000.flac): a copied session is trained and tested on twice; remove the copy")
            seen[h] = s

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
        self.check_distinct(names)
        Xs, labs = [], []
        for _, frames, lab in tqdm(self.iter_sessions(names), total=len(names), desc="features", unit="session",
                                   disable=None if progress else True):
            Xs.append(log_magnitude_db(frames, self.rig))
            labs.append(lab)
        return FeatureTable(np.concatenate(Xs), {k: np.concatenate([d[k] for d in labs]) for k in labs[0]})
