"""What the importers share: their error type, the output level, and writing a dataset all or nothing."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..dataset import DatasetWriter, refuse_inside_dataset, swap_folders, writer_lock
from ..errors import SonicskinError

PEAK_LEVEL = 0.5  # imported streams are scaled to this peak (-6 dBFS)


class ImportDataError(SonicskinError):
    """Input an importer refuses: the message names the file, the row or array, and the fix."""


@contextlib.contextmanager
def _staged(out: Path, mode: str, inputs=()) -> Iterator[tuple[Path, str]]:
    """Where to write and the writer mode; ``out`` locked for the whole import, a finished dataset moved into place.
    ``inputs``: the files and folders read, never inside an ``out`` that --overwrite replaces."""
    if mode not in ("create", "overwrite", "resume"):
        raise ValueError(f"mode must be create, overwrite or resume, got {mode!r}")
    where = Path(os.path.realpath(out))
    for p in inputs:
        q = Path(os.path.realpath(p))
        if mode == "overwrite" and (q == where or where in q.parents):
            raise FileExistsError(f"{p} lies inside --out {out}: --overwrite would replace the import's own input; "
                                  f"choose an --out elsewhere")
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} exists and is not a dataset; choose another --out or remove it")
    refuse_inside_dataset(out, "a dataset")
    created = not out.exists()
    try:
        with writer_lock(out):
            exists = (out / "dataset.json").is_file()
            if exists and mode == "create":
                raise FileExistsError(f"{out} already holds a dataset; pass --resume to continue it or --overwrite to "
                                      f"replace it")
            if not exists and any(out.iterdir()):
                raise FileExistsError(f"{out} exists and is not a dataset; choose another --out or remove it")
            if exists and mode == "resume":
                yield out, "resume"
                return
            tmp = out.parent / f".{out.name}.importing"
            if tmp.exists():
                shutil.rmtree(tmp)
            try:
                yield tmp, "create"
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            swap_folders(tmp, out)  # out (locked, empty or the old dataset) now holds the new dataset
            created = False
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # the empty folder the lock made for a refused or failed new import


def _write_session(w: DatasetWriter, session: str, audio: np.ndarray, lab: dict, info: dict) -> None:
    """One session, removed again if anything fails half-way (so ``--resume`` starts it afresh)."""
    try:
        w.write_part(session, 0, audio, lab)
        w.finish_session(session, info)
    except BaseException:
        shutil.rmtree(w.root / session, ignore_errors=True)
        raise


def _first_touch(touch: np.ndarray) -> int:
    """Index of a session's first touch chirp (its length when it has none)."""
    return int(np.argmax(touch)) if touch.any() else int(touch.size)
