"""Ctrl-C that lands inside soundfile's cffi I/O callbacks (in-memory FLAC) is an interruption: exit 130
with the one "interrupted" line, not an "Exception ignored" traceback, not a bogus "unreadable audio" error."""

import io
import shutil
import signal
import sys
import types

import pytest

import sonicskin.dataset as dataset
from sonicskin.cli import _CtrlCInCallbacks, main


class _CtrlCInTell(io.BytesIO):
    """In-memory bytes whose first ``tell()`` (called by libsndfile through cffi) is hit by Ctrl-C."""

    hits = 0

    def tell(self):
        if _CtrlCInTell.hits == 0:
            _CtrlCInTell.hits += 1
            raise KeyboardInterrupt
        return super().tell()


def _evaluate_reading_through(bytes_io, cli_files, tmp_path, monkeypatch, capsys) -> tuple[int, str]:
    """``sonicskin evaluate`` on a copy of the tiny dataset, its parts decoded from ``bytes_io`` objects."""
    data = tmp_path / "tiny"
    shutil.copytree(cli_files["data"], data)
    monkeypatch.setattr(dataset, "io", types.SimpleNamespace(BytesIO=bytes_io, StringIO=io.StringIO))
    rc = main(["evaluate", "--data", str(data)])
    return rc, capsys.readouterr().err


def test_ctrl_c_inside_a_soundfile_callback_interrupts_the_run(cli_files, tmp_path, monkeypatch, capsys):
    _CtrlCInTell.hits = 0
    rc, err = _evaluate_reading_through(_CtrlCInTell, cli_files, tmp_path, monkeypatch, capsys)
    assert _CtrlCInTell.hits == 1  # the interrupt did land inside the callback
    assert rc == 130, err
    assert "sonicskin evaluate: interrupted; whatever it had written is kept" in err
    assert "Traceback" not in err and "Exception ignored" not in err and "unreadable" not in err, err


def test_other_callback_errors_still_reach_the_previous_hook(cli_files, tmp_path, monkeypatch, capsys):
    """Only Ctrl-C is taken over: any other exception in a callback goes to the hook installed before (Python's
    report), the reader's own one-line error follows, and the previous hook is back afterwards."""

    class _Broken(io.BytesIO):
        def tell(self):
            raise OSError("disk gone")

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    before = sys.unraisablehook
    rc, err = _evaluate_reading_through(_Broken, cli_files, tmp_path, monkeypatch, capsys)
    assert rc == 2 and "unreadable audio" in err and "interrupted" not in err, err
    assert seen and all(isinstance(e, OSError) and str(e) == "disk gone" for e in seen)
    assert sys.unraisablehook is before


def test_a_swallowed_ctrl_c_is_delivered_again_once_back_in_python():
    """When the library carries on after the failed callback, the interrupt still comes, a moment later."""
    ctrl_c = _CtrlCInCallbacks()
    # Python's Ctrl-C handler, as in a terminal: a suite started in the background (`make test &`) inherits SIGINT
    # ignored, and then interrupt_main rightly does nothing
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _swallowed_ctrl_c_comes_back(ctrl_c)
    finally:
        signal.signal(signal.SIGINT, old)


def _swallowed_ctrl_c_comes_back(ctrl_c) -> None:
    with pytest.raises(KeyboardInterrupt), ctrl_c.installed():
        sys.unraisablehook(types.SimpleNamespace(exc_value=KeyboardInterrupt(), exc_type=KeyboardInterrupt,
                                                 exc_traceback=None, err_msg=None, object=None))
        assert ctrl_c.swallowed and ctrl_c._timer is not None
        ctrl_c._timer.join()  # however busy the machine: the timer has fired, the interrupt is pending (no time bound)
        for _ in range(1000):  # plain Python work: the re-delivered Ctrl-C lands here, at the first bytecodes
            sum(range(1000))
        raise AssertionError("the swallowed Ctrl-C was not delivered again")
