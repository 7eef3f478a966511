"""Hostile findings of issue 27 on the live loop, the Python API, the rig check and the event stream: each one was
silently wrong (touch events from noise, a hang, a reader that refused the writer's own events) or a bare exception
before its fix, and must now be one clear line (or a run that goes on, with a warning)."""

from __future__ import annotations

import json
import re
import threading

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, refusal, refusals, run

import sonicskin
from sonicskin import acquire
from sonicskin.errors import SonicskinError


# -- a device whose chirp is lost mid-run ---------------------------------------------------------------------------
def _device(fault: str, good_s: float, *, fault_s: float = 6.0):
    """A fake audio interface: ``good_s`` seconds of the rig's chirp train (a little noise on it), then ``fault_s`` of
    ``fault``: ``noise`` (std 0.1, the transmitter stopped while the input amplifier hisses), ``dc`` (a constant 0.3),
    ``dc+noise`` (0.3 with a 1e-3 noise floor).  Every block is queued at start (a device that keeps delivering)."""
    from sonicskin.dsp import rig_chirp

    class Device(acquire._QueueSource):
        def __init__(self, rig, device=None, **kw):
            super().__init__(rig, 1024, max_queued_s=60)

        def start(self):
            fs = int(self.rig.fs_hz)
            n = int((good_s + fault_s) * fs) // 1024 * 1024
            x = np.resize(rig_chirp(self.rig).astype(np.float32) * 0.1, n)
            x += np.random.default_rng(0).normal(0, 1e-3, n).astype(np.float32)
            bad = slice(int(good_s * fs), None)
            noise = np.random.default_rng(1).normal(0, 1.0, x[bad].size).astype(np.float32)
            x[bad] = {"noise": 0.1 * noise, "dc": np.float32(0.3), "dc+noise": 0.3 + 1e-3 * noise}[fault]
            for k in range(0, n, 1024):
                self._deliver(x[k:k + 1024])

        def stop(self):
            pass

    return Device


CHIRP_LOST = (r"sonicskin live: error: the chirp was lost: (9[5-9]|1[0-9][0-9]) of the last 188 chirps \(1\.0 s\) do not "
              r"repeat the chirp before them \(coherence median 0\.[0-2]\d; a chirp train's is 0\.92-1\.00, noise's "
              r"0\.03-0\.25\); is the transmitter still playing on output --tx and reaching the receiver\? check it with "
              r"`sonicskin check`")


@pytest.mark.parametrize("fault", ["noise", "dc+noise"])
def test_a_chirp_lost_mid_run_stops_the_run_with_one_line(cli_files, monkeypatch, capsys, fault):
    """The input turns to noise (or to a DC level on a noise floor) 5 s after a good boot: `live` kept emitting about 9
    touch events a second from the noise (312 and 324 events), exit 0.  Now the frames without the chirp never reach the
    model and the run stops about half a second later, with its summary and one line."""
    monkeypatch.setattr(acquire, "SoundDeviceSource", _device(fault, 5.0))
    code, out, err = run(capsys, ["live", "--device", "0", "--artifact", cli_files["artifact"], "--duration", "30",
                                  "--no-status"])
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err, err
    assert re.fullmatch(CHIRP_LOST, lines[-1]), lines[-1]
    summary = json.loads(lines[-2])["summary"]
    assert summary["skipped"]["no_chirp"] >= 90 and summary["chirps"] > 0.9 * 5.0 * 187.5
    period_s = 1024 / 192000
    late = [e for e in map(json.loads, out.splitlines()) if e["t_s"] > 5.0]  # frames that start after the chirp stopped
    assert late == [], late[:3]
    assert len([e for e in map(json.loads, out.splitlines()) if e["t_s"] > 5.0 - period_s]) <= 1  # the straddling frame


