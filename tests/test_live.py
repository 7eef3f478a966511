"""The live system: framing with re-lock, the loop on the simulated device, faults, UDP, and an
end-to-end run through a real audio server (JACK with its dummy driver)."""

import json
import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from sonicskin import acquire
from sonicskin.acquire import AudioError, SimulatedSource
from sonicskin.dsp import rig_chirp
from sonicskin.fit import build_svm_artifact
from sonicskin.live import Framer, LiveLoop, UdpSink
from sonicskin.runtime import SkinRuntime
from sonicskin.sim import Scenario, Simulator, build_timeline
from sonicskin.sim.generate import simulate_dataset

LAYOUT = {"kind": "grid", "nx": 3, "ny": 1, "spacing_cm": 2.4, "x0_cm": 6, "y0_cm": 12}
SC = Scenario(sessions=1, layout=LAYOUT, touch_s=2.0, gap_s=0.8, calibration_s=3.0, repeats=2, seed=21)


@pytest.fixture(scope="module")
def artifact(tmp_path_factory, rig):
    root = tmp_path_factory.mktemp("live")
    simulate_dataset(SC, rig, root / "data", progress=False, log=lambda *_: None)
    build_svm_artifact(root / "data", root / "art", progress=False, log=lambda *_: None)
    return root / "art"


def _live_timeline(rig, seed=77, calibration_s=3.0):
    sc = SC.replace(seed=seed, repeats=1, calibration_s=calibration_s)
    return Simulator(sc, rig), build_timeline(sc, rig)


def _score(events, tl, rig, first_sample_of_chirp0):
    """Share of touch events on scripted touches that name the touched location."""
    L = rig.n_chirp
    hits = n = 0
    for e in events:
        if e.kind != "touch":
            continue
        k = int(round((e.t_s * rig.fs_hz - first_sample_of_chirp0) / L))
        if 0 <= k < len(tl) and tl.force_n[k] >= 0.5:
            n += 1
            hits += e.location == tl.location[k]
    return hits / max(n, 1), n


@pytest.mark.parametrize("offset", [0, 777, 20_000])
def test_framer_locks_and_relocks(rig, offset):
    s = rig_chirp(rig).astype(np.float32)
    L = rig.n_chirp
    stream = np.tile(s, 8)[offset:]
    f = Framer(s)
    got = []
    for i in range(0, 4 * L, 1000):
        got += f.push(stream[i:i + 1000], i)
    assert got and all((st + offset) % L == 0 for st, _ in got)
    np.testing.assert_array_equal(got[0][1], s)
    # Lose 1500 samples: the next block is flagged, the framer locks again on the true chirp grid.
    after = []
    for i in range(4 * L + 1500, 8 * L - offset - 1000, 1000):
        after += f.push(stream[i:i + 1000], i, discontinuity=(i == 4 * L + 1500))
    assert f.relocks == 1 and after and all((st + offset) % L == 0 for st, _ in after)


def test_live_loop_on_the_simulated_device(rig, artifact):
    sim, tl = _live_timeline(rig)
    src = SimulatedSource(sim, tl, realtime=False, offset=5000)
    lines = []
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lines.append)
    with src:
        summary = loop.run()
    acc, n = _score(loop.events, tl, rig, -5000)
    touched = int((tl.force_n >= 0.5).sum())
    assert n > 0.9 * touched and acc > 0.9
    assert summary["reference_refreshes"] == 1 and summary["relocks"] == 0
    ev = json.loads(lines[0])
    assert set(ev) >= {"t_s", "kind", "location", "x_cm", "y_cm", "force_n", "confidence", "model", "latency_ms"}
    assert any(json.loads(x)["kind"] == "release" for x in lines)


