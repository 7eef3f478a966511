"""Load a training checkpoint without running code from it: ``torch.load(weights_only=True)`` (numpy's scalar and
dtype allow-listed for older checkpoints), then the module rebuilt from its hyper-parameters; anything else refused."""

from __future__ import annotations

import contextlib
import inspect
import re
import zipfile
from pathlib import Path

import numpy as np
import torch

from sonicskin.artifact_schema import _check_features, _check_layout, _check_rig, _Doc
from sonicskin.errors import SonicskinError

from .module import SkinLitModule

__all__ = ["CheckpointError", "load_checkpoint"]

META_KEYS = ("data", "rig", "layout", "spec", "split", "min_force_n")  # what export needs
HINT = "export only checkpoints written by `sonicskin train`"
MAX_CHECKPOINT_BYTES = 1024 * 2**20  # a SkinNet with its kernel layer is a few MB


class CheckpointError(SonicskinError):
    """A file that is not a sonicskin training checkpoint, or one that would run code when loaded."""


def _numpy_safe_globals() -> list:
    """numpy's scalar reconstructor and dtypes: they rebuild a value from a dtype and bytes, nothing else."""
    try:
        from numpy._core.multiarray import scalar
    except ImportError:  # numpy < 2
        from numpy.core.multiarray import scalar
    dtypes = [type(np.dtype(c)) for c in "?bhilqBHILQefdgFDGUS"]
    return [scalar, np.dtype, *dtypes]


def _first_line(e: BaseException) -> str:
    text = str(e)
    m = re.search(r"Unsupported global: GLOBAL (\S+)", text)  # torch's refusal names the offending global
    if m:
        return f"it names the Python global {m.group(1)}"
    m = re.search(r"Unsupported operand \d+", text)
    if m:
        return m.group(0)
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return (lines[0] if lines else type(e).__name__)[:200]


def load_checkpoint(path: str | Path) -> SkinLitModule:
    """A :class:`SkinLitModule` (CPU, eval, ``.meta`` set) from a checkpoint; else one-line :class:`CheckpointError`."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path} does not exist or is not a file; pass a .ckpt or a run folder")
    if path.stat().st_size > MAX_CHECKPOINT_BYTES:  # refused by its size before anything is read
        raise CheckpointError(f"{path} is {path.stat().st_size / 2**20:,.0f} MB, more than a sonicskin checkpoint can be "
                              f"({MAX_CHECKPOINT_BYTES / 2**20:.0f} MB at most); {HINT}")
    if not zipfile.is_zipfile(path):  # torch.save has written zip archives since torch 1.6
        raise CheckpointError(f"{path} is not a training checkpoint (not the zip archive torch.save writes); {HINT}")
    try:
        allow = getattr(torch.serialization, "safe_globals", None)  # torch >= 2.5; plain metadata needs none
        with allow(_numpy_safe_globals()) if allow else contextlib.nullcontext():
            ckpt = torch.load(path, map_location="cpu", weights_only=True, mmap=False)
    except Exception as e:  # torch's weights-only refusal, and zip/pickle/format errors of every kind
        if "Weights only load failed" in str(e):
            raise CheckpointError(f"refused to load {path}: it holds Python objects beyond tensors and plain data "
                                  f"({_first_line(e)}), and loading them could run code; {HINT}") from None
        raise CheckpointError(f"{path} is not a training checkpoint ({_first_line(e)}); {HINT}") from None
    if not isinstance(ckpt, dict):
        raise CheckpointError(f"{path} is not a training checkpoint (it holds a {type(ckpt).__name__}); {HINT}")
    for key, kind in (("state_dict", dict), ("hyper_parameters", dict), ("sonicskin", dict)):
        if not isinstance(ckpt.get(key), kind):
            what = "has no sonicskin metadata; train it with `sonicskin train`" if key == "sonicskin" else f"has no {key}; {HINT}"
            raise CheckpointError(f"{path} {what}")
    missing = sorted(set(META_KEYS) - set(ckpt["sonicskin"]))
    if missing:
        raise CheckpointError(f"{path}: its sonicskin metadata lacks {missing}; train it again with `sonicskin train`")
    known = set(inspect.signature(SkinLitModule.__init__).parameters) - {"self"}
    hp = {k: v for k, v in ckpt["hyper_parameters"].items() if not k.startswith("_")}  # Lightning's own entries
    unknown = sorted(set(hp) - known)
    if unknown:
        raise CheckpointError(f"{path} was trained with hyper-parameters this sonicskin does not know ({unknown}); "
                              f"export it with the sonicskin version that trained it")
    try:
        lit = SkinLitModule(**hp)
        lit.load_state_dict(ckpt["state_dict"], strict=True)
    except (TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"{path}: the weights do not fit the network of its hyper-parameters "
                              f"({_first_line(e)}); {HINT}") from None
    _check_meta(ckpt["sonicskin"], lit, path)
    lit.meta = ckpt["sonicskin"]
    return lit.eval()


def _check_meta(meta: dict, lit: SkinLitModule, path: Path) -> None:
    """The sonicskin metadata with the artifact schema's checks, and against the network it describes."""
    class Doc(_Doc):
        def fail(self, field, problem, fix=None):
            raise CheckpointError(f"{self.source}: its sonicskin metadata {field} {problem}; {HINT}")

    doc = Doc(str(path))
    rig = _check_rig(doc, meta["rig"])
    layout = _check_layout(doc, meta["layout"])
    spec = _check_features(doc, meta["spec"], rig.n_band, rig)
    doc.str(meta["data"], "data")
    doc.num(meta["min_force_n"], "min_force_n", lo=0, hi=1e4)
    split = doc.obj(meta["split"], "split")
    for k in ("train", "val", "test"):
        for i, s in enumerate(doc.list(doc.get(split, k, "split"), f"split.{k}")):
            doc.str(s, f"split.{k}[{i}]")
    if "sessions_sha256" in meta:  # optional: checkpoints written before it have none
        fp = doc.obj(meta["sessions_sha256"], "sessions_sha256")
        for k, v in fp.items():
            if not (isinstance(v, str) and len(v) == 64 and all(c in "0123456789abcdef" for c in v)):
                doc.fail(f"sessions_sha256.{k}", f"must be 64 lowercase hex digits, got {str(v)[:70]!r}")
    hp = lit.hparams
    if hp.n_in != len(spec.bins):
        doc.fail("spec.bins", f"lists {len(spec.bins)} bins but the network takes {hp.n_in} inputs")
    if hp.n_locations != len(layout.ids):
        doc.fail("layout.ids", f"lists {len(layout.ids)} locations but the network has {hp.n_locations}")