def test_the_api_raises_the_same_line_for_a_lost_chirp(cli_files, monkeypatch):
    from sonicskin.live import InputUnusable

    monkeypatch.setattr(acquire, "SoundDeviceSource", _device("noise", 5.0))
    with pytest.raises(InputUnusable) as e:
        list(sonicskin.listen(cli_files["artifact"], device=0, duration_s=30))
    assert re.fullmatch(CHIRP_LOST.removeprefix("sonicskin live: error: "), str(e.value)), str(e.value)
    assert isinstance(e.value, SonicskinError)


CONSTANT = (r"sonicskin live: error: the device delivers audio but none of the last 3\.0 s gave a usable chirp \(\d+ constant "
            r"frame\(s\)\); the input is a constant level with no signal on it \(a DC offset\): the receiver's preamp or "
            r"the interface's input \(--rx\) is stuck; check the cable and the levels with `sonicskin check`")


@pytest.mark.parametrize("good_s", [0.0, 5.0], ids=["at-boot", "mid-run"])
def test_a_constant_input_stops_the_run_with_one_line(cli_files, monkeypatch, capsys, good_s):
    """A constant 0.3 from the start gave exit 0 and no event (its spectrum repeats, so the boot check passed it); after a
    good boot it gave touch events.  A frame that does not vary is now a fault, as silence is."""
    monkeypatch.setattr(acquire, "SoundDeviceSource", _device("dc", good_s))
    code, out, err = run(capsys, ["live", "--device", "0", "--artifact", cli_files["artifact"], "--duration", "30",
                                  "--no-status"])
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err, err
    assert re.fullmatch(CONSTANT, lines[-1]), lines[-1]
    assert json.loads(lines[-2])["summary"]["skipped"]["constant"] > 0
    assert [e for e in map(json.loads, out.splitlines()) if e["t_s"] > good_s] == []


def test_chirp_coherence_separates_a_chirp_train_from_noise(cli_files):
    """Known answers of the running check: consecutive frames of a chirp train through a moving robot's link (motor
    noise, the pose changing the channel; the shipped moving scenario on the small rig) repeat, noise does not, and a
    frame cut at another offset of the same train repeats as well (a re-lock)."""
    from sonicskin.live import MIN_COHERENCE, band_spectrum, chirp_coherence
    from sonicskin.rig import Rig
    from sonicskin.sim import Scenario, Simulator, build_timeline

    rig = Rig.load(cli_files["rig"])
    sc = Scenario.load("moving").replace(sessions=1)
    tl = build_timeline(sc, rig)
    moving = np.flatnonzero(tl.moving > 0)[:64]
    assert moving.size == 64
    frames = Simulator(sc, rig).render(tl.select(moving))
    S = [band_spectrum(f, rig) for f in frames]
    rho = [chirp_coherence(a, b, rig) for a, b in zip(S[1:], S[:-1])]
    assert min(rho) > 0.9 > MIN_COHERENCE
    noise = np.random.default_rng(2).normal(0, 0.1, (64, rig.n_chirp))
    N = [band_spectrum(f, rig) for f in noise]
    assert max(chirp_coherence(a, b, rig) for a, b in zip(N[1:], N[:-1])) < 0.3 < MIN_COHERENCE
    shifted = band_spectrum(np.roll(frames[10], 300), rig)  # the same chirp, cut 300 samples later
    assert chirp_coherence(shifted, S[9], rig) > 0.9


def test_a_valid_run_loses_no_frame_to_the_check(cli_files, capsys):
    """The running check does not refuse a valid run: the simulated link with its scripted presses skips no frame."""
    code, out, err = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact",
                                  cli_files["artifact"], "--fast", "--duration", "30", "--no-status"])
    assert code == 0, err
    summary = json.loads(err.strip().splitlines()[-1])["summary"]
    assert summary["skipped"] == {"nan": 0, "silent": 0, "clipped": 0, "dropout": 0, "constant": 0, "no_chirp": 0}
    assert summary["touch_events"] > 0


