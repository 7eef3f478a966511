"""``sonicskin <verb>``: one command line for the simulated rig, datasets and models.

A user error (:class:`sonicskin.errors.SonicskinError`, and the ``ValueError``/``OSError`` of bad files) is one line
``sonicskin <verb>: error: <message>``, exit code 2 (``SONICSKIN_DEBUG=1``: its traceback); anything else is a bug."""

from __future__ import annotations

import _thread
import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import warnings

from .. import threads
from ..errors import SonicskinError, UsageError
from .parser import build_parser, verb_function

__all__ = ["build_parser", "main", "SonicskinError", "UsageError"]


class _CtrlCInCallbacks:
    """Ctrl-C landing inside a C library's Python callback (soundfile's cffi ones cannot unwind it) is remembered
    (:attr:`swallowed`) and delivered again a moment later; :func:`main` reports an error that follows it as the
    interruption it is."""

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
        """The hook, and SIGTERM (a supervisor stopping the sensor) made a Ctrl-C: every file is closed as on Ctrl-C."""
        self._previous = sys.unraisablehook
        sys.unraisablehook = self._hook
        main_thread = threading.current_thread() is threading.main_thread()
        term = signal.signal(signal.SIGTERM, self._terminate) if main_thread else None
        try:
            yield self
        finally:
            sys.unraisablehook = self._previous
            if main_thread:
                signal.signal(signal.SIGTERM, term)
            if self._timer is not None:
                self._timer.cancel()

    def _terminate(self, signum, frame) -> None:
        self.terminated = True
        for child in multiprocessing.active_children():  # the verb's workers: a Ctrl-C reaches them too
            child.terminate()
        raise KeyboardInterrupt

    terminated = False


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
        how = "terminated (SIGTERM)" if ctrl_c.terminated else "interrupted"
        resume = "; run it again with --resume to finish it" if hasattr(a, "resume") else ""  # a verb that writes a dataset
        print(f"\n{verb}: {how}; whatever it had written is kept{resume}", file=sys.stderr)
        return 143 if ctrl_c.terminated else 130

    ctrl_c = _CtrlCInCallbacks()
    try:
        threads.configure(getattr(a, "threads", None))
        with warnings.catch_warnings(), ctrl_c.installed():
            warnings.showwarning = one_line_warning  # the package's warnings as one line each, like errors
            run = verb_function(a.func, a.verb)
            return run(a, extra) if getattr(a, "passthrough", False) else run(a)
    except BrokenPipeError:  # `sonicskin live | head`: the reader went away
        sys.stdout = None
        return 0
    except KeyboardInterrupt:
        return interrupted()
    except Exception as exc:
        if ctrl_c.swallowed:  # the error is the failed callback's: the user pressed Ctrl-C
            return interrupted()
        if not isinstance(exc, (ValueError, OSError)) or os.environ.get("SONICSKIN_DEBUG"):  # SonicskinError: a ValueError
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