def test_live_loop_and_offline_replay_agree_chirp_by_chirp(rig, artifact, tmp_path):
    """A recorded session played through the live loop (audio -> framing -> SkinStream.frame, one
    chirp at a time) and replayed offline as compare/evaluate do (dataset features -> SkinRuntime.replay,
    vectorised) gives the same prediction for every chirp, Alg. 2 refreshes included."""
    import shutil

    from sonicskin.compare import replay_sessions
    from sonicskin.dataset import Dataset

    art = tmp_path / "art"
    shutil.copytree(artifact, art)
    meta = json.loads((art / "skin.json").read_text())
    # Refresh every 3 s from 0.5 s of rest (the 0.8 s gaps between presses) so the replay crosses several.
    for k in ("features", "calibration"):
        meta[k].update(alpha_s=3.0, beta_s=0.5)
    from sonicskin.artifact import skin_json
    from sonicskin.features import FeatureSpec

    # Written as a writer writes it: the models' bindings and the digest record the new settings (an edit is refused).
    skin_json(art, rig=meta["rig"], layout=meta["layout"], spec=FeatureSpec.from_dict(meta["features"]),
              min_force_n=meta["min_force_n"], training=meta["training"], models=meta["models"], drift=meta.get("drift"))
    assert "drift" in meta  # drift tracking on: every reference estimates the stretch, every chirp is mapped back
    ds = Dataset(artifact.parent / "data")
    t = ds.features(progress=False)
    for model in ("svm", "net") if "net" in meta["models"] else ("svm",):
        rt = SkinRuntime(art, model)
        got: dict = {}
        src = acquire.RecordingSource(ds, "s000")
        loop = LiveLoop(rt, src, emit=lambda _: None, on_chirp=lambda t_s, p, got=got: got.__setitem__(round(t_s * rig.fs_hz), p))
        with src:
            loop.run(idle_timeout_s=0.2)
        offline = replay_sessions(rt, t, ["s000"])
        # Chirp k of the session, as the framer found it (the labels' t_s omit the channel delay).
        first = min(got)
        assert all((st - first) % rig.n_chirp == 0 for st in got)
        got = {(st - first) // rig.n_chirp: p for st, p in got.items()}
        keys = np.round((t["t_s"][t["session"] == "s000"] - t["t_s"][0]) * rig.chirps_per_s).astype(int)
        assert set(got) == set(keys.tolist())  # the same chirps
        live_cal = np.array([got[k] is None for k in keys])
        np.testing.assert_array_equal(live_cal, offline.calibrating)
        assert live_cal.sum() == rt.stream().reference.beta
        run = ~live_cal
        live = [got[k] for k in keys[run]]
        np.testing.assert_array_equal([p.touch[0] for p in live], offline.touch[run])
        np.testing.assert_array_equal([p.location[0] for p in live], offline.location[run])
        np.testing.assert_allclose([p.force_n[0] for p in live], offline.force_n[run], atol=1e-4)
        np.testing.assert_allclose(np.concatenate([p.xy_cm for p in live]), offline.xy_cm[run], atol=1e-4)
        assert loop.refreshes >= 3 and offline.touch.any() and (~offline.touch[run]).any()
        assert loop.stream.drift is not None and loop.stream.drift.updates == loop.refreshes


def test_dropouts_are_counted_and_survived(rig, artifact):
    sim, tl = _live_timeline(rig)
    src = SimulatedSource(sim, tl, realtime=False, drop_every=150, offset=100)
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None)
    with src:
        summary = loop.run()
    assert summary["overflows"] == len(tl) * rig.n_chirp // 1024 // 150
    assert summary["relocks"] == summary["overflows"]
    acc, n = _score(loop.events, tl, rig, -100)
    # A lost block costs the chirp it cut and one period to lock again: ~2 of every 7.5 chirps here.
    assert n > 0.6 * int((tl.force_n >= 0.5).sum()) and acc > 0.85
    assert summary["chirps"] < 0.85 * len(tl)


def test_bad_frames_are_skipped_and_counted(rig, artifact):
    sim, tl = _live_timeline(rig)
    frames = sim.render(tl.select(np.arange(60)))
    frames[40, 100] = np.nan
    frames[45] = np.clip(frames[45] * 100, -1, 1)

    class Replay(acquire._QueueSource):
        def start(self):
            for k in range(0, frames.size, 1024):
                self._deliver(frames.ravel()[k:k + 1024])
            self.finished = type("E", (), {"is_set": lambda self: True})()

        def stop(self):
            pass

    src = Replay(rig, 1024, max_queued_s=30)
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None)
    src.start()
    summary = loop.run(idle_timeout_s=0.1)
    assert summary["skipped"] == {"nan": 1, "silent": 0, "clipped": 1, "dropout": 0, "constant": 0, "no_chirp": 0}
    assert summary["chirps"] == loop.framer.n_frames - 2 >= 57  # the last chirp is cut by the channel delay


