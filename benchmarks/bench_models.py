"""Per-chirp cost of the two deployed models side by side, in one run: the ONNX call alone and the
whole per-chirp path (frame -> FFT features -> Alg. 2 reference -> model -> detection -> force,
:meth:`sonicskin.runtime.SkinStream.frame`, what the live loop calls once per chirp).  The two
models are timed interleaved, chirp by chirp, so they share the machine's load.  Prints figures;
not a test.

    python benchmarks/bench_models.py [--artifact DIR] [--data DATASET] [--chirps 500] [--small]

Without ``--artifact`` it simulates the moving scenario (seed 0, cached under ``data/seeds``) and
trains and exports both models on its first session, as ``sonicskin compare --scenario`` does
(:func:`build_artifact`, also used by ``bench_live.py``).  ``--small``: a 4096-sample chirp, short
presses and a 5-epoch network in a temporary folder (seconds; for the tests).

Stdout: a markdown table (model | ONNX call median, p99 | whole per-chirp path median, p99 | file
size) and one sentence with the speed ratios; everything else goes to stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sonicskin.dataset import Dataset
from sonicskin.dsp import log_magnitude_db
from sonicskin.runtime import SkinRuntime


def _log(*msg) -> None:
    print(*msg, file=sys.stderr, flush=True)


SMALL = {"n_chirp": 4096, "overrides": {"sessions": 2, "train_repeats": 1, "touch_s": 0.6, "gap_s": 0.2, "moving_s": 2.0},
         "epochs": 5}


def build_artifact(work: Path, *, small: bool = False) -> tuple[Path, Dataset]:
    """Both models (SVM and network, ONNX) trained on the first session of the simulated moving robot
    (seed 0; datasets cached under ``work/data``, the artifact in ``work/artifact``; made once)."""
    from sonicskin.rig import Rig
    from sonicskin.seeds import _one_seed, scenario_dataset

    rig, kw = Rig.load("jaco"), {}
    if small:
        rig = dataclasses.replace(rig, n_chirp=SMALL["n_chirp"], name=f"small-{SMALL['n_chirp']}")
        kw = SMALL["overrides"]
    ds = scenario_dataset("moving", 0, work / "data", rig=rig, log=_log, **kw)
    art = work / "artifact"
    if not (art / "skin.json").is_file():
        _log(f"training both models on {ds.root} into {art}")
        _one_seed("moving", ds, [0], art, epochs=SMALL["epochs"] if small else None, log=_log)
    return art, ds


def _ms(x: np.ndarray, q: float) -> str:
    return f"{np.percentile(x, q) * 1e3:.3f} ms"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Stdout: the markdown table and the ratio sentence only; progress on stderr.")
    ap.add_argument("--artifact", help="artifact with net.onnx and svm.onnx (default: train one on simulated data)")
    ap.add_argument("--data", help="dataset to take the chirps from (default: the artifact's)")
    ap.add_argument("--chirps", type=int, default=500, help="timed chirps per model (default: 500)")
    ap.add_argument("--work", default="reports/bench-models", help="where the default artifact and its data go "
                    "(default: reports/bench-models; with --small: a temporary folder)")
    ap.add_argument("--small", action="store_true", help="a short-chirp rig, short presses, a 5-epoch network, 100 chirps: for the tests")
    a = ap.parse_args(argv)
    if a.chirps < 1:
        ap.error("--chirps must be >= 1")
    tmp = tempfile.TemporaryDirectory(prefix="bench-models-") if a.small and a.work == ap.get_default("work") else None
    if a.small:
        a.chirps = min(a.chirps, 100)
    if a.artifact:
        art = Path(a.artifact)
    else:
        art, ds0 = build_artifact(Path(tmp.name if tmp else a.work), small=a.small)
        a.data = a.data or str(ds0.root)

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
    inputs = {k: st.reference.inputs(log_magnitude_db(frames[rows[:64]], rts[k].rig)[:, st.bins]) for k, st in streams.items()}
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
    _log(f"artifact {art}; {n} chirps of {ds.root.name}/{test[0]} per model, interleaved; "
         f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, onnxruntime 1 thread; chirp period {period_ms:.1f} ms")
    names = {"svm": "SVM", "net": "network"}
    out = ["| model | ONNX call median | p99 | whole per-chirp path median | p99 | share of the chirp period (path p99) | ONNX file |",
           "|---|---|---|---|---|---|---|"]
    for k in [m for m in ("svm", "net") if m in rts]:
        out.append(f"| {names[k]} | {_ms(onnx[k], 50)} | {_ms(onnx[k], 99)} | {_ms(path[k], 50)} | {_ms(path[k], 99)} "
                   f"| {np.percentile(path[k], 99) * 1e3 / period_ms:.2%} | {(art / rts[k].m['file']).stat().st_size / 1e3:.0f} kB |")
    out.append("")
    out.append(f"{n} chirps per model, timed interleaved; the whole path is frame -> features -> reference -> model -> detection "
               f"-> force, one chirp period is {period_ms:.1f} ms.")
    if set(rts) == {"net", "svm"}:
        from sonicskin.metrics import speed_ratio

        def said(r: str) -> str:
            return "as fast as the SVM's" if r == "as fast" else f"{r} than the SVM's"

        out[-1] += (f" The network's ONNX call is {said(speed_ratio(np.median(onnx['net']), np.median(onnx['svm'])))}, "
                    f"its whole per-chirp path {said(speed_ratio(np.median(path['net']), np.median(path['svm'])))}.")
    print("\n".join(out))
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