# -- a simulated source that stops delivering, at any pace ------------------------------------------------------------
def _stall_after(monkeypatch, calls: int, how: str):
    """Make the simulator's producer stop after ``calls`` renders: ``block`` (waits for ever, not computing), ``raise``,
    or ``busy`` (computes for 2.5 s, then goes on: a slow render on a loaded machine, not a stall)."""
    import time

    from sonicskin.sim import Simulator

    orig, n, release = Simulator.render, [0], threading.Event()

    def render(self, tl, **kw):
        n[0] += 1
        if n[0] > calls:
            if how == "block":
                release.wait()
            elif how == "raise":
                raise RuntimeError("the renderer broke")
            elif how == "busy" and n[0] == calls + 1:
                t = time.perf_counter()
                while time.perf_counter() - t < 2.5:
                    sum(range(1000))
        return orig(self, tl, **kw)

    monkeypatch.setattr(Simulator, "render", render)
    return release


def _iterate(lst) -> dict:
    """Iterate a listener in a thread (a hang is then a failed test, not a stuck suite)."""
    out: dict = {"events": 0}

    def go():
        try:
            for _ in lst:
                out["events"] += 1
        except BaseException as e:  # handed to the test
            out["error"] = e

    t = threading.Thread(target=go, daemon=True)
    t.start()
    t.join(timeout=300)  # a guard against a hang only (the run takes seconds)
    out["alive"] = t.is_alive()
    return out


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "real-time"])
def test_a_simulated_source_that_stops_delivering_ends_with_device_lost(cli_files, monkeypatch, fast):
    """``fast=True`` with a producer that stops delivering hung for ever (no exit after 90-180 s): the watchdog only
    watched devices; at real-time pace the run ended at ``duration_s`` with no word."""
    from sonicskin.api import Listener
    from sonicskin.live import DeviceLost

    release = _stall_after(monkeypatch, 1, "block")
    try:
        r = _iterate(Listener(cli_files["artifact"], scenario=cli_files["scenario"], fast=fast, duration_s=60,
                              watchdog_s=1.0, blocksize=256))
    finally:
        release.set()
    assert not r["alive"]
    assert isinstance(r.get("error"), DeviceLost), r
    assert str(r["error"]) == ("no audio from the simulated device for 1 s: its producer thread stopped delivering without "
                               "ending the stream (and is not computing); start again")


def test_a_producer_that_raises_hands_its_error_to_the_caller(cli_files, monkeypatch):
    """An exception in the simulated source's thread ended the stream silently (and hung with fast=True)."""
    from sonicskin.api import Listener

    _stall_after(monkeypatch, 1, "raise")
    r = _iterate(Listener(cli_files["artifact"], scenario=cli_files["scenario"], fast=True, duration_s=60, watchdog_s=1.0,
                          blocksize=256))
    assert not r["alive"] and isinstance(r.get("error"), RuntimeError) and str(r["error"]) == "the renderer broke", r


def test_a_slow_render_is_not_a_stall(cli_files, monkeypatch):
    """A render that computes for longer than the watchdog (a loaded machine) is not a dead device: the run goes on."""
    from sonicskin.api import Listener

    _stall_after(monkeypatch, 1, "busy")
    lst = Listener(cli_files["artifact"], scenario=cli_files["scenario"], fast=True, duration_s=60, watchdog_s=1.0,
                   blocksize=256)
    r = _iterate(lst)
    assert not r["alive"] and "error" not in r, r
    assert r["events"] > 0 and lst.summary["stream_s"] > 5


