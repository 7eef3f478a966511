"""``sonicskin train``: LightningCLI over SkinLitModule and SkinDataModule, configured by YAML.

Third-party warnings and banners are silenced; one bar over the epochs (on a terminal) replaces Lightning's per-batch
bars (``--trainer.enable_progress_bar true`` / ``--trainer.enable_model_summary true`` bring Lightning's own back)."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import time
import warnings
from collections.abc import Iterator

import lightning as L
from lightning.pytorch.cli import LightningCLI

from sonicskin import threads
from sonicskin.errors import UsageError, is_number

from .data import SkinDataModule
from .fit import choose_auto_layer
from .module import LAYER_KINDS, SkinLitModule

__all__ = ["SkinCLI", "EpochBar", "main", "quiet_third_party"]

PROG = "sonicskin train"


@contextlib.contextmanager
def quiet_third_party() -> Iterator[None]:
    """Silence Lightning/torch/torchvision warnings and Lightning's info banners for the duration; errors still show."""
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
    """One progress bar over the epochs (on a terminal only), the final metrics kept in :attr:`results`."""

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
            no_force = prep is not None and not any(v == v for v in prep.force.tolist())
            self._bar.set_postfix({k: "n/a" if no_force and "force" in k else f"{v:.3g}" for k, v in m.items()
                                   if k.startswith("val_")}, refresh=False)
            self._bar.update(1)

    def on_train_end(self, trainer, pl_module) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        self.results = {"epochs": trainer.current_epoch, "train_time_s": time.perf_counter() - self._t0, **self._metrics(trainer)}


# -- what a training YAML or option may name, and the ranges of its numbers --------------------------------------
# jsonargparse imports a ``class_path`` while parsing: a YAML naming ``os.system`` would be imported (and its
# module's top-level code run) before any check.  Only the Lightning classes below may be named.
ALLOWED_CLASSES = frozenset(
    f"{prefix}{name}" for name, mods in {
        "CSVLogger": ("lightning.pytorch.loggers.", "lightning.pytorch.loggers.csv_logs."),
        "TensorBoardLogger": ("lightning.pytorch.loggers.", "lightning.pytorch.loggers.tensorboard."),
        "ModelCheckpoint": ("lightning.pytorch.callbacks.", "lightning.pytorch.callbacks.model_checkpoint."),
        "EarlyStopping": ("lightning.pytorch.callbacks.", "lightning.pytorch.callbacks.early_stopping."),
        "LearningRateMonitor": ("lightning.pytorch.callbacks.", "lightning.pytorch.callbacks.lr_monitor."),
    }.items() for prefix in ("", *mods))
# A user's own callbacks/loggers: opted in by name, outside any file a config could smuggle in.
ALLOW_ENV = "SONICSKIN_ALLOW_CLASSES"
# Options whose string value jsonargparse resolves to a class (and imports when it is a dotted path).
CLASS_OPTIONS = ("trainer.logger", "trainer.callbacks", "trainer.strategy", "trainer.plugins", "trainer.profiler",
                 "trainer.accelerator", "optimizer", "lr_scheduler")
_DOTTED = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+")


def _refuse_class(name: object, where: str) -> None:
    extra = {n.strip() for n in os.environ.get(ALLOW_ENV, "").split(",") if n.strip()}
    if not isinstance(name, str) or (name not in ALLOWED_CLASSES and name not in extra):
        allowed = sorted(n for n in ALLOWED_CLASSES if "." not in n)
        raise UsageError(f"{where} names the class {str(name)[:80]!r}, which sonicskin train does not load (it would be "
                         f"imported to check it); allowed: {', '.join(allowed)} from lightning.pytorch, or a class you "
                         f"name yourself in ${ALLOW_ENV} (comma-separated dotted paths)")