def test_udp_sink_sends_to_localhost():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2)
    UdpSink(str(rx.getsockname()[1]))('{"kind": "touch"}')
    assert json.loads(rx.recv(1000)) == {"kind": "touch"}


def test_audio_errors_say_what_to_do(monkeypatch, rig):
    def no_portaudio():
        raise OSError("PortAudio library not found")

    monkeypatch.setattr(acquire, "import_sounddevice", lambda: (_ for _ in ()).throw(
        AudioError("the PortAudio library is not installed; on Debian/Ubuntu: sudo apt-get install libportaudio2")))
    with pytest.raises(AudioError, match="apt-get install libportaudio2"):
        acquire.list_devices()
    monkeypatch.undo()
    import builtins
    real_import = builtins.__import__

    def fake_import(name, *a, **k):
        if name == "sounddevice":
            no_portaudio()
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(AudioError, match="PortAudio library is not installed"):
        acquire.import_sounddevice()
    monkeypatch.undo()
    monkeypatch.setattr(acquire, "list_devices", lambda: [])
    monkeypatch.setattr(acquire, "import_sounddevice", lambda: None)
    with pytest.raises(AudioError, match="no audio device found.*--device sim"):
        acquire.find_device(None, rig, 1, 1)
    monkeypatch.setattr(acquire, "list_devices", lambda: [{"index": 0, "name": "USB Audio", "hostapi": "ALSA",
                                                          "inputs": 2, "outputs": 2, "default_rate_hz": 48000.0}])
    with pytest.raises(AudioError, match="no audio device matches 'Fireface'"):
        acquire.find_device("Fireface", rig, 1, 1)


# -- end to end through JACK -------------------------------------------------------------------

JACK_PERIOD = 4096

