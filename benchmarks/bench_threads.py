"""Training time against the thread setting, at load 0 and next to a competing load (issue 20).

Trains the network (``training.quick.fit_net``, the code ``sonicskin reproduce``/``compare --scenario``
use) on a synthetic one-shot session (31 locations, 300 OSPA inputs, 3,000 chirps) for a few epochs with
``SONICSKIN_THREADS`` = 1, the default (half the cores) and every core, each alone and again while
``--load`` busy processes (pure-Python loops, like another job on a shared robot computer) run beside it.
Each configuration runs in a fresh process, so torch, OpenMP and BLAS see only that setting.

    python benchmarks/bench_threads.py               # prints one line per configuration, then the ratios
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import subprocess
import sys
import time

CHILD = r"""
import json, sys, time
import numpy as np
from sonicskin import threads
threads.configure()
from sonicskin.training.quick import fit_net
import torch
rng = np.random.default_rng(0)
n, d, k = 3000, 300, 31
cls = rng.integers(0, k, n)
X = (rng.normal(size=(k, d))[cls] + rng.normal(size=(n, d))).astype(np.float32)
force = rng.uniform(0.5, 8, n).astype(np.float32)
t0 = time.perf_counter()
fit_net(X, cls, force, n_locations=k, epochs=int(sys.argv[1]), kernel=False)
print(json.dumps({"s": time.perf_counter() - t0, "torch_threads": torch.get_num_threads()}))
"""


def _busy(stop):
    x = 0
    while not stop.is_set():
        x += 1


def run(threads: int | None, epochs: int) -> dict:
    env = dict(os.environ)
    for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "SONICSKIN_THREADS"):
        env.pop(v, None)
    if threads is not None:
        env["SONICSKIN_THREADS"] = str(threads)
    r = subprocess.run([sys.executable, "-c", CHILD, str(epochs)], env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    from sonicskin.threads import default_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--load", type=int, default=os.cpu_count() or 2, help="busy processes beside training (default: one per core)")
    a = ap.parse_args(argv)
    cores = os.cpu_count() or 1
    settings = sorted({1, default_threads(), cores})
    res = {}
    for load in (0, a.load):
        stop = mp.Event()
        procs = [mp.Process(target=_busy, args=(stop,), daemon=True) for _ in range(load)]
        for p in procs:
            p.start()
        time.sleep(0.5 if load else 0)
        try:
            for n in settings:
                r = run(n, a.epochs)
                res[(n, load)] = r["s"]
                print(f"threads {n} ({'default' if n == default_threads() else 'every core' if n == cores else 'one'}), "
                      f"{load} busy processes beside: {a.epochs} epochs in {r['s']:.1f} s (torch threads {r['torch_threads']})",
                      flush=True)
        finally:
            stop.set()
            for p in procs:
                p.join()
    d = default_threads()
    if cores != d:
        print(f"under load, every core ({cores}) takes {res[(cores, a.load)] / res[(d, a.load)]:.1f}x the default's ({d}) time; "
              f"alone, {res[(cores, 0)] / res[(d, 0)]:.1f}x")
    print(f"the default ({d} threads) under load takes {res[(d, a.load)] / res[(d, 0)]:.1f}x its time alone")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