# -- the event stream: what `live` writes, its own reader reads -----------------------------------------------------
def test_the_reader_keeps_fields_it_does_not_know():
    """A v1 reader refused an event with one added field (``additionalProperties: false``), though fields are only ever
    added within a version: the first added field would have broken every deployed reader."""
    from sonicskin.events import EVENT_SCHEMA, parse_event

    line = ('{"v": 1, "t_s": 4.2667, "kind": "touch", "location": 3, "x_cm": 6.1, "y_cm": 12.0, "force_n": 2.5, '
            '"confidence": 0.9, "model": "svm", "latency_ms": 0.8, "pressure_kpa": 3.5, "tags": ["a"]}')
    ev = parse_event(line)
    assert ev.location == 3 and ev.extra == {"pressure_kpa": 3.5, "tags": ["a"]} and ev.link is None
    assert json.loads(ev.to_json()) == json.loads(line)  # a relay passes them on
    assert EVENT_SCHEMA["additionalProperties"] is True and EVENT_SCHEMA["properties"]["link"]["type"] == "string"
    assert "link" not in EVENT_SCHEMA["required"]


def test_a_declared_field_is_still_checked():
    from sonicskin.events import EventError, parse_event

    good = {"v": 1, "t_s": 1.0, "kind": "touch", "location": 0, "x_cm": 1.0, "y_cm": 2.0, "force_n": 1.0,
            "confidence": 0.5, "model": "svm", "latency_ms": 0.1}
    assert parse_event(json.dumps({**good, "link": "forearm"})).link == "forearm"
    with pytest.raises(EventError) as e:
        parse_event(json.dumps({**good, "link": 5}))
    assert str(e.value) == "link must be string, got 5"
    with pytest.raises(EventError) as e:
        parse_event(json.dumps({**good, "v": 3, "pressure_kpa": 1}))
    assert str(e.value) == "v must be one of [1, 2], got 3 (a reader for schema v2: a newer sonicskin reads newer events)"


def test_everything_live_links_writes_parses(cli_files, monkeypatch, capsys):
    """Every event of ``live --links`` carries ``"link"``; ``parse_event`` raised ``EventError: unknown fields ['link']``
    on each of them.  Two time-duplexed links (the shipped two-links-time config) on a fake two-channel interface."""
    from sonicskin.events import parse_event
    from sonicskin.links import load_links
    from sonicskin.rig import Rig
    from sonicskin.sim import Scenario, Simulator, build_timeline

    rig = Rig.load(cli_files["rig"])
    sc = Scenario.load(cli_files["scenario"])
    frames = []
    for k in range(2):  # one simulated link per robot link: the same link, another person-session of presses
        live = sc.replace(seed=sc.seed + 1000 + k, sessions=1)
        frames.append(Simulator(live, rig).render(build_timeline(live, rig)))
    n = min(len(f) for f in frames)
    quiet = np.random.default_rng(0).normal(0, 1e-5, (n, rig.n_chirp)).astype(np.float32)  # the other link's turn
    cols = [np.stack([frames[0][:n], quiet], axis=1).ravel(), np.stack([quiet, frames[1][:n]], axis=1).ravel()]
    stream = np.stack(cols, axis=1)[3000:]

    class Interface(acquire._QueueSource):
        def __init__(self, rig, device=None, *, links=None, blocksize=1024, **kw):
            super().__init__(rig, blocksize, max_queued_s=60)
            self.finished = threading.Event()

        def start(self):
            for k in range(0, len(stream), 1024):
                self._deliver(stream[k:k + 1024])
            self.finished.set()

        def stop(self):
            pass

    monkeypatch.setattr(acquire, "SoundDeviceSource", Interface)
    art = str(cli_files["artifact"])
    code, out, err = run(capsys, ["live", "--device", "0", "--rig", cli_files["rig"], "--links", "two-links-time",
                                  "--link-artifact", art, "--link-artifact", art, "--no-status"])
    assert code == 0, err
    events = [parse_event(line) for line in out.splitlines()]
    names = [lk.name for lk in load_links("two-links-time", rig)]
    assert {e.link for e in events} == set(names) and all(e.extra == {} for e in events)
    assert all(json.loads(line)["link"] == e.link for line, e in zip(out.splitlines(), events))


