"""Issue 37, under load: real-time scheduling (--realtime, realtime=), the queue between the audio thread and the loop
sized from the chirp period, lost audio named as stream time, latency from the block's arrival, no allocation per block
in the framer and the audio callback, and a finite simulated session that says its length."""

from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run

from sonicskin import acquire
from sonicskin.acquire import Block, realtime_thread
from sonicskin.dsp import rig_chirp
from sonicskin.live import Framer, LiveLoop, run_loops
from sonicskin.rig import Rig
from sonicskin.runtime import SkinRuntime
from sonicskin.session import open_run


def _policy() -> tuple[int, int]:
    tid = threading.get_native_id()
    return os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)


def test_realtime_thread_is_granted_then_undone_or_says_what_it_got():
    """SCHED_FIFO where permitted (root here), and the thread back to what it was after; where FIFO is refused, a
    negative nice instead, or one line that says neither was granted."""
    before = _policy()
    got, undo = realtime_thread(acquire.LOOP_PRIORITY)
    try:
        if os.geteuid() == 0:
            assert got == "SCHED_FIFO 60" and _policy()[0] == os.SCHED_FIFO
        else:
            assert got.startswith("SCHED_FIFO not permitted")
    finally:
        undo()
    assert _policy() == before


def test_realtime_thread_without_permission_says_so(monkeypatch):
    def refuse(*a):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", refuse)
    got, undo = realtime_thread(70)
    undo()
    assert got == ("SCHED_FIFO not permitted (Operation not permitted), nor a negative nice: normal priority (root or an "
                   "rtprio limit grants it)")
    calls = []
    monkeypatch.setattr(os, "setpriority", lambda *a: calls.append(a))  # nice permitted, FIFO not
    got, _ = realtime_thread(70)
    assert got == "SCHED_FIFO not permitted (Operation not permitted), nice -10 instead" and calls[0][2] == -10


def test_live_realtime_schedules_both_threads_and_says_so(cli_files, capsys):
    """--realtime: one line on stderr names what the audio thread (here the simulated device's) and the processing
    thread got, the summary carries it, and the caller's thread is as it was after the run."""
    before = _policy()
    run_ = open_run(cli_files["artifact"], scenario=cli_files["scenario"], rig=cli_files["rig"], realtime=True)
    run_.loops(emit=lambda line: None)
    capsys.readouterr()
    run_.run(duration_s=1.0)
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if ln.startswith("sonicskin: real-time scheduling: "))
    assert set(run_.granted) == {"audio", "processing"}
    assert line == (f"sonicskin: real-time scheduling: audio thread {run_.granted['audio']}; processing thread "
                    f"{run_.granted['processing']}")
    if os.geteuid() == 0:
        assert run_.granted == {"audio": "SCHED_FIFO 70", "processing": "SCHED_FIFO 60"}
    assert _policy() == before


def test_realtime_and_fast_contradict(cli_files, capsys):
    code, out, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--rig", cli_files["rig"], "--scenario",
                                  cli_files["scenario"], "--fast", "--realtime"])
    assert assert_one_line_error(code, err, "live") == (
        "sonicskin live: error: --realtime/realtime= schedules a run at the sample rate, --fast/fast= runs as fast as it "
        "goes; drop one of them") and out == ""


def test_the_queue_holds_a_stall_of_16_chirp_periods_or_2_s():
    jaco, slow = Rig.load("jaco"), Rig(n_chirp=96_000)  # 106.7 ms chirps; 0.5 s chirps
    assert acquire._QueueSource(jaco, 1024).queued_s == 2.0  # 16 x 106.7 ms = 1.7 s
    q = acquire._QueueSource(slow, 1024)
    assert q.queued_s == pytest.approx(16 * slow.period_s) and q.queue.maxsize == int(q.queued_s * slow.fs_hz / 1024)


