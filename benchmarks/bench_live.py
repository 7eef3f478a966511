"""Live consumer cost per chirp (median, p99) for the SVM and the network, CPU share in real time,
and how many links (TX/RX pairs) one core sustains.  Prints figures; not a test.

    python benchmarks/bench_live.py [--artifact DIR]   # default: train/export on a small simulated set
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from sonicskin.acquire import SimulatedSource
from sonicskin.live import LiveLoop
from sonicskin.rig import Rig
from sonicskin.runtime import SkinRuntime
from sonicskin.sim import Scenario, Simulator, build_timeline


def run(artifact: Path, model: str, rig: Rig, realtime: bool, seconds: float) -> dict:
    sc = Scenario.load("moving").replace(seed=99, sessions=1)
    tl = build_timeline(sc, rig)
    tl = tl.select(np.arange(len(tl)) < int(seconds * rig.chirps_per_s))
    src = SimulatedSource(Simulator(sc, rig), tl, realtime=realtime)
    loop = LiveLoop(SkinRuntime(artifact, model), src, emit=lambda _: None)
    with src:
        return loop.run()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--artifact", default="runs/compare-moving/artifact",
                    help="artifact with net and svm (sonicskin compare --data data/moving makes one)")
    ap.add_argument("--seconds", type=float, default=20.0)
    a = ap.parse_args()
    rig = Rig.load("jaco")
    art = Path(a.artifact)
    if not (art / "skin.json").is_file():
        raise SystemExit(f"{art} is missing: run `sonicskin simulate --scenario moving --out data/moving` and "
                         f"`sonicskin compare --data data/moving` first, or pass --artifact")
    period_ms = rig.period_s * 1e3
    print(f"threads: OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; chirp period {period_ms:.1f} ms")
    for model in ("svm", "net"):
        s = run(art, model, rig, realtime=False, seconds=a.seconds)
        per_link_ms = s["latency_ms_median"]
        print(f"{model}: per chirp median {s['latency_ms_median']:.2f} ms, p99 {s['latency_ms_p99']:.2f} ms "
              f"({s['latency_ms_p99'] / period_ms:.1%} of the period) over {s['chirps']} chirps; "
              f"one core sustains ~{int(period_ms // per_link_ms)} links in real time")
        t0 = time.perf_counter()
        r = run(art, model, rig, realtime=True, seconds=min(a.seconds, 10.0))
        print(f"{model}: real time, {r['chirps']} chirps in {time.perf_counter() - t0:.1f} s, CPU share of this process "
              f"{r['cpu_share']:.1%} (simulated device included), overflows {r['overflows']}, relocks {r['relocks']}")


if __name__ == "__main__":
    main()
