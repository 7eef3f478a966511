"""Per-chirp cost of frame -> features -> SVM decision, batched featurisation, and the simulator.

Prints figures; not a test.  Run: ``python benchmarks/bench_pipeline.py`` (one core: it sets
OMP_NUM_THREADS=1 before numpy loads unless the variable is already set).

The simulator's figure is chirps per CPU-second of ``simulate --scenario moving`` (5,481 chirps,
FLAC writing included, user + system time of the process): the issue's measure, independent of how
busy the machine is with other work.  Featurisation is chirps per second per core, batched.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import resource  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from sonicskin.dsp import log_magnitude_db  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.sim import Scenario, Simulator, build_timeline  # noqa: E402
from sonicskin.sim.generate import simulate_dataset  # noqa: E402
from sonicskin.skin import SkinSVM  # noqa: E402


def timeit(fn, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter(); fn(); ts.append(time.perf_counter() - t)
    return np.array(ts)


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def simulate_moving(rig: Rig) -> None:
    """``sonicskin simulate --scenario moving`` in-process, FLAC included; chirps per CPU-second."""
    sc = Scenario.load("moving")
    with tempfile.TemporaryDirectory() as d:
        c0, t0 = cpu_s(), time.perf_counter()
        fig = simulate_dataset(sc, rig, os.path.join(d, "moving"), progress=False, log=lambda *_: None)
        cpu, wall = cpu_s() - c0, time.perf_counter() - t0
    print(f"simulator: {fig['chirps']} chirps of the moving scenario in {cpu:.1f} CPU-s ({wall:.1f} s wall): "
          f"{fig['chirps'] / cpu:.0f} chirps per CPU-second, FLAC writing included")


def featurise(rig: Rig, frames: np.ndarray) -> None:
    """Batched featurisation, best of 3 passes over the frames, CPU time of this (one-core) process."""
    best = np.inf
    for _ in range(3):
        c0 = time.process_time()
        log_magnitude_db(frames, rig)
        best = min(best, time.process_time() - c0)
    print(f"batched featurisation: {len(frames) / best:.0f} chirps/s per core ({best / len(frames) * 1e6:.0f} us/chirp, "
          f"float32, {rig.n_band} band bins of {rig.n_chirp}-sample chirps)")


def main() -> None:
    rig = Rig.load("jaco")
    simulate_moving(rig)
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
    model = SkinSVM(rig, sc.make_layout()).fit(X0, s0.location, s0.force_n, quiet=quiet,
                                                 X_moving=X0[(s0.location < 0) & (s0.moving > 0)])
    frame = f1[100:101]
    feat = timeit(lambda: log_magnitude_db(frame, rig), 200)
    x = X1[100:101]
    dec = timeit(lambda: model.localizer_.decision_function(x), 200)
    full = timeit(lambda: model.predict(log_magnitude_db(frame, rig), online=False), 200)
    period_ms = rig.period_s * 1e3
    for name, t in (("frame -> features", feat), ("features -> SVM scores", dec), ("frame -> location + force", full)):
        print(f"per chirp {name:26s} median {np.median(t) * 1e3:6.3f} ms  p99 {np.percentile(t, 99) * 1e3:6.3f} ms"
              f"  ({np.median(t) * 1e3 / period_ms:.2%} of the {period_ms:.1f} ms chirp period)")


if __name__ == "__main__":
    main()