class _Burst(acquire._QueueSource):
    """A device that delivers ``n`` blocks of the chirp train at once into a queue of ``max_queued_s``: what a loop that
    stalled sees; the blocks beyond the queue are dropped."""

    def __init__(self, rig, n, max_queued_s):
        super().__init__(rig, 1024, max_queued_s=max_queued_s)
        self.n, self.finished = n, threading.Event()

    def start(self):
        x = np.resize(rig_chirp(self.rig).astype(np.float32) * 0.1, self.n * 1024)
        x += np.random.default_rng(0).normal(0, 1e-3, x.size).astype(np.float32)
        for k in range(self.n):
            self._deliver(x[k * 1024:(k + 1) * 1024])
        self.finished.set()

    def stop(self):
        pass


def test_dropped_blocks_name_the_stream_time_they_held(cli_files, capsys):
    """A loop that fell behind: the blocks the full queue could not take are dropped, and the warning, the status line
    and the summary say which stream time is missing (the blocks after the queue's 3 s)."""
    rig = Rig.load(cli_files["rig"])
    src = _Burst(rig, 1200, max_queued_s=3.0)  # 562 blocks fit
    loop = LiveLoop(SkinRuntime(cli_files["artifact"], "svm"), src, emit=lambda line: None, status=True)
    kept = src.queue.maxsize
    with src:
        s = run_loops([loop], src, watchdog_s=None)[0]
    a, b = kept * 1024 / rig.fs_hz, 1200 * 1024 / rig.fs_hz
    assert s["dropped_blocks"] == 1200 - kept and s["lost_spans_s"] == [[round(a, 4), round(b, 4)]]
    assert s["lost_s"] == pytest.approx(b - a, abs=1e-3)
    err = capsys.readouterr().err
    assert (f"sonicskin: warning: audio lost: stream time {a:.3f}-{b:.3f} s is missing ({b - a:.3f} s in all: "
            f"{1200 - kept} blocks dropped as the loop fell behind the audio, 0 lost by the driver); --realtime, or fewer "
            f"busy programs") in err
    assert f"lost {b - a:.2f} s of stream (the last {a:.2f}-{b:.2f} s)" in loop.status_line()


def test_injected_drops_are_named_too(cli_files):
    """--drop-every (what a driver reports as lost input) keeps each lost block's span, merged when they touch."""
    src = acquire._QueueSource(Rig.load(cli_files["rig"]), 1024)
    for k in range(6):
        if k in (2, 3):
            src.overflows += 1
            src._pos += 1024
            src._lose(src._pos - 1024, src._pos)
        else:
            src._deliver(np.zeros(1024, np.float32))
    assert [list(x) for x in src.lost_spans] == [[2048, 4096]]
    assert [(b.start, b.discontinuity) for b in iter(lambda: src.read(0), None)] == [
        (0, False), (1024, False), (4096, True), (5120, False)]


def test_a_stall_shorter_than_the_queue_loses_nothing(cli_files):
    """The simulated device in real time, the loop stalled for half a second (a busy machine, a GC pause): the queue
    holds what arrived meanwhile, no block is dropped, no chirp is lost."""
    r = open_run(cli_files["artifact"], scenario=cli_files["scenario"], rig=cli_files["rig"])
    stalled = []

    def on_chirp(t_s, p):
        if not stalled and p is not None and t_s > 4.0:  # after the boot calibration (3.5 s)
            stalled.append(t_s)
            time.sleep(0.5)

    loop = LiveLoop(r.runtimes[0], r.source, emit=lambda line: None, on_chirp=on_chirp)
    with r.source:
        s = run_loops([loop], r.source, duration_s=5.5)[0]
    assert stalled and s["dropped_blocks"] == 0 and s["relocks"] == 0 and s["lost_spans_s"] == []
    assert max(loop.latencies_ms) >= 400  # the chirps that waited in the queue: their latency says so