def _walk_classes(node: object, path: tuple[str, ...], where: str) -> None:
    """Every ``class_path`` in a parsed YAML/JSON value, and dotted names given to a class option."""
    key = ".".join(path)
    if isinstance(node, dict):
        for k, v in node.items():
            if k == "class_path":
                _refuse_class(v, f"{where} ({key}.class_path)" if key else where)
            else:
                _walk_classes(v, (*path, str(k)), where)
    elif isinstance(node, list):
        for v in node:
            _walk_classes(v, path, where)
    elif isinstance(node, str) and key.rstrip("+") in CLASS_OPTIONS and _DOTTED.fullmatch(node.strip()):
        _refuse_class(node.strip(), where if where == f"--{key}" else f"{where} ({key})")


def _yaml_file(path: str) -> object:
    import yaml

    try:
        with open(path, encoding="utf-8") as fh:
            return yaml.safe_load(fh)
    except OSError as e:
        raise UsageError(f"cannot read the training config {path} ({e.strerror or e})") from None
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError) as e:
        line = " ".join(str(e).split())[:160]
        raise UsageError(f"{path} is not a valid YAML training config ({line}); fix the file") from None


def refuse_unlisted_classes(args: list[str]) -> None:
    """Refuse a ``class_path`` not in :data:`ALLOWED_CLASSES` before jsonargparse imports anything a file names."""
    import yaml

    i = 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--"):
            i += 1
            continue
        key, eq, value = arg[2:].partition("=")
        if not eq:
            value = args[i + 1] if i + 1 < len(args) and not args[i + 1].startswith("--") else None
            i += 1
        i += 1
        if value is None:
            continue
        if key == "config" or (value.endswith((".yaml", ".yml", ".json")) and os.path.isfile(value)):
            _walk_classes(_yaml_file(value), () if key == "config" else tuple(key.split(".")), value)
            continue
        if key.endswith(".class_path") or key == "class_path":
            _refuse_class(value, f"--{key}")
            continue
        try:
            parsed = yaml.safe_load(value)
        except (yaml.YAMLError, RecursionError):
            parsed = value
        _walk_classes(parsed, tuple(key.split(".")), f"--{key}")


# option -> (check, what it must be); None values are Lightning's "not set" and pass
_INT_GE = {"trainer.min_epochs": 0, "trainer.min_steps": 0, "trainer.log_every_n_steps": 1, "trainer.num_nodes": 1,
           "trainer.accumulate_grad_batches": 1, "trainer.check_val_every_n_epoch": 1, "trainer.num_sanity_val_steps": -1,
           "model.n_in": 1, "model.n_locations": 1, "model.n_centres": 0, "data.n_bins": 1}
_FLOAT_RANGES = {  # (lo, lo_open, hi)
    "model.lr": (0.0, True, 10.0), "model.weight_decay": (0.0, False, 10.0), "model.dropout": (0.0, False, 0.99),
    "model.input_dropout": (0.0, False, 0.99), "model.label_smoothing": (0.0, False, 0.99),
    "model.force_weight": (0.0, False, 1e6), "model.kernel_lr": (0.0, False, 10.0), "model.tau": (0.0, True, 1e6),
    "model.rest_mix": (0.0, False, 1.0), "model.noise_db": (0.0, False, 100.0),
    "data.noise_db": (0.0, False, 100.0), "data.min_force_n": (0.0, False, 1e4), "trainer.gradient_clip_val": (0.0, False, 1e9),
    "data.alpha_s": (0.0, True, 1e7), "data.beta_s": (0.0, True, 3600.0),
}
MAX_EPOCHS = 1_000_000
MAX_BATCH = 1_000_000
MAX_WEIGHTS = 50_000_000  # 200 MB of float32 weights (SkinNet at the shipped config: under 0.1 million)
MAX_INPUTS_GUESS = 300    # the inputs (OSPA's gamma) are known only once the data is read: the default gamma
MAX_CENTRES = 100_000     # RBF units of the kernel layer, one per SVM support vector