@pytest.fixture(scope="module")
def jack(rig):
    """A JACK server of this test run's own (a unique server name through JACK_DEFAULT_SERVER), so
    test runs in parallel on one machine never wire or stop each other's clients."""
    if shutil.which("jackd") is None:
        pytest.skip("JACK is not installed (apt-get install jackd2); .ci/run installs it")
    name = f"sonicskin-test-{os.getpid()}"
    old = os.environ.get("JACK_DEFAULT_SERVER")
    os.environ["JACK_DEFAULT_SERVER"] = name  # read by libjack in PortAudio and by jack_lsp/jack_connect
    # 4096-frame periods (21 ms): without real-time scheduling on 2 shared cores, a Python
    # callback can miss 5 ms deadlines and JACK then repeats or drops a period (an xrun).
    proc = subprocess.Popen(["jackd", "-n", name, "--no-realtime", "-d", "dummy", "-r", str(int(rig.fs_hz)), "-p",
                             str(JACK_PERIOD)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(50):
        if subprocess.run(["jack_lsp"], capture_output=True).returncode == 0:
            break
        time.sleep(0.1)
    else:
        proc.kill()
        _restore_env("JACK_DEFAULT_SERVER", old)
        pytest.skip("jackd did not start with the dummy driver at 192 kHz")
    sd = acquire.import_sounddevice()
    sd._terminate()  # PortAudio enumerates host APIs at initialisation: look again now JACK runs
    sd._initialize()
    yield
    sd._terminate()  # leave JACK before the server goes (PortAudio asserts at exit otherwise)
    proc.terminate()
    proc.wait(timeout=5)
    _restore_env("JACK_DEFAULT_SERVER", old)
    sd._initialize()


def _restore_env(key, value):
    if value is None:
        os.environ.pop(key, None)
    else:
        os.environ[key] = value


def _wire_loopback() -> str:
    """Connect every PortAudio client's first output to its first input, away from the dummy system ports.
    (A client of an earlier run that is still closing makes JACK name ours PortAudio-01, and PortAudio
    numbers the ports of a process's later streams on: in_1, out_1...; so read the names.)"""
    ports = subprocess.run(["jack_lsp"], capture_output=True, text=True).stdout.split()
    clients = sorted({p.split(":")[0] for p in ports if p.startswith("PortAudio")})
    assert clients, f"no PortAudio client in JACK: {ports}"

    def num(port):
        return int(port.rsplit("_", 1)[1])

    for c in clients:
        ins = sorted((p for p in ports if p.startswith(f"{c}:in_")), key=num)
        outs = sorted((p for p in ports if p.startswith(f"{c}:out_")), key=num)
        if not ins or not outs:
            continue
        for sys_port in ("system:capture_1", "system:capture_2"):
            subprocess.run(["jack_disconnect", sys_port, ins[0]], capture_output=True)
        for sys_port in ("system:playback_1", "system:playback_2"):
            subprocess.run(["jack_disconnect", outs[0], sys_port], capture_output=True)
        subprocess.run(["jack_connect", outs[0], ins[0]], capture_output=True)  # fails harmlessly when already connected
    lsp = subprocess.run(["jack_lsp", "-c"], capture_output=True, text=True).stdout
    return lsp


def test_end_to_end_through_jack(rig, artifact, jack):
    """Real sounddevice duplex stream at 192 kHz through JACK: what the simulated receiver would
    hear is played on the output, looped back to the input, framed and classified live."""
    # Hands off for 4.5 s: the loop calibrates on its first 3 s of audio, which starts a moment
    # after playback (until the loopback is wired, the input is silent and skipped).
    sim, tl = _live_timeline(rig, seed=78, calibration_s=4.5)
    play = sim.render(tl).ravel()
    src = acquire.SoundDeviceSource(rig, "system", playback=play, blocksize=JACK_PERIOD)
    lines = []
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lines.append)
    with src:
        time.sleep(0.2)
        lsp = _wire_loopback()
        summary = loop.run(duration_s=len(tl) * rig.period_s + 0.5)
    touches = [e for e in loop.events if e.kind == "touch"]
    runs0 = [(e.location, round(e.t_s, 1)) for e in touches[::5]]
    assert len(touches) > 0.6 * int((tl.force_n >= 0.5).sum()), (len(touches), runs0, summary, lsp)
    # Scripted order of touched locations vs the order of detected runs.
    order = [int(e) for e in dict.fromkeys(tl.event[tl.event >= 0])]
    scripted = [int(tl.location[tl.event == e][0]) for e in order]
    runs = []
    for e in touches:
        if not runs or runs[-1][0] != e.location:
            runs.append([e.location, 0])
        runs[-1][1] += 1
    detected = [loc for loc, n in runs if n >= 5]
    assert detected == scripted, (detected, scripted, summary)


def test_links_config(rig):
    from sonicskin.links import load_links

    t = load_links("two-links-time", rig)
    assert [(lk.name, lk.slot, lk.n_slots) for lk in t] == [("upper-arm", 0, 2), ("forearm", 1, 2)]
    assert np.abs(t[1].tx_period(rig)[: rig.n_chirp]).max() == 0 and np.abs(t[1].tx_period(rig)[rig.n_chirp:]).max() > 0
    f = load_links("two-links-frequency", rig)
    assert (f[0].rig.f_lo_hz, f[0].rig.f_hi_hz, f[1].rig.f_lo_hz, f[1].rig.f_hi_hz) == (20e3, 50e3, 50e3, 80e3)


def test_two_time_duplexed_links_from_one_stream(rig, artifact):
    """Two links share one interface, taking turns chirp by chirp; one loop per link reads its own channel."""
    from sonicskin.links import load_links
    from sonicskin.live import run_loops

    links = load_links("two-links-time", rig)
    # 4.5 s hands-off: the loops calibrate on their first 3 s of whole chirps (the stream starts mid-period).
    (sim_a, tl_a), (sim_b, tl_b) = _live_timeline(rig, 80, 4.5), _live_timeline(rig, 81, 4.5)
    n = min(len(tl_a), len(tl_b))
    fa, fb = sim_a.render(tl_a.select(np.arange(n))), sim_b.render(tl_b.select(np.arange(n)))
    noise = np.random.default_rng(0).normal(0, 1e-5, fa.shape).astype(np.float32)  # the other link's turn
    col_a = np.stack([fa, noise], axis=1).ravel()
    col_b = np.stack([noise, fb], axis=1).ravel()
    stream = np.stack([col_a, col_b], axis=1)[3000:]

    class Replay(acquire._QueueSource):
        def start(self):
            for k in range(0, len(stream), 1024):
                self._deliver(stream[k:k + 1024])
            self.finished = type("E", (), {"is_set": lambda self: True})()

        def stop(self):
            pass

    src = Replay(rig, 1024, max_queued_s=60)
    loops = [LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None, link=lk, channel=i) for i, lk in enumerate(links)]
    src.start()
    run_loops(loops, src, idle_timeout_s=0.1)
    L = rig.n_chirp
    for lp, tl, lk in zip(loops, (tl_a, tl_b), links):
        hits = n_ev = 0
        for e in lp.events:
            k = int(round((e.t_s * rig.fs_hz + 3000 - lk.slot * L) / (2 * L)))
            if e.kind == "touch" and 0 <= k < n and tl.force_n[k] >= 0.5:
                n_ev += 1
                hits += e.location == tl.location[k]
        assert n_ev > 0.8 * int((tl.force_n[:n] >= 0.5).sum()) and hits / n_ev > 0.9


