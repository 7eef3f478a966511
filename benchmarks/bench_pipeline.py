"""Per-chirp cost of frame -> features -> SVM decision, batched featurisation, and the simulator.

Prints figures; not a test.  Run: ``python benchmarks/bench_pipeline.py`` (set OMP_NUM_THREADS=1
for one core).
"""

from __future__ import annotations

import time

import numpy as np

from sonicskin.dsp import log_magnitude_db
from sonicskin.rig import Rig
from sonicskin.sim import Scenario, Simulator, build_timeline
from sonicskin.skin import SkinSVM


def timeit(fn, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter(); fn(); ts.append(time.perf_counter() - t)
    return np.array(ts)


def main() -> None:
    rig = Rig.load("jaco")
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
    print(f"simulator: setup {setup:.2f} s, {len(s0) / render:.0f} chirps/s of received audio (moving robot)")

    t0 = time.perf_counter()
    X0 = log_magnitude_db(f0, rig)
    batch = time.perf_counter() - t0
    X1 = log_magnitude_db(f1, rig)
    print(f"batched featurisation: {len(f0) / batch:.0f} chirps/s ({batch / len(f0) * 1e6:.0f} us/chirp)")

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