def check_ranges(cfg) -> None:
    """Numbers of a parsed training config in their ranges: one :class:`UsageError` line naming the option."""
    def get(key):
        try:
            return cfg.get(key)
        except (KeyError, AttributeError):
            return None

    def bad(key, must, v):
        raise UsageError(f"--{key} must be {must}, got {v!r}")

    for key, hi in (("trainer.max_epochs", MAX_EPOCHS), ("trainer.max_steps", MAX_EPOCHS * 1000)):
        v = get(key)
        if v is not None and (not is_number(v, integer=True) or not (v == -1 or 1 <= v <= hi)):
            bad(key, f"-1 (no limit) or an integer from 1 to {hi}", v)
    for key, lo in _INT_GE.items():
        v = get(key)
        if v is not None and (not is_number(v, integer=True) or v < lo or v > 2**31):
            bad(key, f"an integer >= {lo}", v)
    v = get("data.batch_size")
    if v is not None and (not is_number(v, integer=True) or not 1 <= v <= MAX_BATCH):
        bad("data.batch_size", f"an integer from 1 to {MAX_BATCH}", v)
    for key, (lo, lo_open, hi) in _FLOAT_RANGES.items():
        v = get(key)
        if v is None:
            continue
        if not is_number(v) or (v <= lo if lo_open else v < lo) or v > hi:
            bad(key, f"a finite number {'>' if lo_open else '>='} {lo:g} and <= {hi:g}", v)
    hidden = get("model.hidden")
    if hidden is not None and not all(is_number(h, integer=True) and 1 <= h <= 65536 for h in hidden):
        bad("model.hidden", "a list of layer widths from 1 to 65536", list(hidden))
    # Sizes that would be allocated before anything runs: [65536, 65536] is 17 GB of weights, n_centres 1e8 x 60 inputs
    # 24 GB (the machine's memory; the OOM killer ends the run, or another process).
    n_in = max(get("model.n_in") or 0, get("data.n_bins") or 0, MAX_INPUTS_GUESS)
    if hidden:
        widths = [n_in, *hidden]
        weights = sum(a * b for a, b in zip(widths, widths[1:]))
        if weights > MAX_WEIGHTS:
            bad("model.hidden", f"layers of at most {MAX_WEIGHTS / 1e6:.0f} million weights together (these have "
                                f"{weights / 1e6:,.0f} million)", list(hidden))
    n_centres = get("model.n_centres")
    if isinstance(n_centres, int) and n_centres > MAX_CENTRES:
        bad("model.n_centres", f"an integer from 0 to {MAX_CENTRES} (the SVM's support vectors; 0: chosen when training "
                               f"starts)", n_centres)
    for key in ("trainer.limit_train_batches", "trainer.limit_val_batches", "trainer.val_check_interval"):
        v, lo = get(key), (0 if key == "trainer.limit_val_batches" else 1)  # 0 validation batches: no validation
        if v is None:
            continue
        is_int = is_number(v, integer=True)
        if not ((is_int and v >= lo) or (isinstance(v, float) and math.isfinite(v) and (lo == 0 or v > 0) and 0 <= v <= 1)):
            bad(key, f"a fraction in {'[0' if lo == 0 else '(0'}, 1] or a batch count >= {lo}", v)
    v = get("trainer.fast_dev_run")
    if v is not None and not isinstance(v, bool) and (not isinstance(v, int) or v < 0):
        bad("trainer.fast_dev_run", "true, false or a batch count >= 0", v)
    devices = get("trainer.devices")  # Lightning: an int >= 1, -1 (all), "auto", or a list / comma string of indices
    ok = devices is None or devices == "auto" or (is_number(devices, integer=True) and (devices >= 1 or devices == -1))
    if not ok and isinstance(devices, str):
        parts = [x.strip() for x in devices.split(",") if x.strip()]
        ok = bool(parts) and all(x.lstrip("-").isdigit() for x in parts) and (
            int(parts[0]) >= 1 or int(parts[0]) == -1 if len(parts) == 1 else all(int(x) >= 0 for x in parts))
    if not ok and isinstance(devices, (list, tuple)):
        ok = bool(devices) and all(is_number(x, integer=True) and x >= 0 for x in devices)
    if ok and get("trainer.accelerator") == "cpu" and not (devices is None or devices == "auto" or isinstance(devices, int)
                                                            or (isinstance(devices, str) and "," not in devices)):
        bad("trainer.devices", "a number of processes (an integer >= 1) on the CPU; device index lists are for GPUs", devices)
    if not ok:
        bad("trainer.devices", "an integer >= 1, -1 (every device), auto, or a list of device indices", devices)
    strategy = get("trainer.strategy")  # spawned workers rebuild the location layer the parent never sees
    if isinstance(strategy, str) and re.search(r"(spawn|fork|notebook)", strategy):
        bad("trainer.strategy", "auto or ddp (the network's location layer is built when training starts, which a "
                                "spawned or forked worker cannot hand back)", strategy)
    kernel = get("model.kernel")  # typed bool | str: any other word would have meant True (a kernel layer) silently
    if kernel is not None and not isinstance(kernel, bool) and kernel != "auto":
        bad("model.kernel", "true, false or auto", kernel)
    layer = get("model.layer")
    if layer is not None and layer not in LAYER_KINDS:
        bad("model.layer", ", ".join(LAYER_KINDS[:-1]) + f" or {LAYER_KINDS[-1]}", layer)
    seed = get("seed_everything")
    if seed is not None and not isinstance(seed, bool) and (not isinstance(seed, int) or not 0 <= seed < 2**32):
        bad("seed_everything", "true, false or an integer from 0 to 2**32 - 1", seed)