def test_rig_check_through_jack(rig, jack):
    """`sonicskin check` on a real duplex stream: what the simulated receiver would hear (rest, then a
    press) is played on JACK's output, looped back to its input, recorded on every input and measured."""
    from sonicskin.check import SimulatedDevice, analyse, capture

    dev = SimulatedDevice(rig, SC)
    with dev.source(settle_s=0.5, rest_s=3.0, press_s=2.0, tail_s=1.5) as src:  # what the simulated receiver puts out
        play = np.concatenate([b.samples for b in acquire.blocks(src) if b is not None])
    asked = []
    cap = capture(rig, "system", rest_s=3.0, press_s=2.0, playback=play, blocksize=JACK_PERIOD,
                         on_start=lambda: (time.sleep(0.2), _wire_loopback()), prompt=asked.append)
    rep = analyse(cap, rig)
    assert any("PRESS NOW" in m for m in asked)
    # Chirps the loopback had not wired yet, or an xrun of JACK's dummy driver: counted, not fatal.
    assert rep.status("output-to-input delay") != "fail", rep.table()
    for name in ("sample rate", "chirp lock", "input level", "SNR per sub-band", "touch contrast"):
        assert rep.status(name) == "pass", rep.table()
    # The loopback adds whole blocks of latency to the simulated interface's 2.9 ms + the acoustic path.
    extra = rep.measurements["delay_ms"] - analyse(capture(rig, dev, rest_s=3.0, press_s=2.0), rig).measurements["delay_ms"]
    assert extra == pytest.approx(round(extra * rig.fs_hz / 1e3 / JACK_PERIOD) * JACK_PERIOD / rig.fs_hz * 1e3, abs=0.05), extra


# -- a live loop that survives its device (issue 16.5) ------------------------------------------------

class _Replay(acquire._QueueSource):
    """A finite stream delivered block by block, as fast as it is read."""

    def __init__(self, rig, stream):
        super().__init__(rig, 1024, max_queued_s=600)
        self.stream = stream

    def start(self):
        for k in range(0, len(self.stream), 1024):
            self._deliver(self.stream[k:k + 1024])
        self.finished = type("E", (), {"is_set": lambda self: True})()

    def stop(self):
        pass


@pytest.fixture(scope="module")
def boot_stream(rig):
    sim, tl = _live_timeline(rig, seed=79)
    return sim.render(tl).ravel(), tl


def _chirp_errors(events, tl, rig, offset):
    """Share of the chirps after the 3 s boot that the loop gets wrong: a pressed chirp (>= 0.5 N)
    without a touch event naming its marker, or a hands-off chirp with a touch event."""
    L = rig.n_chirp
    got = {int(round((e.t_s * rig.fs_hz + offset) / L)): e.location for e in events if e.kind == "touch"}
    boot = rig.seconds_to_chirps(3.0)
    wrong = n = 0
    for k in range(boot + 1, len(tl) - 1):
        if 0 < tl.force_n[k] < 0.5:
            continue
        n += 1
        wrong += (got.get(k) != tl.location[k]) if tl.force_n[k] >= 0.5 else (k in got)
    return wrong / n


