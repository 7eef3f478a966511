"""Per-chirp cost of frame -> features -> SVM decision, batched featurisation, and the simulator.

Prints figures; not a test.  Run: ``python benchmarks/bench_pipeline.py`` (one core: it sets
OMP_NUM_THREADS=1 before numpy loads unless the variable is already set).

The simulator's figure is chirps per CPU-second of ``sonicskin simulate --scenario moving`` (5,481 chirps,
FLAC writing included), run as its own process and measured like ``/usr/bin/time`` does (user + system
time of the child, imports included): the issue's measure, independent of how busy the machine is with
other work.  It is the median of three runs, each printed (the system time of identical runs varies by
about 1 CPU-s here).  A budget line then times, in one more run, the parts the target cannot shrink.
Featurisation is chirps per second per core, batched.  Each figure is printed with its
target (issue 18: >= 1,000 chirps per CPU-second, >= 10,000 chirps/s per core) and whether it is met.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from sonicskin.dsp import log_magnitude_db  # noqa: E402
from sonicskin.kinds.closed import score_entry  # noqa: E402
from sonicskin.kinds.svm import SVMHead, fit_pipeline, ovo_decision, ovr_scores_from_ovo  # noqa: E402
from sonicskin.ospa import OSPA  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.sim import Scenario, Simulator, build_timeline  # noqa: E402


def timeit(fn, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter(); fn(); ts.append(time.perf_counter() - t)
    return np.array(ts)


SIM_TARGET = 1000  # chirps per CPU-second, FLAC included
FEAT_TARGET = 10000  # chirps/s per core, batched


def met(value: float, target: float) -> str:
    return f"target >= {target:,}: {'met' if value >= target else 'NOT met'}"


def _simulate_once() -> tuple[int, float, float, float]:
    """One ``sonicskin simulate --scenario moving`` child: chirps, user and system CPU-s, wall s."""
    with tempfile.TemporaryDirectory() as d:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "sonicskin", "simulate", "--scenario", "moving", "--out",
                            os.path.join(d, "moving")], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if r.returncode:
            raise SystemExit(f"simulate failed: {r.stderr.strip()[-500:]}")
        chirps = sum(json.loads(p.read_text())["n_chirps"] for p in Path(d, "moving").glob("*/session.json"))
    return chirps, after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime, wall


def simulate_moving(runs: int = 3) -> int:
    """``sonicskin simulate --scenario moving`` as a child process, FLAC included; chirps per CPU-second of the
    median of ``runs`` runs (the system time of identical runs varies by 1 CPU-s here; every run is printed)."""
    done = sorted((_simulate_once() for _ in range(runs)), key=lambda r: r[1] + r[2])
    chirps, user, sys_, wall = done[len(done) // 2]
    rate = chirps / (user + sys_)
    every = ", ".join(f"{u + s_:.1f}" for _, u, s_, _ in done)
    print(f"simulator: {chirps} chirps of the moving scenario in {user + sys_:.1f} CPU-s ({user:.1f} user + {sys_:.1f} sys, "
          f"{wall:.1f} s wall; the median of {runs} runs: {every} CPU-s): {rate:.0f} chirps per CPU-second, "
          f"FLAC writing and imports included; {met(rate, SIM_TARGET)}")
    return chirps


# The same command, instrumented: CPU time (of the calling thread, user + system) of the parts the issue cannot
# shrink without another file writer, fewer modes or another random stream, and of the work any simulator that
# writes this dataset does (inverse FFTs, the files' bytes to disk, their hashes).  Printed as JSON by the child.
_BUDGET_CHILD = r"""
import json, resource, sys, time
t_imp = time.process_time()
import scipy.fft
import soundfile
import sonicskin.cli
from sonicskin import dataset
from sonicskin.sim import channel, noise
imports = time.process_time() - t_imp
cpu = {}  # label -> CPU-s, in the order timed
def timed(obj, name, key):
    f = getattr(obj, name)
    cpu[key] = 0.0
    def w(*a, **k):
        t = time.thread_time()
        try:
            return f(*a, **k)
        finally:
            cpu[key] += time.thread_time() - t
    setattr(obj, name, w)
