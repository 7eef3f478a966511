"""Per-chirp cost of the two deployed models side by side, in one run: the ONNX call alone and the
whole per-chirp path (frame -> FFT features -> Alg. 2 reference -> model -> detection -> force,
:meth:`sonicskin.runtime.SkinStream.frame`, what the live loop calls once per chirp).  The two
models are timed interleaved, chirp by chirp, so they share the machine's load.  Prints figures;
not a test.

    python benchmarks/bench_models.py [--artifact DIR] [--data DATASET] [--chirps 500]

Without ``--artifact`` it simulates the moving scenario (seed 0, cached under ``data/seeds``) and
trains and exports both models on its first session, as ``sonicskin compare --scenario`` does.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from sonicskin.dataset import Dataset
from sonicskin.runtime import SkinRuntime


def _stats(x: np.ndarray) -> str:
    return f"median {np.median(x) * 1e6:7.0f} us  p99 {np.percentile(x, 99) * 1e6:7.0f} us"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--artifact", help="artifact with net.onnx and svm.onnx (default: train one on simulated data)")
    ap.add_argument("--data", help="dataset to take the chirps from (default: the artifact's)")
    ap.add_argument("--chirps", type=int, default=500, help="timed chirps per model")
    a = ap.parse_args()
    if a.artifact:
        art = Path(a.artifact)
    else:
        from sonicskin.seeds import _one_seed, scenario_dataset

        ds = scenario_dataset("moving", 0, "data/seeds")
        art = Path("reports/bench-models/artifact")
        if not (art / "skin.json").is_file():
            _one_seed("moving", ds, [0], art, epochs=None, log=print)
        a.data = a.data or str(ds.root)
    import json

    meta = json.loads((art / "skin.json").read_text())
    ds = Dataset(a.data or meta["training"]["data"])
    test = meta["training"]["split"]["test"] or ds.sessions[-1:]
    frames, lab = ds.read_session(test[0])
    t_s = lab["t_s"]
    rts = {k: SkinRuntime(art, k) for k in ("net", "svm") if k in meta["models"]}
    streams = {k: rt.stream() for k, rt in rts.items()}
    beta = next(iter(streams.values())).reference.beta
    for st in streams.values():  # boot calibration on the first beta chirps (not timed)
        for i in range(beta):
            st.frame(frames[i], t_s[i])
    rows = np.arange(beta, len(frames))
    inputs = {k: st.reference.inputs(np.stack([st.rt.band_features(frames[r:r + 1])[0][st.bins] for r in rows[:64]]))
              for k, st in streams.items()}
    n, warm = a.chirps, 30
    path = {k: np.empty(n) for k in rts}
    onnx = {k: np.empty(n) for k in rts}
    for i in range(-warm, n):
        r = rows[i % rows.size]
        for k, st in streams.items():
            t0 = time.perf_counter()
            st.frame(frames[r], t_s[r])
            t1 = time.perf_counter()
            rts[k].run(inputs[k][i % 64][None])
            t2 = time.perf_counter()
            if i >= 0:
                path[k][i], onnx[k][i] = t1 - t0, t2 - t1
    period_ms = ds.rig.period_s * 1e3
    print(f"artifact {art}; {n} chirps of {ds.root.name}/{test[0]} per model, interleaved; "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, onnxruntime 1 thread; chirp period {period_ms:.1f} ms")
    for k in rts:
        print(f"  {k:3s}  ONNX call        {_stats(onnx[k])}   ({(art / rts[k].m['file']).stat().st_size / 1e3:.0f} kB)")
        print(f"  {k:3s}  whole per chirp  {_stats(path[k])}   (frame -> features -> reference -> model -> detection -> force)")
    if set(rts) == {"net", "svm"}:
        from sonicskin.metrics import speed_ratio

        line = (f"  the network's ONNX call is {speed_ratio(np.median(onnx['net']), np.median(onnx['svm']))} than the SVM's, "
                f"its whole per-chirp path {speed_ratio(np.median(path['net']), np.median(path['svm']))}")
        print(line.replace("as fast than", "as fast as"))


if __name__ == "__main__":
    main()