def _run_stream(rig, artifact, stream, **kw):
    warnings = []
    src = _Replay(rig, stream)
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None, warn=warnings.append, **kw)
    src.start()
    summary = loop.run(idle_timeout_s=0.1)
    return loop, summary, warnings


@pytest.mark.parametrize("fault", ["nan", "zeros"])
def test_a_fault_in_the_boot_calibration_does_not_poison_the_session(rig, artifact, boot_stream, fault):
    """NaN samples in 8 chirps, or 0.43 s of zeros, inside the first 3 s (hands off; the first press
    starts at 3 s): the reference comes from the clean chirps of the hands-off window, with one
    warning, and the error rate stays near the clean run's."""
    stream, tl = boot_stream
    offset = 3000
    clean_loop, _, clean_warn = _run_stream(rig, artifact, stream[offset:])
    base = _chirp_errors(clean_loop.events, tl, rig, offset)
    bad = stream[offset:].copy()
    L, fs = rig.n_chirp, int(rig.fs_hz)
    if fault == "nan":
        bad[np.arange(5, 13) * L + 777] = np.nan
    else:
        bad[fs: fs + int(0.43 * fs)] = 0.0
    loop, summary, warn = _run_stream(rig, artifact, bad)
    err = _chirp_errors(loop.events, tl, rig, offset)
    assert not clean_warn and base < 0.06
    assert err < base + 0.04, (err, base)
    assert summary["boot_disturbed"] and len(warn) == 1 and warn[0].startswith("boot calibration disturbed:"), warn
    skipped = summary["skipped"]["nan"] if fault == "nan" else summary["skipped"]["silent"] + summary["skipped"]["dropout"]
    assert skipped >= (8 if fault == "nan" else 4)
    assert 28 // 4 <= loop.stream.reference.boot_chirps < 28


def test_non_finite_samples_never_reach_the_model(rig, artifact, boot_stream):
    stream, tl = boot_stream
    bad = stream[5000:].copy()
    L = rig.n_chirp
    bad[:50] = np.nan                              # before the lock
    bad[40 * L + 10: 40 * L + 20] = np.inf         # mid-stream
    bad[60 * L + 3] = -np.inf
    rt = SkinRuntime(artifact, "svm")
    seen = []
    real_run = rt.run
    rt.run = lambda x: seen.append(np.isfinite(x).all()) or real_run(x)
    src = _Replay(rig, bad)
    loop = LiveLoop(rt, src, emit=lambda _: None, warn=lambda _: None)
    src.start()
    summary = loop.run(idle_timeout_s=0.1)
    assert seen and all(seen) and summary["skipped"]["nan"] >= 2  # the first NaNs fall before the first whole chirp
    assert summary["relocks"] <= 1 and summary["chirps"] > len(tl) - 10
    assert _chirp_errors(loop.events, tl, rig, 5000) < 0.08


def test_dropout_frames():
    from sonicskin.live import dropout_frames

    x = np.random.default_rng(0).normal(0, 1e-3, (4, 2048)).astype(np.float32)
    x[1, 100:164] = 0      # 64 zeros in a row: a dropout
    x[2, ::2] = 0          # many zeros, never two in a row
    x[3, 10:73] = 0        # 63 in a row
    np.testing.assert_array_equal(dropout_frames(x), [False, True, False, False])


class _Dying(acquire._QueueSource):
    """A device that delivers ``n`` blocks and then falls silent without a word (the server died);
    ``every_s`` paces the blocks."""

    def __init__(self, rig, n, every_s=0.0):
        super().__init__(rig, 1024)
        self.n, self.every_s = n, every_s
        self._stop = False

    def start(self):
        chirp = np.tile(rig_chirp(self.rig).astype(np.float32) * 0.1, 1 + self.n * 1024 // self.rig.n_chirp + 1)

        def produce():
            for i in range(self.n):
                if self._stop:
                    return
                self._deliver(chirp[i * 1024:(i + 1) * 1024])
                time.sleep(self.every_s)

        import threading
        threading.Thread(target=produce, daemon=True).start()

    def stop(self):
        self._stop = True


def test_watchdog_stops_a_loop_whose_device_died(rig, artifact):
    from sonicskin.live import DeviceLost

    src = _Dying(rig, 100)
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None)
    src.start()
    t0 = time.perf_counter()
    with pytest.raises(DeviceLost, match=r"no audio from the device for 1 s \(the audio server or the interface stopped"):
        loop.run(duration_s=20, watchdog_s=1.0)
    assert time.perf_counter() - t0 >= 1.0  # not before its second (no upper bound: the suite runs at load 5)


