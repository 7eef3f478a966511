"""What every verb shares: value types that validate while parsing, the option groups that several
verbs take (split and model options, writer modes), and small helpers for the training verbs."""

from __future__ import annotations

import argparse
import contextlib
import math
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

from ..errors import UsageError

DEFAULT_N_BINS = 300


# -- value types (argparse ``type=``): a bad value is a usage error naming the option ----------------
def _number(kind, text: str, what: str):
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _bounded(kind, what: str, positive: bool):
    """An argparse type: a ``kind`` (float or int) that is > 0 (``positive``) or >= 0."""
    rule = "> 0" if positive else ">= 0"

    def parse(text: str):
        v = _number(kind, text, f"{what} {rule}")
        if v < 0 or (positive and v == 0):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return v

    parse.__name__ = f"{'positive' if positive else 'nonneg'}_{kind.__name__}"
    return parse


positive_float = _bounded(float, "a number", positive=True)
nonneg_float = _bounded(float, "a number", positive=False)
positive_int = _bounded(int, "a whole number", positive=True)
nonneg_int = _bounded(int, "a whole number", positive=False)


def udp_target(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` with a port in 1-65535 (host defaults to 127.0.0.1)."""
    host, _, port = text.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT with a port number 1-65535, got {text!r}") from None
    if not 1 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 1-65535, got {p}")
    return (host or "127.0.0.1"), p


def key_value(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with VALUE read as YAML (``sessions=2``, ``motion={enabled: true}``)."""
    import yaml

    k, sep, v = text.partition("=")
    if not sep or not k.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = yaml.safe_load(v)
    except yaml.YAMLError:
        raise argparse.ArgumentTypeError(f"{k.strip()}: {v!r} is not a YAML value") from None
    return k.strip(), value


def check_overrides(cls, items: list[tuple[str, object]], what: str) -> dict:
    """``--set`` overrides checked against the fields of dataclass ``cls``: known key, value of the
    field's type (an int for an int field, a list for a tuple, a mapping for a dict...)."""
    import dataclasses

    fields = {f.name: f for f in dataclasses.fields(cls)}
    out = {}
    for k, v in items or []:
        if k not in fields:
            raise UsageError(f"--set {k}: unknown {what} key; valid keys: {', '.join(sorted(fields))}")
        f = fields[k]
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default
        ok = _same_kind(default, v)
        if not ok:
            raise UsageError(f"--set {k}={v!r}: expected {_kind_name(default)} (like {default!r})")
        out[k] = v
    return out


def _same_kind(default, v) -> bool:
    if isinstance(default, bool):
        return isinstance(v, bool)
    if isinstance(default, int):
        return isinstance(v, int) and not isinstance(v, bool)
    if isinstance(default, float):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    if isinstance(default, str):
        return isinstance(v, str)
    if isinstance(default, (tuple, list)):
        return isinstance(v, list) and len(v) == len(default) if isinstance(default, tuple) and len(default) == 2 \
            else isinstance(v, list)
    if isinstance(default, dict):
        return isinstance(v, dict)
    return default is None or v is not None


def _kind_name(default) -> str:
    for t, name in ((bool, "true or false"), (int, "a whole number"), (float, "a number"), (str, "a text"),
                    (dict, "a mapping {key: value}")):
        if isinstance(default, t):
            return name
    if isinstance(default, tuple) and len(default) == 2:
        return "a list of two values [a, b]"
    return "a list [a, b, ...]"


# -- option groups ---------------------------------------------------------------------------------------
def add_model_options(p: argparse.ArgumentParser, *, train_default: str = "the first") -> None:
    """The options every model verb shares (evaluate, fit-svm, train, export, compare): OSPA bins,
    model inputs and the split of sessions / people."""
    g = p.add_argument_group("model and split options (the same on evaluate, fit-svm, train, export, compare)")
    g.add_argument("--n-bins", type=positive_int, metavar="GAMMA",
                   help=f"OSPA gamma, the bins the SVM reads (default: chosen by validation in fit-svm, train, export and "
                        f"compare; the paper's {DEFAULT_N_BINS} in evaluate; never more than the band's usable bins)")
    g.add_argument("--mode", choices=("relative", "absolute"),
                   help="model inputs: minus the no-touch reference (Alg. 2) or absolute (default: relative)")
    g.add_argument("--train", nargs="+", metavar="SESSION", help=f"training sessions (default: {train_default})")
    g.add_argument("--val", nargs="+", metavar="SESSION",
                   help="validation sessions, or 'none' for no validation (default: the second when there are three or "
                        "more and --test is not given, else none)")
    g.add_argument("--test", nargs="+", metavar="SESSION", help="test sessions (default: all the others)")
    g.add_argument("--test-subjects", type=nonneg_int, nargs="+", metavar="ID",
                   help="leave-subjects-out: sessions of these people are the test set (default: off)")
    g.add_argument("--no-refit", dest="refit", action="store_false",
                   help="deploy the models fitted on the training sessions alone (default: after choosing on the "
                        "validation session, refit every model on the training and validation sessions together)")


def check_split_options(a: argparse.Namespace) -> None:
    """Options that contradict each other, refused before any work.  ``--val none`` becomes an empty list
    (no validation session), which every verb passes on as such (never the default split's)."""
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
                import warnings

                warnings.warn(f"--{k} names {', '.join(twice)} more than once; each session counts once", stacklevel=2)
                setattr(a, k, list(dict.fromkeys(given)))
    train, val, test = (set(getattr(a, k, None) or ()) for k in ("train", "val", "test"))
    for x, y, nx, ny in ((train, val, "--train", "--val"), (train, test, "--train", "--test"), (val, test, "--val", "--test")):
        if x & y:
            raise UsageError(f"session(s) {', '.join(sorted(x & y))} given to both {nx} and {ny}; a session is in one split only")
    if getattr(a, "test_subjects", None) and (train or val or test):
        raise UsageError("--test-subjects chooses the split by person; drop --train/--val/--test or --test-subjects")


def resolve_n_bins(a: argparse.Namespace, data: str | Path | None, *, warn=None) -> int:
    """The user's ``--n-bins``, or the default clamped (with a warning) to the bins the dataset's rig
    has after its matched filter.  An explicit gamma larger than that is a usage error: the user
    asked for something this data cannot give."""
    if data is None:
        return a.n_bins if a.n_bins is not None else DEFAULT_N_BINS
    from ..dataset import Dataset

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


def add_writer_options(p: argparse.ArgumentParser, what: str = "dataset") -> None:
    """``--overwrite`` / ``--resume``, the same on every verb that writes a dataset."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--overwrite", action="store_true", help=f"replace an existing {what} (default: refuse)")
    g.add_argument("--resume", action="store_true",
                   help=f"continue an interrupted {what}: keep what is complete, add what is missing (default: off)")


def writer_mode(a: argparse.Namespace) -> str:
    return "overwrite" if a.overwrite else "resume" if a.resume else "create"


@contextlib.contextmanager
def clean_on_failure(out: str | Path, mode: str) -> Iterator[Path]:
    """Remove ``out`` again when this run fails (or is interrupted) before it wrote a single part,
    so a retry is not blocked by a lone ``dataset.json``.  Anything a previous run made is kept
    unless ``--overwrite`` had already replaced it; written parts are kept (``--resume`` continues
    them)."""
    from ..dataset import writer_lock

    out = Path(out)
    existed = out.is_dir() and any(out.iterdir()) or out.is_file()
    # The folder's writer lock first: a run refused because another process writes ``out`` leaves before the clean-up
    # below could remove that run's files (two `simulate --out X` at once used to end with no dataset at all).
    with writer_lock(out):
        try:
            yield out
        except BaseException:
            if out.is_dir() and (not existed or mode == "overwrite") and not any(out.glob("*/part-*.csv")):
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


# -- training helpers ------------------------------------------------------------------------------------
def need_train_extra(verb: str) -> None:
    try:
        import lightning  # noqa: F401
        import torch  # noqa: F401
    except ImportError:
        raise UsageError(f"`sonicskin {verb}` needs the training extra: pip install -c constraints.txt "
                         f"'sonicskin[train]'") from None


def train_config(name: str) -> str:
    """A training YAML path, or a name under configs/train (works from any directory)."""
    from ..rig import _resolve_config

    return str(_resolve_config(name, "train"))


def latest_checkpoint(run: Path) -> Path:
    if run.is_file():
        if run.suffix != ".ckpt":
            raise UsageError(f"{run} is not a checkpoint (.ckpt); pass a run folder of `sonicskin train` or its .ckpt file")
        return run
    if not run.is_dir():
        raise FileNotFoundError(f"{run} does not exist; pass a run folder of `sonicskin train` or a .ckpt file")
    last = sorted(run.rglob("last.ckpt"), key=lambda p: p.stat().st_mtime)
    if not last:
        raise FileNotFoundError(f"no checkpoint under {run}; run `sonicskin train` first")
    d = last[-1].parent
    best = sorted(d.glob("best-*.ckpt"), key=lambda p: p.stat().st_mtime)
    return best[-1] if best else last[-1]


def lightning_overrides(a: argparse.Namespace, n_bins: int | None) -> list[str]:
    """The shared model/split options as LightningCLI ``--data.*`` arguments."""
    import json

    out = []
    if n_bins is not None:
        out += ["--data.n_bins", str(n_bins)]
    if a.mode:
        out += ["--data.mode", a.mode]
    if a.train:
        out += ["--data.train_sessions", json.dumps(a.train)]
    if a.val is not None:  # [] (--val none, or --test taking every other session) means no validation: never dropped
        out += ["--data.val_sessions", json.dumps(a.val)]
    if a.test_subjects:
        out += ["--data.test_subjects", json.dumps(a.test_subjects)]
    return out