class _SlowBoot(acquire._ProducerSource):
    """A device whose first audio takes ``boot_s`` to produce (a simulated arm rendering its first chunk of six walls)."""

    def __init__(self, rig, boot_s, seconds):
        super().__init__(rig, 1024, realtime=True)
        self.boot_s, self.n = boot_s, int(seconds * rig.fs_hz)

    def _chunks(self):
        time.sleep(self.boot_s)
        yield np.zeros(self.n, np.float32)


def test_a_slow_first_render_is_boot_time_not_stream_time_to_catch_up():
    """The stream clock starts at the first block: after a 0.6 s boot the blocks still arrive at the sample rate, not
    0.6 s of them at once (which overfilled the queue of a six-link simulated arm on a slow PC, dropping audio at 2.5 s)."""
    rig = Rig.load("jaco")
    src = _SlowBoot(rig, boot_s=0.6, seconds=0.5)
    with src:
        got = [b for b in iter(lambda: src.read(2.0), None)]
    assert sum(len(b.samples) for b in got) == src.n and src.dropped_blocks == 0
    stream_s = got[-1].start / rig.fs_hz  # how far in the stream the last block starts: 0.49 s
    assert got[-1].t - got[0].t >= 0.8 * stream_s  # paced (a burst would deliver them within milliseconds)


def test_a_real_time_simulated_device_renders_about_a_second_ahead(cli_files):
    """Each render holds the blocks back for its duration, so in real time a chunk is at most about a second of audio
    (jaco: 9 chirps, not the 64 = 6.8 s a run as fast as it goes renders at once)."""
    from sonicskin.sim import Scenario, Simulator, build_timeline

    rig, sc = Rig.load("jaco"), Scenario.load(cli_files["scenario"]).replace(sessions=1)
    sim, tl = Simulator(sc, rig), build_timeline(sc, rig)
    assert [acquire.SimulatedSource(sim, tl, realtime=rt).chunk for rt in (True, False)] == [9, 64]


def test_latency_counts_from_the_blocks_arrival(cli_files):
    """latency_ms is from the arrival of the block that completes the chirp (Block.t) to its event: time waiting in the
    queue behind a slow loop counts, not only the processing."""
    rig = Rig.load(cli_files["rig"])
    src = acquire._QueueSource(rig, 1024)
    loop = LiveLoop(SkinRuntime(cli_files["artifact"], "svm"), src, emit=lambda line: None)
    n = 1000  # 5.3 s: past the boot calibration (3.5 s)
    x = np.resize(rig_chirp(rig).astype(np.float32) * 0.1, n * 1024)
    x += np.random.default_rng(0).normal(0, 1e-3, x.size).astype(np.float32)
    t_old = time.perf_counter() - 0.25
    for k in range(n):
        loop.feed(Block(x[k * 1024:(k + 1) * 1024], k, k * 1024, False, t_old))
    assert loop.latencies_ms and min(loop.latencies_ms) >= 250


@pytest.mark.parametrize("sizes", [[1000], [1, 4095, 7, 30_000, 512]])
def test_framer_frames_any_block_sizes_in_its_preallocated_buffers(rig, sizes):
    """The framer copies each block into buffers it allocated once (a block longer than any before grows them once):
    the frames are the stream's chirps, exactly, whatever the block sizes."""
    s = rig_chirp(rig).astype(np.float32)
    L = rig.n_chirp
    stream = np.tile(s, 12)[777:]
    f = Framer(s)
    got, i, k = [], 0, 0
    while i + sizes[k % len(sizes)] <= stream.size:
        n = sizes[k % len(sizes)]
        got += f.push(stream[i:i + n], i)
        i, k = i + n, k + 1
    assert len(got) >= 10 and f.relocks == 0
    for start, frame in got:
        assert (start + 777) % L == 0
        np.testing.assert_array_equal(frame, s)
    bufs = [id(b) for b in f._bufs]
    f.push(stream[:1000], i + 5, discontinuity=True)
    assert [id(b) for b in f._bufs] == bufs or max(sizes) > 2 * L