LOGGED = tuple(f"{stage}_{k}" for stage in ("val", "train") for k in ("loss", "acc", "force_rmse", "detect"))


def check_monitors(callbacks) -> None:
    """A checkpoint or early-stopping callback must watch a metric the module logs (a misspelt one ended the run)."""
    from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint

    for cb in callbacks:
        mon = getattr(cb, "monitor", None)
        if isinstance(cb, (EarlyStopping, ModelCheckpoint)) and mon is not None and mon not in LOGGED:
            raise UsageError(f"{type(cb).__name__} monitors {mon!r}, which sonicskin train does not log; monitor one of "
                             f"{', '.join(LOGGED)}")


class SkinCLI(LightningCLI):
    follow_root_dir = False  # --trainer.default_root_dir given without a logger: the logger writes there too

    def _set_seed(self) -> None:  # the first use of the parsed config (before instantiation): check it here
        check_ranges(self.config.get(self.subcommand) if self.subcommand else self.config)
        super()._set_seed()

    def before_instantiate_classes(self) -> None:
        cfg = self.config.get(self.subcommand) if self.subcommand else self.config
        root, logger = cfg.trainer.default_root_dir, cfg.trainer.logger
        init = getattr(logger, "init_args", None)
        if self.follow_root_dir and root and init is not None and "save_dir" in init:
            init.save_dir = root

    def before_fit(self) -> None:
        if self.model.hparams.layer == "auto":  # the location layer, chosen on data it does not train on
            choose_auto_layer(self.model, self.datamodule, epochs=self.trainer.max_epochs or 40)

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.n_in", "model.n_in", apply_on="instantiate")
        parser.link_arguments("data.n_locations", "model.n_locations", apply_on="instantiate")
        parser.link_arguments("data.noise_db", "model.noise_db")


def main(args: list[str] | None = None, run: bool = True) -> SkinCLI:
    """``args`` as after ``sonicskin train``; a bad option is a one-line :class:`sonicskin.errors.UsageError`."""
    from jsonargparse import ArgumentError
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    threads.apply_torch()  # sonicskin --threads / SONICSKIN_THREADS, not torch's every-core default
    refuse_unlisted_classes(list(args or []))  # before jsonargparse imports any class a file names
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
        except (ArgumentError, MisconfigurationException) as e:  # MisconfigurationException: Lightning's Trainer
            msg = " ".join(str(e).split())                       # refusing e.g. --trainer.devices=0 or a missing GPU
            raise UsageError(f"{msg} (`{PROG} --help` lists the model/data/trainer options)") from None
        cli.epoch_bar = bar
        check_monitors(cli.trainer.callbacks)
        if run:
            try:
                cli.before_fit()  # run=False: LightningCLI does not call it
                cli.trainer.fit(cli.model, datamodule=cli.datamodule)
            except MisconfigurationException as e:
                raise UsageError(f"{' '.join(str(e).split())} (`{PROG} --help` lists the model/data/trainer options)") from None
    return cli