# -- refused up front: one line each ----------------------------------------------------------------------------------
def _live(cli_files, *argv):
    return ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact", cli_files["artifact"],
            "--fast", "--duration", "5", "--no-status", *argv]


LIVE_REFUSALS = [
    (["--udp", "255.255.255.255:9999"], "--udp 255.255.255.255:9999: 255.255.255.255 is the broadcast address, which a UDP "
                                        "socket may not send to (Permission denied); give the address of the machine "
                                        "that reads the events (127.0.0.1 for this one)"),
    (["--udp", "0.0.0.0:9999"], "--udp 0.0.0.0:9999: 0.0.0.0 is the unspecified address, not a destination; give the "
                                "address of the machine that reads the events (127.0.0.1 for this one)"),
    (["--lsl", ""], "--lsl '': the stream needs a name (e.g. --lsl sonicskin, or --lsl alone for that default)"),
    (["--drop-every", "1"], "--drop-every 1 drops every audio block, so nothing would reach the loop; give N >= 2 (one "
                            "block lost in N)"),
    (["--blocksize", "1000000000"], "--blocksize must be an integer from 1 to 1048576 (audio frames per block), got "
                                    "1000000000"),
]


@pytest.mark.parametrize("argv, message", refusals(LIVE_REFUSALS))
def test_live_options_that_cannot_work_are_one_line(cli_files, capsys, argv, message):
    """``--udp 255.255.255.255:9999`` ran to the end with one warning that no event was sent; ``--lsl ''`` published a
    stream no inlet can find by name; ``--drop-every 1`` dropped every block without a word; ``--blocksize 1e9``
    was taken where the API refuses more than 2^20."""
    code, out, err = run(capsys, _live(cli_files, *argv))
    assert assert_one_line_error(code, err, "live") == f"sonicskin live: error: {message}" and out == ""


def test_drop_every_is_for_the_simulated_device(cli_files, capsys):
    code, _, err = run(capsys, ["live", "--device", "0", "--artifact", cli_files["artifact"], "--drop-every", "5"])
    assert assert_one_line_error(code, err, "live") == ("sonicskin live: error: --drop-every injects lost blocks into the "
                                                        "simulated device (--device sim); a real device loses its own")


CHECK_REFUSALS = [
    (["--press", "0.05"], "--press 0.05 s holds fewer than the 3 chirp periods the check needs to measure the touch "
                          "contrast (106.7 ms each): give --press 0.4 or more"),
    (["--blocksize", "1000000000"], "--blocksize must be an integer from 1 to 1048576 (audio frames per block), got "
                                    "1000000000"),
]


@pytest.mark.parametrize("argv, message", refusals(CHECK_REFUSALS))
def test_check_values_that_cannot_be_measured_are_one_line(tmp_path, capsys, argv, message):
    """``check --press 0.05`` reported 'touch contrast: fail', which reads as a rig fault, for a press too short to
    measure; ``--blocksize 1e9`` was accepted where the API caps it at 2^20."""
    assert refusal(capsys, ["check", "--out", tmp_path / "o", *argv]) == message
    assert not (tmp_path / "o").exists()


def test_the_shortest_press_the_check_accepts_is_measured(cli_files, tmp_path, capsys):
    """At the refusal's own suggestion the touch contrast is measured (the small rig: 3 periods are 16 ms)."""
    code, _, err = run(capsys, ["check", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--rest", "1",
                                "--press", "0.01", "--out", tmp_path / "o"])
    assert assert_one_line_error(code, err, "check") == (
        "sonicskin check: error: --press 0.01 s holds fewer than the 3 chirp periods the check needs to measure the touch "
        "contrast (5.3 ms each): give --press 0.1 or more")
    code, out, err = run(capsys, ["check", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--rest", "1",
                                  "--press", "0.1", "--out", tmp_path / "o"])
    contrast = json.loads((tmp_path / "o" / "check.json").read_text())["measurements"]["touch_contrast_db"]
    assert contrast > 0, out