def test_the_audio_callback_plays_the_period_by_slices(rig):
    """The duplex callback's output is the links' chirp period, back to back, from a precomputed buffer (a slice per
    callback, no index arrays), whatever the callback sizes."""
    src = acquire.SoundDeviceSource.__new__(acquire.SoundDeviceSource)
    acquire._QueueSource.__init__(src, rig, 1024, max_queued_s=60)
    links = [acquire.Link(tx=1, rx=0)]
    period = rig.n_chirp
    tx = np.zeros((period, 2), np.float32)
    tx[:, 1] = rig_chirp(rig)
    src._tx, src._period, src._tx_pos, src._rx, src.links = tx[np.arange(period + 1024) % period], period, 0, [0], links

    class Status:
        input_overflow = output_underflow = False

    out = []
    for frames in [1024] * 30 + [3000, 1024]:
        o = np.empty((frames, 2), np.float32)
        src._callback(np.zeros((frames, 1), np.float32), o, frames, None, Status())
        out.append(o)
    out = np.concatenate(out)
    np.testing.assert_array_equal(out, tx[np.arange(len(out)) % period])


def test_a_simulated_session_lasts_the_duration_asked_for(cli_files, capsys):
    """--duration longer than one scripted pass over the markers: the person presses them again until the run has
    lasted as long as asked (it ended early with the session, which cut the 60 s load benchmark to 47 s)."""
    from sonicskin.rig import Rig
    from sonicskin.session import live_scenario
    from sonicskin.sim import Scenario, build_timeline

    rig, sc = Rig.load(cli_files["rig"]), Scenario.load(cli_files["scenario"])
    once = len(build_timeline(live_scenario(sc), rig)) / rig.chirps_per_s
    assert live_scenario(sc, rig, once / 2) == live_scenario(sc)  # long enough already: the same session
    longer = live_scenario(sc, rig, 2.5 * once)
    assert len(build_timeline(longer, rig)) / rig.chirps_per_s >= 2.5 * once
    code, out, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--rig", cli_files["rig"], "--scenario",
                                  cli_files["scenario"], "--fast", "--duration", f"{2.5 * once:.1f}", "--no-status"])
    assert code == 0 and "the simulated session is" not in err
    import json
    summary = json.loads(err.strip().splitlines()[-1])["summary"]
    assert math.isclose(summary["stream_s"], round(2.5 * once, 1), abs_tol=0.2)
    late = [e for e in map(json.loads, out.splitlines()) if e["kind"] == "touch" and e["t_s"] > 1.2 * once]
    assert len(late) >= len(sc.make_layout())  # the second pass and after: presses, not rest


# -- issue 37 finding 8: options an arm would ignore are refused ------------------------------------------------------
def test_live_links_with_an_artifact_is_refused(capsys):
    code, out, err = run(capsys, ["live", "--links", "arm6", "--artifact", "artifacts/x", "--fast"])
    assert assert_one_line_error(code, err, "live") == (
        "sonicskin live: error: --artifact artifacts/x with --links arm6: an arm's links carry their artifacts (its arm "
        "file's `artifact:`, or --link-artifact DIR once per link); drop --artifact")


@pytest.mark.parametrize("kw", [{"rx": 5}, {"tx": 1}, {"scenario": "moving"}])
def test_a_listener_on_an_arm_refuses_what_each_link_takes_from_the_arm_file(kw):
    from sonicskin.api import Listener
    from sonicskin.errors import SonicskinError
    from sonicskin.rig import config_dir

    arm = config_dir() / "arms" / "arm6.yaml"
    with pytest.raises(SonicskinError) as e:
        Listener(arm, **kw)
    assert str(e.value) == (f"{arm} is an arm: each link takes its channels and its simulated wall from the arm file (tx:, "
                            f"rx:, scenario:); drop --tx/--rx/--scenario (tx=, rx=, scenario=)")
