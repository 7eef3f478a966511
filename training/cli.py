"""``sonicskin train``: LightningCLI over SkinLitModule and SkinDataModule, configured by YAML.

The console stays readable: third-party warnings and banners are silenced, and instead of
Lightning's per-batch bars there is one bar over the epochs (on a terminal only) followed by the
results.  ``--trainer.enable_progress_bar true`` / ``--trainer.enable_model_summary true`` bring
Lightning's own back.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
import warnings
from collections.abc import Iterator

import lightning as L
from lightning.pytorch.cli import LightningCLI

from sonicskin.errors import UsageError

from .data import SkinDataModule
from .module import SkinLitModule

__all__ = ["SkinCLI", "EpochBar", "main", "quiet_third_party"]

PROG = "sonicskin train"


@contextlib.contextmanager
def quiet_third_party() -> Iterator[None]:
    """Silence Lightning/torch/torchvision warnings and Lightning's info banners (GPU/TPU lines, the
    seed, the litlogger tip) for the duration; errors still show."""
    names = ("lightning", "lightning.pytorch", "lightning.fabric", "lightning.pytorch.utilities.rank_zero",
             "lightning.fabric.utilities.rank_zero", "lightning.fabric.utilities.seed", "torch", "torchvision")
    loggers = [logging.getLogger(n) for n in (*names, "torch.onnx")]
    levels = [lg.level for lg in loggers]
    with warnings.catch_warnings():
        for mod in ("lightning", "pytorch_lightning", "torch", "torchvision", "litlogger", "jsonargparse"):
            warnings.filterwarnings("ignore", module=mod)
        warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter.*")
        warnings.filterwarnings("ignore", message=".*treespec.*", category=FutureWarning)
        for lg in loggers:
            lg.setLevel(logging.WARNING)
        logging.getLogger("torch.onnx").setLevel(logging.ERROR)  # "torchvision is not installed. Skipping ..."
        try:
            yield
        finally:
            for lg, lvl in zip(loggers, levels):
                lg.setLevel(lvl)


class EpochBar(L.Callback):
    """One progress bar over the epochs with the validation metrics (shown on a terminal only), and
    the final metrics kept in :attr:`results` for the caller to print."""

    def __init__(self, stream=None):
        self.stream = stream
        self.results: dict[str, float] = {}
        self._bar = None
        self._t0 = 0.0

    def on_train_start(self, trainer, pl_module) -> None:
        from tqdm.auto import tqdm

        stream = self.stream or sys.stderr
        self._t0 = time.perf_counter()
        if trainer.is_global_zero:
            total = trainer.max_epochs if trainer.max_epochs and trainer.max_epochs > 0 else None
            self._bar = tqdm(total=total, desc="train", unit="epoch", file=stream,
                             disable=not (hasattr(stream, "isatty") and stream.isatty()))

    def _metrics(self, trainer) -> dict[str, float]:
        return {k: float(v) for k, v in trainer.callback_metrics.items() if getattr(v, "numel", lambda: 1)() == 1}

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        m = self._metrics(trainer)
        if self._bar is not None:
            prep = getattr(getattr(trainer, "datamodule", None), "prepared", None)  # no force sensor: force RMSE is n/a, not 0
            no_force = prep is not None and not any(v == v for v in prep["force"].tolist())
            self._bar.set_postfix({k: "n/a" if no_force and "force" in k else f"{v:.3g}" for k, v in m.items()
                                   if k.startswith("val_")}, refresh=False)
            self._bar.update(1)

    def on_train_end(self, trainer, pl_module) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        self.results = {"epochs": trainer.current_epoch, "train_time_s": time.perf_counter() - self._t0,
                        **self._metrics(trainer)}


class SkinCLI(LightningCLI):
    follow_root_dir = False  # --trainer.default_root_dir given without a logger: the logger writes there too

    def before_instantiate_classes(self) -> None:
        cfg = self.config.get(self.subcommand) if self.subcommand else self.config
        root, logger = cfg.trainer.default_root_dir, cfg.trainer.logger
        init = getattr(logger, "init_args", None)
        if self.follow_root_dir and root and init is not None and "save_dir" in init:
            init.save_dir = root

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.n_in", "model.n_in", apply_on="instantiate")
        parser.link_arguments("data.n_locations", "model.n_locations", apply_on="instantiate")
        parser.link_arguments("data.noise_db", "model.noise_db")


def main(args: list[str] | None = None, run: bool = True) -> SkinCLI:
    """``args`` as on the command line after ``sonicskin train`` (e.g. ``--config configs/train/moving.yaml``).

    With ``run`` the model is fitted; ``cli.epoch_bar.results`` then holds the final metrics.
    A bad option or value raises :class:`sonicskin.errors.UsageError` (one line) instead of
    printing jsonargparse's usage.
    """
    from jsonargparse import ArgumentError

    from sonicskin import threads

    threads.apply_torch()  # sonicskin --threads / SONICSKIN_THREADS, not torch's every-core default
    given = [a.split("=", 1)[0] for a in (args or [])]
    cls = type("SkinCLI", (SkinCLI,), {"follow_root_dir": "--trainer.default_root_dir" in given
                                       and not any(a.startswith("--trainer.logger") for a in given)})
    parser_kwargs = {"prog": PROG, "exit_on_error": False}
    if "--help" in given or "-h" in given:  # --help shows the defaults `train` runs with: those of its --config
        parser_kwargs["default_config_files"] = [v for k, v in zip(args, args[1:]) if k == "--config"]
    bar = EpochBar()
    with quiet_third_party():
        try:
            cli = cls(SkinLitModule, SkinDataModule, args=list(args or []), run=False,
                          parser_kwargs=parser_kwargs,
                          trainer_defaults={"callbacks": [bar], "enable_progress_bar": False,
                                            "enable_model_summary": False},
                          save_config_kwargs={"overwrite": True}, seed_everything_default=0)
        except ArgumentError as e:
            msg = " ".join(str(e).split())
            raise UsageError(f"{msg} (`{PROG} --help` lists the model/data/trainer options)") from None
        cli.epoch_bar = bar
        if run:
            cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    return cli