API_REFUSALS = [
    ({"scenario": "no-such"}, "ConfigNotFoundError", "no scenarios config named 'no-such'; known: drift-2h, moving, "
                              "multi-person, plate-aluminium, random, stationary, two-points; or give a path to a YAML file"),
    ({"rig": "no-such"}, "ConfigNotFoundError", "no rigs config named 'no-such'; known: fast, jaco; or give a path to a "
                         "YAML file"),
    ({"scenario": 5}, "SonicskinError", "scenario must be a scenario name or YAML path (e.g. 'stationary'), got 5"),
    ({"rig": 5}, "SonicskinError", "rig must be None (the artifact's own), a rig name or a YAML path, got 5"),
    ({"fast": "no"}, "SonicskinError", "fast must be True or False, got 'no'"),
    ({"overwrite": "no"}, "SonicskinError", "overwrite must be True or False, got 'no'"),
    ({"view": "80"}, "SonicskinError", "view must be True (any free port), a TCP port number 1-65535 (an int; 0: any free "
                     "one) or None/False (no page), got '80'"),
    ({"view": 80.0}, "SonicskinError", "view must be True (any free port), a TCP port number 1-65535 (an int; 0: any free "
                     "one) or None/False (no page), got 80.0"),
    ({"view": 70000}, "SonicskinError", "view must be True (any free port), a TCP port number 1-65535 (an int; 0: any "
                      "free one) or None/False (no page), got 70000"),
    ({"foxglove": "8765"}, "SonicskinError", "foxglove must be True (port 8765), a TCP port number 1-65535 (an int; 0: any "
                          "free one) or None (no server), got '8765'"),
    ({"foxglove": False}, "SonicskinError", "foxglove must be True (port 8765), a TCP port number 1-65535 (an int; 0: any "
                         "free one) or None (no server), got False"),
    ({"on_event": "print"}, "SonicskinError", "on_event must be a function called with each TouchEvent (or None), got "
                            "'print'"),
    ({"blocksize": 10**9}, "SonicskinError", "blocksize must be an integer from 1 to 1048576 (audio frames per block), "
                           "got 1000000000"),
]


@pytest.mark.parametrize("kw, kind, message", API_REFUSALS, ids=[next(iter(c[0])) + "=" + repr(next(iter(c[0].values())))
                                                                for c in API_REFUSALS])
def test_api_arguments_are_one_line_sonicskin_errors(cli_files, kw, kind, message):
    """``scenario="no-such"``/``rig="no-such"`` raised a bare FileNotFoundError, ``scenario=None`` a TypeError (not
    ``SonicskinError``); ``fast="no"`` counted as true; ``on_event="print"`` failed at the first touch, in the
    listener's thread.  A config that is not there is still a FileNotFoundError too."""
    from sonicskin.api import Listener

    with pytest.raises(SonicskinError) as e:
        Listener(cli_files["artifact"], **kw)
    assert type(e.value).__name__ == kind and str(e.value) == message
    assert isinstance(e.value, FileNotFoundError) == (kind == "ConfigNotFoundError")


def test_overwrite_no_replaces_no_recording(cli_files, tmp_path):
    """``Listener(..., mcap="l.mcap", overwrite="no")`` took "no" as true and replaced the file; only a bool is taken."""
    from sonicskin.api import Listener

    earlier = tmp_path / "l.mcap"
    earlier.write_bytes(b"an earlier recording")
    for bad in ("no", 0, None):
        with pytest.raises(SonicskinError) as e:
            Listener(cli_files["artifact"], mcap=earlier, overwrite=bad)
        assert str(e.value) == f"overwrite must be True or False, got {bad!r}"
    assert earlier.read_bytes() == b"an earlier recording"


