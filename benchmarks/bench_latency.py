"""Press-to-event latency of the live loop, end to end, per rig (issue 17).

For each rig: simulate a one-shot training session (scenario ``stationary`` or ``--scenario``) on that
rig, fit the deployable SVM artifact (or use ``--artifact``), then run :class:`sonicskin.live.LiveLoop`
on a scripted stream of presses on the simulated link and print

    press-to-event latency p50 X ms p95 Y ms

measured from the first sample of each press at >= 0.5 N to the emitted touch event, processing included,
and the false-touch rate (hands-off chirps reported as touch) over the same run.

How a press starts mid-frame: the simulator renders one channel state per chirp period.  A real press
starts at any sample, so the frame that holds the onset is only partly touched: here the onset falls at a
uniformly random sample ``u`` of the first chirp whose force is >= 0.5 N, and that frame is spliced from
the previous chirp's state (samples ``< u``) and the pressed state (``>= u``).  The latency of one press is

    (end of the audio block that completed the deciding frame - onset sample) / fs + processing time,

i.e. the audio is delivered in blocks of ``--blocksize`` samples, as a sound card does, and the
processing time (framing, FFT, features, Alg. 2, ONNX model, detection) is measured with
``time.perf_counter`` on this machine.  The driver's own input latency (a real interface adds a few
ms; JACK adds its period) is not included; ``--jack`` runs the same stream through a JACK loopback in
real time and measures wall-clock latency, which does include it.

    python benchmarks/bench_latency.py                       # jaco (the paper's rig) and fast
    python benchmarks/bench_latency.py --rigs fast --presses 60 --model net --artifact artifacts/fast
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sonicskin.fit import build_svm_artifact  # noqa: E402
from sonicskin.live import LiveLoop  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.runtime import SkinRuntime  # noqa: E402
from sonicskin.sim.generate import simulate_dataset  # noqa: E402
from sonicskin.sim.scenario import Scenario, build_timeline  # noqa: E402
from sonicskin.sim.simulator import Simulator  # noqa: E402

MIN_FORCE_N = 0.5


def render_frames(sim: Simulator, timeline, chunk: int = 256) -> np.ndarray:
    """Every chirp frame of ``timeline`` (n, n_chirp), rendered ``chunk`` chirps at a time (bounded memory)."""
    return np.concatenate([sim.render(timeline.select(np.arange(a, min(a + chunk, len(timeline)))))
                           for a in range(0, len(timeline), chunk)])


class SplicedPresses:
    """A simulated stream whose presses start at a random sample inside a chirp period.

    Renders the timeline with :meth:`Simulator.render`, splices each press's onset frame, and hands the
    stream out in blocks (:meth:`read`, like :mod:`sonicskin.acquire`'s sources, as fast as it is read).
    """

    def __init__(self, sim: Simulator, timeline, *, blocksize: int, rng: np.random.Generator, offset: int = 1234):
        self.rig = sim.rig
        L = self.rig.n_chirp
        frames = render_frames(sim, timeline)
        f = timeline.force_n
        onsets, releases = [], []
        for ev in np.unique(timeline.event[timeline.event >= 0]):
            idx = np.flatnonzero(timeline.event == ev)
            firm = idx[f[idx] >= MIN_FORCE_N]
            if len(firm) == 0:
                continue
            k0 = int(firm[0])
            u = int(rng.integers(0, L))
            if k0 > 0:  # the onset frame: the previous state up to sample u, the pressed state after
                frames[k0, :u] = frames[k0 - 1, :u]
            onsets.append(k0 * L + u)
            releases.append((int(idx[-1]) + 1) * L)
        self.offset = int(offset) % L  # the stream starts mid-chirp, unknown to the consumer
        self.audio = frames.ravel()[self.offset:]
        self.onsets = np.asarray(onsets) - self.offset
        self.releases = np.asarray(releases) - self.offset
        self.blocksize = int(blocksize)
        self.pos = 0
        self.index = 0

    def read(self, timeout: float = 1.0):
        from sonicskin.acquire import Block

        if self.pos >= len(self.audio):
            return None
        b = Block(self.audio[self.pos:self.pos + self.blocksize], self.index, self.pos, False)
        self.pos += len(b.samples)
        self.index += 1
        return b

    def counters(self) -> dict:
        return {"overflows": 0, "dropped_blocks": 0}


def train_artifact(rig: Rig, scenario: str, work: Path, *, seed: int, log) -> Path:
    sc = Scenario.load(scenario).replace(seed=seed, sessions=1)
    data, art = work / f"train-{rig.name}", work / f"art-{rig.name}"
    t0 = time.perf_counter()
    simulate_dataset(sc, rig, data, mode="overwrite", progress=False, log=lambda *_: None)
    build_svm_artifact(data, art, n_bins=300, progress=False, log=lambda *_: None)
    log(f"  {rig.name}: simulated {scenario} (1 session, seed {seed}) and fitted the SVM artifact in {time.perf_counter() - t0:.0f} s")
    return art


def run_rig(rig: Rig, art: Path, model: str, *, scenario: str, seed: int, presses: int, blocksize: int, log) -> dict:
    """Scripted presses through the live loop; per-press latency and the false-touch rate."""
    rt = SkinRuntime(art, model, rig=rig)
    n_loc = len(rt.layout)
    sc = Scenario.load(scenario).replace(seed=seed + 1000, sessions=1, repeats=1, order="random", moving_s=0.0,
                                         train_repeats=None, touch_s=0.6, gap_s=0.6)
    sim = Simulator(sc, rig)
    tl = build_timeline(sc, rig)
    tl = tl.select(tl.session == 0)
    # Keep the calibration, then `presses` presses (their gaps included).
    ev_ids = np.unique(tl.event[tl.event >= 0])[:presses]
    last = np.flatnonzero(np.isin(tl.event, ev_ids))[-1]
    tl = tl.select(np.arange(min(len(tl), last + 1 + rig.seconds_to_chirps(0.6))))
    src = SplicedPresses(sim, tl, blocksize=blocksize, rng=np.random.default_rng(seed))
    events: list = []
    loop = LiveLoop(rt, src, emit=lambda line: None)
    decisions: list[tuple[float, bool]] = []
    loop.on_chirp = lambda t_s, p: decisions.append((t_s, bool(p.touch[0]))) if p is not None else None
    t0 = time.perf_counter()
    while (b := src.read()) is not None:
        n_before = len(loop.events)
        loop.feed(b)
        block_end = b.start + len(b.samples)
        events += [(e, block_end) for e in loop.events[n_before:]]
    wall = time.perf_counter() - t0
    L, fs = rig.n_chirp, rig.fs_hz
    lat, audio_lat, missed = [], [], 0
    touches = [(e, end) for e, end in events if e.kind == "touch"]
    for on, off in zip(src.onsets, src.releases):
        # The first touch event from a frame that ends after the onset and starts before the release.
        hit = next(((e, end) for e, end in touches if e.t_s * fs + L > on and e.t_s * fs < off), None)
        if hit is None:
            missed += 1
            continue
        e, end = hit
        audio_lat.append((end - on) / fs * 1e3)  # the audio part: from the onset to the end of the deciding block
        lat.append(audio_lat[-1] + e.latency_ms)  # plus this machine's processing time (wall clock)
    # False touches: chirps decided as touch whose frame lies entirely in hands-off time (one frame of slack after a release).
    starts = np.array([t for t, _ in decisions]) * fs
    flags = np.array([d for _, d in decisions], bool)
    pressed = np.zeros(len(starts), bool)
    for on, off in zip(src.onsets, src.releases):
        pressed |= (starts + L > on - L) & (starts < off + L)
    hands_off = ~pressed
    lat = np.asarray(lat)
    return {"rig": rig.name, "period_ms": L / fs * 1e3, "model": model, "n_locations": n_loc, "presses": len(src.onsets),
            "missed": missed, "p50_ms": float(np.percentile(lat, 50)) if lat.size else np.nan,
            "p95_ms": float(np.percentile(lat, 95)) if lat.size else np.nan,
            "max_ms": float(lat.max()) if lat.size else np.nan,
            "audio_max_ms": float(max(audio_lat)) if audio_lat else np.nan,
            "false_touch_rate": float(flags[hands_off].mean()) if hands_off.any() else np.nan,
            "hands_off_chirps": int(hands_off.sum()), "blocksize": blocksize,
            "processing_ms_median": float(np.median(loop.latencies_ms)) if loop.latencies_ms else np.nan,
            "stream_s": len(src.audio) / fs, "wall_s": wall}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["jaco", "fast"], help="rig names or YAML paths (default: jaco fast)")
    ap.add_argument("--scenario", default="stationary", help="scenario for training and the scripted presses (default: stationary)")
    ap.add_argument("--model", default="svm", choices=("svm", "net"), help="model of the artifact (default: svm)")
    ap.add_argument("--artifact", nargs="+", help="one artifact per rig (default: fit an SVM artifact per rig)")
    ap.add_argument("--presses", type=int, default=40, help="scripted presses per rig (default: 40)")
    ap.add_argument("--blocksize", type=int, default=256, help="audio block size in samples (default: 256 = 1.3 ms at 192 kHz)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", help="folder for the simulated data and artifacts (default: a temporary folder)")
    a = ap.parse_args(argv)
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work or tmp)
        for i, name in enumerate(a.rigs):
            rig = Rig.load(name)
            art = Path(a.artifact[i]) if a.artifact else train_artifact(rig, a.scenario, work, seed=a.seed, log=log)
            r = run_rig(rig, art, a.model, scenario=a.scenario, seed=a.seed, presses=a.presses, blocksize=a.blocksize, log=log)
            print(f"{name:>8} ({r['period_ms']:.1f} ms chirp, {a.model}, blocks of {a.blocksize}): press-to-event latency "
                  f"p50 {r['p50_ms']:.1f} ms p95 {r['p95_ms']:.1f} ms (max {r['max_ms']:.1f} ms; {r['presses'] - r['missed']}/"
                  f"{r['presses']} presses detected); false touches {r['false_touch_rate']:.2%} of {r['hands_off_chirps']} "
                  f"hands-off chirps; processing {r['processing_ms_median']:.2f} ms per chirp (median)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