def test_duration_is_honoured_by_the_clock(rig, artifact):
    """A device that delivers 10 x slower than real time: --duration 1.5 still ends after 1.5 s."""
    src = _Dying(rig, 10_000, every_s=0.05)
    loop = LiveLoop(SkinRuntime(artifact, "svm"), src, emit=lambda _: None)
    src.start()
    t0 = time.perf_counter()
    summary = loop.run(duration_s=1.5, watchdog_s=None)
    src.stop()
    assert time.perf_counter() - t0 >= 1.5 and summary["stream_s"] < 0.5  # ended by the clock, not by the audio


def test_cli_live_on_a_device_that_dies_ends_with_one_line(rig, artifact, monkeypatch, capsys):
    monkeypatch.setattr(acquire, "SoundDeviceSource", lambda rig, device, **kw: _Dying(rig, 50))
    from sonicskin.cli import main

    t0 = time.perf_counter()
    code = main(["live", "--device", "0", "--artifact", str(artifact), "--duration", "20", "--watchdog", "1", "--no-status"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and time.perf_counter() - t0 >= 1.0  # the watchdog's second, then one line
    assert err[-1].startswith("sonicskin live: error: no audio from the device for 1 s") and err[-2].startswith('{"summary"')


def test_rig_check_through_jack_names_a_rate_the_server_does_not_run(jack):
    """JACK runs at 192 kHz; a 48 kHz rig is refused by the real device, with the fix."""
    from sonicskin.check import analyse, capture
    from sonicskin.rig import Rig

    rig48 = Rig(fs_hz=48_000.0, f_lo_hz=5_000.0, f_hi_hz=20_000.0, n_chirp=4096, pwm_hz=(30_000.0,))
    rep = analyse(capture(rig48, "system", prompt=lambda m: None), rig48)
    assert rep.status("sample rate") == "fail" and not rep.ok
    assert rep.line("sample rate").fix.startswith("set the interface to 48000 Hz"), rep.table()


def test_the_fast_frame_check_never_passes_a_faulty_frame():
    """clearly_clean (one pass per chirp of every link) is True only where the full checks find no fault: a DC offset
    far above a variation too small to be audio, silence, NaN, clipping and dropouts all go to the full checks."""
    from sonicskin.live import LiveLoop, clearly_clean

    rng = np.random.default_rng(3)
    L = 2560
    frames = [0.1 * rng.standard_normal(L), np.full(L, 0.5), 0.5 + 1e-9 * rng.standard_normal(L), np.zeros(L),
              np.r_[np.nan, 0.1 * np.ones(L - 1)], np.clip(2 * rng.standard_normal(L), -1, 1),
              np.r_[np.zeros(100), 0.1 * rng.standard_normal(L - 100)], 1e-8 * rng.standard_normal(L),
              np.r_[np.zeros(63), 0.1 * rng.standard_normal(L - 63)], 0.3 + 0.01 * rng.standard_normal(L)]
    frames += [a * rng.standard_normal(L) + b for a in (1e-8, 1e-6, 1e-3, 0.3) for b in (0.0, 0.2, 0.9)]
    verdicts = [(clearly_clean(f.astype(np.float32)), LiveLoop._fault(f.astype(np.float32))) for f in frames]
    assert all(fault == 0 for clean, fault in verdicts if clean)
    assert sum(clean for clean, _ in verdicts) >= 5  # and it does pass ordinary audio


def test_a_pause_longer_than_alpha_reboots_alike_live_and_offline(rig, artifact):
    """A recording with a pause of two hours in it (the device was off): the chirps after the pause start a new boot
    calibration (no predictions for beta seconds), chirp by chirp (the live loop's path) as in the vectorised replay."""
    from sonicskin.dataset import Dataset

    t = Dataset(artifact.parent / "data").features(progress=False)
    X, ts = t.X, np.asarray(t["time_s"], float).copy()
    half = len(ts) // 2
    ts[half:] += 7200.0
    for model in ("svm", "net") if (artifact / "net.onnx").exists() else ("svm",):
        rt = SkinRuntime(artifact, model)
        st = rt.stream()
        one = [st.chirp(X[i], ts[i]) for i in range(len(X))]
        cal = np.array([p is None for p in one])
        beta = st.reference.beta
        assert np.flatnonzero(cal).tolist() == list(range(beta)) + list(range(half, half + beta))
        assert st.reference.reboots == 1
        off = rt.replay(X, ts)
        np.testing.assert_array_equal(off.calibrating, cal)
        np.testing.assert_array_equal(off.touch[~cal], [p.touch[0] for p in one if p is not None])
        np.testing.assert_array_equal(off.location[~cal], [p.location[0] for p in one if p is not None])


_DEAD_SERVER_LIVE = """
import functools, sys
import numpy as np
from sonicskin import acquire
from sonicskin.dsp import rig_chirp
from sonicskin.rig import Rig
rig = Rig.load("jaco")  # the chirp through a made-up wall on the output, so the loopback sounds like a link
h = np.random.default_rng(0).normal(size=400) * np.exp(-np.arange(400) / 80)
period = np.real(np.fft.ifft(np.fft.fft(rig_chirp(rig)) * np.fft.fft(h, rig.n_chirp))).astype(np.float32)
acquire.SoundDeviceSource = functools.partial(acquire.SoundDeviceSource, playback=0.3 * period / np.abs(period).max())
from sonicskin.cli import main
raise SystemExit(main(["live", "--device", "system", "--artifact", sys.argv[1], "--duration", "60", "--watchdog", "2",
                       "--no-status"]))
"""


def test_live_exits_when_its_jack_server_dies(rig, artifact, tmp_path):
    """Issue 37: `live --device system` whose JACK server died mid-run printed its error and summary, then never exited
    (PortAudio's terminate hangs at interpreter exit): a supervisor that restarts the sensor waited forever.  It exits
    now, with the error's code 2."""
    if shutil.which("jackd") is None:
        pytest.skip("JACK is not installed (apt-get install jackd2); .ci/run installs it")
    env, live = dict(os.environ, JACK_DEFAULT_SERVER=f"sonicskin-dies-{os.getpid()}"), None
    server = subprocess.Popen(["jackd", "-n", env["JACK_DEFAULT_SERVER"], "--no-realtime", "-d", "dummy", "-r",
                               str(int(rig.fs_hz)), "-p", str(JACK_PERIOD)], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        for _ in range(50):
            if subprocess.run(["jack_lsp"], env=env, capture_output=True).returncode == 0:
                break
            time.sleep(0.1)
        else:
            pytest.skip("jackd did not start with the dummy driver at 192 kHz")
        live = subprocess.Popen([sys.executable, "-c", _DEAD_SERVER_LIVE, str(artifact)], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        for _ in range(300):  # its client's ports, then wired out -> in
            ports = subprocess.run(["jack_lsp"], env=env, capture_output=True, text=True).stdout.split()
            if any(p.startswith("PortAudio") and ":in_" in p for p in ports):
                break
            time.sleep(0.1)
        client = next(p for p in ports if p.startswith("PortAudio")).split(":")[0]
        subprocess.run(["jack_disconnect", "system:capture_1", f"{client}:in_0"], env=env, capture_output=True)
        subprocess.run(["jack_connect", f"{client}:out_0", f"{client}:in_0"], env=env, capture_output=True)
        time.sleep(4)
        server.terminate()  # the audio server goes away mid-run
        out, err = live.communicate(timeout=120)  # a hang guard (it hung for ever), not a speed bound
    finally:
        for p in (server, live):
            if p is not None:
                p.kill()
                p.wait()
    lines = err.strip().splitlines()
    assert live.returncode == 2 and lines[-1].startswith("sonicskin live: error: no audio from the device for 2 s"), err
    assert lines[-2].startswith('{"summary"') and json.loads(lines[-2])["summary"]["chirps"] > 0
