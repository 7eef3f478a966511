"""Valid recordings must not be refused by import-wav's sweep checks: simulate random-family rigs (1 session, 2 markers),
export them as WAV + interval CSV, import.

    python notes/hostdata_false_refusals.py RIG SEEDS OUTDIR

RIG a rig name or YAML, SEEDS comma-separated.  Measured on this branch: the small rig of tests/cli_helpers.py with
seeds 0,3,7001,7005,11,42,12,13,14,15,16 and jaco with seeds 1,2 (with and without motion): 13 of 13 imported.
"""
from __future__ import annotations

import csv
import shutil
import sys
from pathlib import Path

import numpy as np
import soundfile as sf

from sonicskin.dataset import Dataset
from sonicskin.importers import import_wav
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario


def main() -> None:
    rig = Rig.load(sys.argv[1])
    out = Path(sys.argv[3])
    refused = 0
    for seed in [int(v) for v in sys.argv[2].split(",")]:
        root = out / f"fp{seed}"
        shutil.rmtree(root, ignore_errors=True)
        root.mkdir(parents=True)
        sc = Scenario.load("random", seed=seed)
        lay = {**sc.layout, "nx": 2, "ny": 1}
        sc = sc.replace(sessions=1, layout=lay, touch_s=0.4, gap_s=0.2, calibration_s=1.0, moving_s=min(sc.moving_s, 2.0),
                        repeats=1, train_repeats=None)
        simulate_dataset(sc, rig, root / "d", progress=False, log=lambda *_: None)
        ds = Dataset(root / "d")
        s = ds.sessions[0]
        x = np.concatenate([sf.read(ds.root / s / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(s)])
        (root / "rec").mkdir()
        sf.write(root / "rec" / "a.wav", x, int(rig.fs_hz), subtype="FLOAT")
        _, lab = ds.read_session(s)
        loc = lab["location"]
        edges = np.flatnonzero(np.diff(loc)) + 1
        rows = [["file", "start_s", "end_s", "location"]]
        for a, b in zip(np.r_[0, edges], np.r_[edges, loc.size]):
            if loc[a] >= 0:
                rows.append(["a.wav", f"{lab['t_s'][a] - 0.002:.6f}", f"{lab['t_s'][b - 1] + 0.002:.6f}", str(loc[a])])
        with open(root / "l.csv", "w", newline="") as fh:
            csv.writer(fh).writerows(rows)
        try:
            import_wav(root / "rec", root / "l.csv", root / "imp", chirp_hz=(rig.f_lo_hz, rig.f_hi_hz), period_s=rig.period_s,
                       amplitude=rig.amplitude, log=lambda *_: None)
            print(seed, sc.material, sc.geometry["kind"], "motion" if sc.motion.get("enabled") else "still", "imported")
        except ValueError as e:
            refused += 1
            print(seed, "REFUSED", e)
    print("refused", refused)


if __name__ == "__main__":
    main()
