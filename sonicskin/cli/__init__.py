"""``sonicskin <verb>``: one command line for the simulated rig, datasets and models.

One module per verb family, each with an ``add_parsers(sub)``: :mod:`.data` (simulate, record,
import-*), :mod:`.models` (evaluate, fit-svm, train, export, compare, reproduce) and :mod:`.live`
(live, devices, info).  Shared option groups and value types live in :mod:`._common`.

Errors: a user error (:class:`sonicskin.errors.SonicskinError` and the ``ValueError``/``OSError``
the readers raise for bad files) is printed as one line ``sonicskin <verb>: error: <message>``
with exit code 2; set ``SONICSKIN_DEBUG=1`` to see its traceback.  Anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

import _thread
import argparse
import contextlib
import os
import sys
import threading
import warnings

from .. import __version__, threads
from ..errors import SonicskinError, UsageError
from . import data, live, models

__all__ = ["build_parser", "main", "SonicskinError", "UsageError"]

EPILOG = """\
typical session on the simulated rig:
  sonicskin simulate --scenario moving --out data/moving      # received audio + labels
  sonicskin evaluate --data data/moving                       # the paper's SVM pipeline + ablations
  sonicskin train --config moving --data data/moving          # the network (Lightning)
  sonicskin export --run runs/moving --out artifacts/moving   # both models -> ONNX + skin.json
  sonicskin compare --data data/moving --artifact artifacts/moving

every verb: sonicskin <verb> --help
"""


class Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line (``sonicskin <verb>: error: ...``, exit 2)."""

    def error(self, message: str):  # noqa: D102 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


class _LightningHelp(argparse.Action):
    """``train -h``: our options, then LightningCLI's model/data/trainer options."""

    def __init__(self, option_strings, dest, **kw):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show this help (with the "
                         "LightningCLI model/data/trainer options) and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        parser.print_help()
        sys.stdout.flush()
        try:
            import lightning  # noqa: F401
        except ImportError:
            print("\n(LightningCLI options appear here with the training extra: pip install 'sonicskin[train]')")
            parser.exit(0)
        from sonicskin.training.cli import main as train_main

        from ._common import train_config

        print("\nLightningCLI options (model, data, trainer), all accepted by `sonicskin train` and `sonicskin compare`:")
        sys.stdout.flush()
        import contextlib
        import io
        import re

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
        parser.exit(0)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="sonicskin", description="SonicSkin: touch localization and force from one pair of piezo discs "
               "on a robot link. Runs on the simulated rig by default.",
               epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"sonicskin {__version__}")
    sub = p.add_subparsers(dest="verb", metavar="<verb>", parser_class=Parser)
    data.add_parsers(sub)
    models.add_parsers(sub)
    live.add_parsers(sub)
    for verb in sub.choices.values():  # one thread setting on every verb (sonicskin.threads)
        verb.add_argument("--threads", metavar="N", default=None,
                          help=f"threads for training, featurisation and simulation (default: ${threads.ENV}, else half "
                               f"the cores, at most 4: {threads.default_threads()} here)")
    train = sub.choices["train"]
    train.register("action", "lightning_help", _LightningHelp)
    # Replace train's -h/--help by one that also lists the LightningCLI options.
    train._actions = [x for x in train._actions if not isinstance(x, argparse._HelpAction)]
    for group in train._action_groups:
        group._group_actions = [x for x in group._group_actions if not isinstance(x, argparse._HelpAction)]
    train._option_string_actions.pop("-h", None)
    train._option_string_actions.pop("--help", None)
    train.add_argument("-h", "--help", action="lightning_help")
    return p


def _user_error(exc: BaseException) -> bool:
    """Errors a user causes with their input (printed as one line) as opposed to bugs."""
    if isinstance(exc, (SonicskinError, ValueError, OSError)):
        return True
    if isinstance(exc, RuntimeError):
        from ..acquire import AudioError

        return isinstance(exc, AudioError)
    return False


class _CtrlCInCallbacks:
    """Ctrl-C that lands inside a C library's Python callback is not lost and prints no traceback.

    soundfile reads and writes in-memory FLAC through cffi callbacks.  A ``KeyboardInterrupt`` raised
    while one of them runs cannot unwind through C: cffi prints it as an "Exception ignored" traceback,
    the callback returns a failure, and the run goes on (or fails with a misleading libsndfile error).
    While installed, such an interrupt is remembered (:attr:`swallowed`) and delivered again a moment
    later (:func:`_thread.interrupt_main`), once control is back in Python; :func:`main` reports an
    error that follows it as the interruption it is.
    """

    def __init__(self) -> None:
        self.swallowed = False
        self._timer: threading.Timer | None = None

    def _hook(self, unraisable) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            self.swallowed = True
            if self._timer is None or not self._timer.is_alive():
                self._timer = threading.Timer(0.05, _thread.interrupt_main)
                self._timer.daemon = True
                self._timer.start()
        else:
            self._previous(unraisable)

    @contextlib.contextmanager
    def installed(self):
        self._previous = sys.unraisablehook
        sys.unraisablehook = self._hook
        try:
            yield self
        finally:
            sys.unraisablehook = self._previous
            if self._timer is not None:
                self._timer.cancel()


def main(argv: list[str] | None = None) -> int:
    """Run ``sonicskin`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    if not sys.stderr.isatty():  # piped or logged: no progress bars (tqdm and Lightning's read TQDM_DISABLE)
        os.environ.setdefault("TQDM_DISABLE", "1")
    p = build_parser()
    try:
        a, extra = p.parse_known_args(argv)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else 2
    if not getattr(a, "func", None):
        p.print_help()
        return 2
    verb = f"sonicskin {a.verb}"
    if extra and not getattr(a, "passthrough", False):
        print(f"{verb}: error: unrecognized arguments: {' '.join(extra)} (see `{verb} --help`)", file=sys.stderr)
        return 2
    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"{verb}: warning: {' '.join(str(message).split())}", file=sys.stderr)

    def interrupted() -> int:
        print(f"\n{verb}: interrupted; everything written so far is kept", file=sys.stderr)
        return 130

    ctrl_c = _CtrlCInCallbacks()
    try:
        threads.configure(getattr(a, "threads", None))
        with warnings.catch_warnings(), ctrl_c.installed():
            warnings.showwarning = one_line_warning  # the package's warnings as one line each, like errors
            return a.func(a, extra) if getattr(a, "passthrough", False) else a.func(a)
    except BrokenPipeError:  # `sonicskin live | head`: the reader went away
        sys.stdout = None
        return 0
    except KeyboardInterrupt:
        return interrupted()
    except Exception as exc:
        if ctrl_c.swallowed:  # the error is the failed callback's: the user pressed Ctrl-C
            return interrupted()
        if not _user_error(exc) or os.environ.get("SONICSKIN_DEBUG"):
            raise
        msg = " ".join(str(exc).split()) or type(exc).__name__
        if isinstance(exc, (FileExistsError, NotADirectoryError)) and exc.filename is not None:  # an output folder's path
            msg = (f"cannot use {exc.filename} as a folder: it, or a folder above it, is a file ({exc.strerror}); choose "
                   f"another output path or move the file")
        elif isinstance(exc, OSError) and exc.filename is not None and str(exc.filename) not in msg:
            msg = f"{msg}: {exc.filename}"
        print(f"{verb}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
