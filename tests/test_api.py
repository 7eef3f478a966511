"""`sonicskin.listen` / `sonicskin.Listener`: the same events as `sonicskin live`, as objects, and the
README's Python example, run on the tiny artifact and scenario of these tests."""

import json
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

import sonicskin
from sonicskin import acquire
from sonicskin.errors import SonicskinError
from sonicskin.events import TouchEvent, validate_event
from sonicskin.live import DeviceLost

REPO = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    """The README's python block that calls sonicskin.listen, on this file's tiny artifact and scenario instead of
    what `make demo` wrote (tests/test_readme.py runs it as written, after the demo)."""
    blocks = [b for b in re.findall(r"```python\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S) if "sonicskin.listen(" in b]
    assert blocks, "no python example calling sonicskin.listen in README.md"
    code = blocks[0]
    assert "runs/compare-moving/artifact" in code and 'scenario="moving"' in code, code
    return code.replace("runs/compare-moving/artifact", "artifacts/tiny").replace('scenario="moving"', 'scenario="tiny.yaml"')


def _kw(cli_files):
    return {"scenario": cli_files["scenario"], "fast": True}


def test_listen_yields_the_events_live_prints(cli_files, capsys):
    # The command line first: its main() sizes the process's thread pools (sonicskin.threads), which changes the
    # simulated device's rounding in the last digit of a force; run after it, both read the same stream.
    code, out, _ = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact",
                                cli_files["artifact"], "--fast", "--duration", "30", "--no-status"])
    assert code == 0
    events = list(sonicskin.listen(cli_files["artifact"], duration_s=30, **_kw(cli_files)))
    assert events and all(isinstance(e, TouchEvent) for e in events)
    cli = [json.loads(x) for x in out.splitlines()]
    api = [e.to_dict() for e in events]
    for d in api:
        validate_event(d)
    strip = ("latency_ms",)  # processing time differs run to run; everything else is the same stream
    assert [{k: v for k, v in d.items() if k not in strip} for d in api] == \
        [{k: v for k, v in d.items() if k not in strip} for d in cli]


def test_callback_and_poll_for_a_controller_loop(cli_files):
    seen, threads = [], set()

    def on_event(ev):
        seen.append(ev)
        threads.add(threading.current_thread().name)

    polled, ticks = [], 0
    with sonicskin.Listener(cli_files["artifact"], on_event=on_event, duration_s=30, **_kw(cli_files)) as skin:
        get = skin._queue.get

        def never_blocking(block=True, timeout=None):  # poll never waits on the queue (no clock: the suite runs at load 5)
            assert not block, "poll() waited for an event"
            return get(block, timeout)

        skin._queue.get = never_blocking
        while skin.running:
            polled += skin.poll()  # never blocks the control step
            ticks += 1
            time.sleep(0.002)
        polled += skin.poll()
    assert polled == seen and len(seen) > 5 and ticks > 5
    assert threads == {"sonicskin-listener"}
    assert skin.summary["touch_events"] == sum(e.kind == "touch" for e in seen)


def test_breaking_out_of_listen_stops_the_stream(cli_files):
    t0 = time.perf_counter()
    for _ in sonicskin.listen(cli_files["artifact"], scenario=cli_files["scenario"], duration_s=60):  # real time
        break
    assert time.perf_counter() - t0 < 60  # not a speed bound: a stream that was not stopped runs its 60 s of real time
    assert not any(t.name == "sonicskin-listener" and t.is_alive() for t in threading.enumerate())


def test_listener_errors_are_one_line(cli_files, tmp_path):
    with pytest.raises(SonicskinError, match="is not a sonicskin artifact"):
        sonicskin.Listener(tmp_path)
    with pytest.raises(SonicskinError, match="duration_s must be > 0"):
        sonicskin.Listener(cli_files["artifact"], duration_s=0, **_kw(cli_files))
    with pytest.raises(SonicskinError, match="the artifact knows 3 markers but scenario 'stationary' has 31"):
        sonicskin.Listener(cli_files["artifact"], scenario="stationary")


def test_a_dead_device_reaches_the_caller(cli_files):
    """The audio stops (the server died): the iterator raises DeviceLost within the watchdog's time."""
    lst = sonicskin.Listener(cli_files["artifact"], watchdog_s=0.5, duration_s=60, **_kw(cli_files))

    class Dead(acquire._QueueSource):  # a source that never delivers and never ends
        def start(self):
            pass

        def stop(self):
            pass

    lst.opened.source = lst.loops[0].source = Dead(lst.opened.rig, 1024)
    t0 = time.perf_counter()
    with pytest.raises(DeviceLost, match="no audio from the device for 0.5 s"):
        list(lst)
    assert time.perf_counter() - t0 >= 0.5  # the watchdog waits its 0.5 s (an upper bound would fail at load 5)


def _example_dir(cli_files, tmp_path) -> Path:
    shutil.copytree(cli_files["artifact"], tmp_path / "artifacts" / "tiny")
    shutil.copy(cli_files["scenario"], tmp_path / "tiny.yaml")
    return tmp_path


def test_readme_python_example_runs(cli_files, tmp_path):
    code = readme_example()
    assert len(code.strip().splitlines()) <= 14
    cwd = _example_dir(cli_files, tmp_path)
    p = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    touch = [x for x in lines if " touch marker " in x]
    assert touch and any(" release marker " in x for x in lines), p.stdout
    # marker ids of the tiny layout, force in newtons
    assert all(int(re.search(r"marker (\d+)", x).group(1)) in (0, 1, 2) for x in touch)
    assert re.search(r"^\d+ touch events from the controller loop$", lines[-1]), lines[-1]
    assert "torch" not in p.stderr
    assert np.isfinite([float(re.search(r"(-?[\d.]+) N", x).group(1)) for x in touch]).all()
