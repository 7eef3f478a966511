"""A dataset's feature table, cached as plain arrays in ``<dataset>/.cache`` and keyed by content (:func:`load_features_cached`)."""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import uuid
import warnings
import zipfile
from pathlib import Path

import numpy as np

from . import __version__
from .dataset import COLUMNS, Dataset, FeatureTable

__all__ = ["load_features_cached", "code_digest"]


def code_digest(*modules: str) -> str:
    """sha256 (16 hex digits) of the package version and every ``.py`` source of the named modules or packages.

    A package counts every ``.py`` file under its folder, sorted, each with its path in the folder (a rename
    changes the digest); a module is located by :func:`importlib.util.find_spec` (a package mapped from
    another folder, such as ``sonicskin.training``, is read where it is)."""
    h = hashlib.sha256(f"sonicskin {__version__}\n".encode())
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec is None:
            raise ModuleNotFoundError(f"no module named {name!r}", name=name)
        h.update(f"module {name}\n".encode())
        if spec.submodule_search_locations:  # a package: every source file under its folder(s)
            files = [(Path(root), f) for root in spec.submodule_search_locations for f in Path(root).rglob("*.py")]
        elif spec.origin and spec.origin.endswith(".py"):
            files = [(Path(spec.origin).parent, Path(spec.origin))]
        else:  # a frozen build or an extension module without sources: its name alone
            files = []
        for root, f in sorted(files, key=lambda rf: rf[1].relative_to(rf[0]).as_posix()):
            data = f.read_bytes()
            h.update(f"{f.relative_to(root).as_posix()} {len(data)}\n".encode() + data)
    return h.hexdigest()[:16]


def _signature(ds: Dataset) -> str:
    """Cache key of a dataset's features: sha256 of the code, ``dataset.json`` and every session's files."""
    h = hashlib.sha256(code_digest("sonicskin.dataset", "sonicskin.dsp").encode())  # the code that computes features
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
    """Why a loaded cache is not what the dataset holds (``""``: an older cache without a digest), or ``None``."""
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
            same = (np.array_equal(got, want, equal_nan=True) if want.dtype.kind == "f" else np.array_equal(got.astype(want.dtype), want))
            if not same:
                return f"its column {c!r} of session {s} differs from the session's label CSVs"
    return None


def load_features_cached(ds: Dataset, *, progress: bool = True) -> FeatureTable:
    """:meth:`Dataset.features`, cached in ``<dataset>/.cache`` by content; a damaged or edited cache is rebuilt."""
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
                warnings.warn(f"{cache}: {why}; the cache was edited (its key kept): rebuilt from the recordings", stacklevel=2)
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
