"""The torch verbs: ``train``, ``export``, ``compare``'s training, and ``train --help``'s LightningCLI options.
Loaded only when one of them runs (:func:`.parser.verb_function`): fit-svm, live and the rest never import torch."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
from pathlib import Path

from sonicskin.training.cli import main as train_main
from sonicskin.training.cli import quiet_third_party
from sonicskin.training.fit import artifact_from_checkpoint

from ..dataset import Dataset
from ..errors import UsageError
from ..fit import selection_lines
from ..rig import resolve_config
from ._common import check_split_options, removed_on_failure, resolve_n_bins
from .models import TRAINING_OPTIONS, _score_artifact, _sessions_for_test


def lightning_help() -> None:
    """After ``train``'s own options: LightningCLI's model/data/trainer options, worded for ``sonicskin train``."""
    print("\nLightningCLI options (model, data, trainer), all accepted by `sonicskin train` and `sonicskin compare`:")
    sys.stdout.flush()
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            train_main(["--config", train_config("moving"), "--help"])
    except SystemExit:
        pass
    text = re.sub(r"\Ausage:.*?\n\n", "", buf.getvalue(), flags=re.S)  # its usage block repeats the list below
    # Two meanings of --data: on `sonicskin train` it is the dataset folder (above), LightningCLI's is a YAML.
    text = text.replace("--data CONFIG         Path to a configuration file.",
                        "--data CONFIG         LightningCLI's YAML of data.* options; not on `sonicskin train`,\n"
                        "                        where --data is the dataset folder (put data.* in the --config YAML)")
    text = text.replace("Base class for all optimizers:", "Optimizer (default: none, the model's own AdamW with model.lr and "
                        "model.weight_decay; --optimizer replaces it):")
    text = re.sub(r"^\(<class 'torch\.optim\.lr_scheduler\.LRScheduler'>.*\):$", "Learning-rate scheduler (default: "
                  "none, the model's own cosine schedule over the epochs; --lr_scheduler replaces it):", text, flags=re.M)
    print(text, end="")


def _train_args(a: argparse.Namespace, data: str | None, extra: list[str]) -> list[str]:
    check_split_options(a)
    if data:
        Dataset(data)  # refused here, in one line, before Lightning starts
    n_bins = resolve_n_bins(a, data) if data and a.n_bins is not None else a.n_bins  # None: chosen by validation
    if data and a.test:
        a.train, a.val = _sessions_for_test(a, data)
    return ["--config", train_config(a.config)] + (["--data.data", data] if data else []) + lightning_overrides(a, n_bins) + extra


def cmd_train(a: argparse.Namespace, extra: list[str]) -> int:
    cli = train_main(_train_args(a, a.data, extra))
    if not cli.trainer.is_global_zero:  # DDP: rank zero reports
        return 0
    _report_training(cli)
    ckpt = cli.trainer.checkpoint_callback
    best = ckpt.best_model_path or "none: no validation ran, export takes last.ckpt"
    print(f"checkpoints: {ckpt.dirpath} (best {best}); config saved beside them")
    return 0


def _report_training(cli, *, selection: bool = True) -> None:
    res = getattr(cli, "epoch_bar", None) and cli.epoch_bar.results
    if res:
        prep = getattr(cli.datamodule, "prepared", None)  # no finite force anywhere: RMSE 0 would be a made-up number
        no_force = prep is not None and not any(v == v for v in prep.force.tolist())
        metrics = ", ".join(f"{k} n/a (no force sensor)" if no_force and "force" in k else f"{k} {v:.3f}"
                            for k, v in res.items() if k.startswith("val_"))
        split = getattr(prep, "split", None)
        if split is not None:  # say where the val_ metrics come from (no validation session: the training data)
            metrics += (f" (validation {', '.join(split.val)})" if split.val else
                        f" (no validation session: on the training sessions {', '.join(split.train)})")
        print(f"trained {res['epochs']} epochs in {res['train_time_s']:.0f} s: {metrics}")
    for line in selection_lines(getattr(cli.datamodule, "selection", None) if selection else None):
        print(line)


def cmd_export(a: argparse.Namespace) -> int:
    check_split_options(a)
    if any(getattr(a, k) for k in (*TRAINING_OPTIONS, "val", "test")):
        raise UsageError("export keeps the bins, inputs and split the checkpoint was trained with; "
                         "pass --n-bins/--mode/--train/... to `sonicskin train` (or use `sonicskin compare`)")
    run = Path(a.run)
    if not run.exists():
        raise FileNotFoundError(f"{run} does not exist; pass a run folder of `sonicskin train` or its .ckpt file")
    export_quietly(latest_checkpoint(run), a.out, data=a.data, refit=a.refit)
    return 0


def export_quietly(ckpt: Path, out: str | Path, *, data: str | Path | None, refit: bool = True) -> None:
    """:func:`sonicskin.training.fit.artifact_from_checkpoint` with one result line and no third-party noise."""
    stdout = sys.stdout
    with removed_on_failure(out), quiet_third_party(), contextlib.redirect_stdout(io.StringIO()):
        artifact_from_checkpoint(ckpt, out, data=data, refit=refit, log=lambda msg: print(msg, file=stdout))


def compare_trained(a: argparse.Namespace, extra: list[str]) -> int:
    """``compare --data``: train and export both models on the same split, then score the artifact."""
    run = Path(a.runs) / f"compare-{Path(a.data).name}"
    args = _train_args(a, a.data, ["--trainer.default_root_dir", str(run), "--trainer.logger.init_args.save_dir", str(run)] + extra)
    cli = train_main(args)
    if not cli.trainer.is_global_zero:  # DDP: rank zero exports and compares
        return 0
    _report_training(cli, selection=False)  # the export below prints the whole selection
    artifact = run / "artifact"
    export_quietly(latest_checkpoint(Path(cli.trainer.checkpoint_callback.dirpath)), artifact, data=a.data, refit=a.refit)
    return _score_artifact(a, artifact, expected=False)


def train_config(name: str) -> str:
    """A training YAML path, or a name under configs/train (works from any directory)."""
    return str(resolve_config(name, "train"))


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
    for k in ("alpha_s", "beta_s"):
        if getattr(a, k) is not None:
            out += [f"--data.{k}", str(getattr(a, k))]
    if not getattr(a, "refit", True):
        out += ["--data.refit", "false"]
    return out