timed(soundfile, "write", "FLAC encoding (libsndfile, level 0, its MD5 included)")
timed(channel.ChannelModel, "_project", "the contact Green's functions' GEMM")
timed(noise.NoiseDraws, "__init__", "the noise's random draws (two Gaussian fields, PWM and gear tones)")
timed(scipy.fft, "irfft", "the inverse FFTs (float32)")
timed(dataset, "_atomic_write_bytes", "writing the parts' bytes (page cache, fsync)")
timed(dataset, "_sha", "their SHA-256")
sonicskin.cli.main(["simulate", "--scenario", "moving", "--out", sys.argv[1]])
r = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"total": r.ru_utime + r.ru_stime, "parts": {"imports (interpreter start excluded)": imports, **cpu}}))
"""


def simulator_budget(chirps: int) -> None:
    """Where the CPU of ``simulate --scenario moving`` goes, against the target's budget (one instrumented run)."""
    with tempfile.TemporaryDirectory() as d:
        r = subprocess.run([sys.executable, "-c", _BUDGET_CHILD, os.path.join(d, "moving")], capture_output=True,
                           text=True)
        if r.returncode:
            raise SystemExit(f"simulate (instrumented) failed: {r.stderr.strip()[-500:]}")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    parts, total = out["parts"], out["total"]
    fixed = sum(parts.values())
    print(f"simulator budget: the target allows {chirps / SIM_TARGET:.2f} CPU-s for these {chirps} chirps; "
          f"an instrumented run took {total:.1f} CPU-s, of which " +
          ", ".join(f"{k} {v:.2f}" for k, v in parts.items()) +
          f" (together {fixed:.2f} CPU-s, {fixed / (chirps / SIM_TARGET):.0%} of the budget) and "
          f"{total - fixed:.2f} CPU-s all the rest (Woodbury solves, noise spectra, the channel per chirp, "
          f"quantisation, labels, the kernel's page faults)")


def featurise(rig: Rig, frames: np.ndarray) -> None:
    """Batched featurisation, best of 3 passes over the frames, CPU time of this (one-core) process."""
    best = np.inf
    for _ in range(3):
        c0 = time.process_time()
        log_magnitude_db(frames, rig)
        best = min(best, time.process_time() - c0)
    rate = len(frames) / best
    print(f"batched featurisation: {rate:.0f} chirps/s per core ({best / len(frames) * 1e6:.0f} us/chirp, "
          f"float32, {rig.n_band} band bins of {rig.n_chirp}-sample chirps); {met(rate, FEAT_TARGET)}")


def main() -> None:
    rig = Rig.load("jaco")
    simulator_budget(simulate_moving())
    sc = Scenario(sessions=2, motion={"enabled": True})
    t0 = time.perf_counter()
    sim = Simulator(sc, rig)
    setup = time.perf_counter() - t0
    tl = build_timeline(sc, rig)
    s0, s1 = tl.select(tl.session == 0), tl.select(tl.session == 1)
    t0 = time.perf_counter()
    f0 = sim.render(s0)
    render = time.perf_counter() - t0
    f1 = sim.render(s1)
    print(f"simulator render only: setup {setup:.2f} s, {len(s0) / render:.0f} chirps/s wall of received audio (moving robot)")

    featurise(rig, np.concatenate([f0, f1]))
    X0 = log_magnitude_db(f0, rig)
    X1 = log_magnitude_db(f1, rig)

    quiet = (s0.location < 0) & (s0.moving == 0)
    layout = sc.make_layout()
    touch = s0.location >= 0
    bins = OSPA(gamma=300, allowed=rig.allowed_mask).fit(X0[touch], X_moving=X0[(s0.location < 0) & (s0.moving > 0)]).selected_
    cls = np.where(touch, layout.index_of(np.where(touch, s0.location, layout.ids[0])), len(layout))
    pipe = fit_pipeline(X0[:, bins], cls, len(layout))
    params = score_entry(ovr_scores_from_ovo(ovo_decision(pipe, X0[:, bins]), len(layout)), X0[:, bins], cls, s0.force_n, quiet,
                         n_locations=len(layout), location_ids=layout.ids, detector="paper")
    head = SVMHead(params, layout)
    frame = f1[100:101]
    feat = timeit(lambda: log_magnitude_db(frame, rig), 200)
    x = X1[100:101, bins]
    dec = timeit(lambda: pipe.decision_function(x), 200)

    def decide(fr):
        z = log_magnitude_db(fr, rig)[:, bins]
        return head.decide([None, pipe.decision_function(z)], z)

    full = timeit(lambda: decide(frame), 200)
    period_ms = rig.period_s * 1e3
    for name, t in (("frame -> features", feat), ("features -> SVM scores", dec), ("frame -> location + force", full)):
        print(f"per chirp {name:26s} median {np.median(t) * 1e3:6.3f} ms  p99 {np.percentile(t, 99) * 1e3:6.3f} ms"
              f"  ({np.median(t) * 1e3 / period_ms:.2%} of the {period_ms:.1f} ms chirp period)")


if __name__ == "__main__":
    main()
