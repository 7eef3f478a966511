"""What the verbs' implementations share: the split and Alg. 2 options' checks, gamma within the dataset's bins, and
output folders that a failed run leaves as they were."""

from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

from ..dataset import Dataset, writer_lock
from ..errors import UsageError
from ..features import DEFAULT_N_BINS, FeatureSpec


def check_split_options(a: argparse.Namespace) -> None:
    """Split and Alg. 2 options that contradict each other, and an ``--out`` that is a file, refused before any work
    (``--val none``: an empty list)."""
    out = getattr(a, "out", None)
    if out and Path(out).is_file():
        raise UsageError(f"--out {out} is a file; give a folder for what this writes (it is created)")
    val_opt = getattr(a, "val", None)
    if val_opt and any(v.lower() == "none" for v in val_opt):
        if len(val_opt) > 1:
            raise UsageError(f"--val {' '.join(val_opt)}: 'none' means no validation session; give it alone or drop it")
        a.val = []
    for k in ("train", "val", "test"):  # a session named twice was recorded twice in the artifact's split
        given = getattr(a, k, None)
        if given:
            twice = sorted({s for s in given if given.count(s) > 1})
            if twice:
                warnings.warn(f"--{k} names {', '.join(twice)} more than once; each session counts once", stacklevel=2)
                setattr(a, k, list(dict.fromkeys(given)))
    train, val, test = (set(getattr(a, k, None) or ()) for k in ("train", "val", "test"))
    for x, y, nx, ny in ((train, val, "--train", "--val"), (train, test, "--train", "--test"), (val, test, "--val", "--test")):
        if x & y:
            raise UsageError(f"session(s) {', '.join(sorted(x & y))} given to both {nx} and {ny}; a session is in one split only")
    if getattr(a, "test_subjects", None) and (train or val or test):
        raise UsageError("--test-subjects chooses the split by person; drop --train/--val/--test or --test-subjects")
    alpha, beta = getattr(a, "alpha_s", None) or FeatureSpec.alpha_s, getattr(a, "beta_s", None) or FeatureSpec.beta_s
    if alpha < beta:
        raise UsageError(f"--alpha-s {alpha:g} is shorter than the no-touch reference it refreshes (--beta-s {beta:g}); "
                         f"give an interval of at least the reference's length")


def alg2_options(a: argparse.Namespace) -> dict:
    """``--alpha-s``/``--beta-s`` as given, as keyword arguments of :func:`sonicskin.fit.prepare`."""
    return {k: getattr(a, k) for k in ("alpha_s", "beta_s") if getattr(a, k, None) is not None}


def resolve_n_bins(a: argparse.Namespace, data: str | Path | None, *, warn=None) -> int:
    """The user's ``--n-bins`` (more than the dataset's usable bins: a usage error), or the default clamped to them with a warning."""
    if data is None:
        return a.n_bins if a.n_bins is not None else DEFAULT_N_BINS
    n_allowed = int(Dataset(data).rig.allowed_mask.sum())
    if a.n_bins is not None:
        if a.n_bins > n_allowed:
            raise UsageError(f"--n-bins {a.n_bins} is more than the {n_allowed} usable bins of the dataset's band; "
                             f"pass --n-bins {n_allowed} or less, or leave it out to use them all")
        return a.n_bins
    if n_allowed < DEFAULT_N_BINS:
        (warn or _warn)(f"the dataset's band has {n_allowed} usable bins; using gamma = {n_allowed} "
                        f"instead of the default {DEFAULT_N_BINS} (pass --n-bins to choose)")
        return n_allowed
    return DEFAULT_N_BINS


def _warn(msg: str) -> None:
    print(f"sonicskin: warning: {msg}", file=sys.stderr)


def writer_mode(a: argparse.Namespace) -> str:
    return "overwrite" if a.overwrite else "resume" if a.resume else "create"


@contextlib.contextmanager
def clean_on_failure(out: str | Path, mode: str) -> Iterator[Path]:
    """Remove ``out`` again when this run fails before it wrote a single part (a retry is not blocked by a lone dataset.json)."""
    out = Path(out)
    existed = out.is_dir() and any(out.iterdir()) or out.is_file()
    was_dataset = (out / "dataset.json").is_file()  # a folder of other files is never removed (its files are the user's)
    # The folder's writer lock first: a run refused because another process writes ``out`` leaves before the clean-up
    # below could remove that run's files (two `simulate --out X` at once used to end with no dataset at all).
    with writer_lock(out):
        try:
            yield out
        except BaseException:
            if out.is_dir() and (not existed or mode == "overwrite" and was_dataset) and not any(out.glob("*/part-*.csv")):
                shutil.rmtree(out, ignore_errors=True)
            raise


@contextlib.contextmanager
def removed_on_failure(out: str | Path) -> Iterator[Path]:
    """An output folder this run creates is removed again if the run fails: no half-made artifact."""
    out = Path(out)
    existed = out.exists()
    try:
        yield out
    except BaseException:
        if not existed and out.is_dir():
            shutil.rmtree(out, ignore_errors=True)
        raise