def test_device_errors_are_sonicskin_errors_and_still_runtime_errors(cli_files):
    """``AudioError``/``DeviceLost`` were RuntimeErrors only: ``except SonicskinError`` in a robot program did not catch
    a missing or dead device.  They are both now (``except AudioError`` and ``except RuntimeError`` still work)."""
    from sonicskin.acquire import AudioError
    from sonicskin.api import Listener
    from sonicskin.live import DeviceLost, InputUnusable

    for cls in (AudioError, DeviceLost, InputUnusable):
        assert issubclass(cls, SonicskinError) and issubclass(cls, RuntimeError)
    with pytest.raises(AudioError) as e:  # no PortAudio, no device, or none of that name: an AudioError each
        Listener(cli_files["artifact"], device="no-such-interface-xyz", rig=cli_files["rig"])
    assert isinstance(e.value, SonicskinError) and len(str(e.value).splitlines()) == 1


# -- live without an artifact says what it will do --------------------------------------------------------------------
def test_live_without_an_artifact_says_what_it_will_do_first(cli_files, tmp_path, monkeypatch, capsys):
    """``sonicskin live`` without ``--artifact`` trained for 118 s and wrote 202 MB into the current folder without a
    word.  It says so on one line before it starts (here the training is stopped right after that line)."""
    import sonicskin.sim.generate as generate

    def stop(*a, **kw):
        raise SonicskinError("stopped by the test")

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(generate, "simulate_dataset", stop)
    code, _, err = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--fast",
                                "--no-status"])
    assert code == 2 and err.splitlines() == [
        "no --artifact: training an SVM on the simulated 'tiny' link first, once: about 2 s on an idle 2-core machine "
        "(longer when it is busy), 3 MB of simulated recordings written to data/sim-tiny-oneshot, the artifact to "
        "artifacts/sim-tiny-svm (reused by later runs); pass --artifact DIR to run a trained one",
        "sonicskin live: error: stopped by the test"]


def test_live_without_an_artifact_names_the_one_it_reuses(cli_files, tmp_path, monkeypatch, capsys):
    import shutil

    monkeypatch.chdir(tmp_path)
    shutil.copytree(cli_files["artifact"], tmp_path / "artifacts" / "sim-tiny-svm")
    code, out, err = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--fast",
                                  "--duration", "5", "--no-status"])
    assert code == 0 and out, err
    assert err.splitlines()[0] == ("no --artifact: using artifacts/sim-tiny-svm, trained on the simulated 'tiny' link by "
                                   "an earlier run (delete it to train again)")


def test_a_boot_cut_by_lost_audio_says_so(cli_files):
    """A boot window that lost chirps to dropped blocks (no faulty frame) warned of '0 faulty chirp(s) (NaN, dropout,
    silence, ...)': it names the lost audio now."""
    from sonicskin.acquire import SimulatedSource
    from sonicskin.live import LiveLoop
    from sonicskin.rig import Rig
    from sonicskin.runtime import SkinRuntime
    from sonicskin.sim import Scenario, Simulator, build_timeline

    rig, sc = Rig.load(cli_files["rig"]), Scenario.load(cli_files["scenario"]).replace(sessions=1)
    src = SimulatedSource(Simulator(sc, rig), build_timeline(sc, rig), realtime=False, drop_every=40)
    warnings: list[str] = []
    loop = LiveLoop(SkinRuntime(cli_files["artifact"], "svm"), src, emit=lambda _: None, warn=warnings.append)
    with src:
        summary = loop.run()
    assert summary["boot_disturbed"] and sum(summary["skipped"].values()) == 0
    assert warnings[1:] and all(w.startswith("audio lost: stream time ") for w in warnings[1:])  # the lost blocks, named
    assert re.fullmatch(
        r"boot calibration disturbed: chirps cut by lost audio \(\d+ overflows or dropped blocks, [1-9]\d* re-locks\) in "
        r"the first 3\.0 s; reference from the \d+ clean chirps of that window, re-taken from the next 3\.0 s of rest",
        warnings[0]), warnings
