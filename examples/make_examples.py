"""Make the worked examples of ``sonicskin import-wav`` and ``sonicskin import-spectra`` (committed outputs).

Both come from the simulator, dressed as another lab's data would arrive:

``examples/wav/``
    ``recordings/s0.wav .. s2.wav``: three sessions of 16-bit mono audio at 16 kHz from a rig that
    plays a logarithmic 1-7 kHz sweep of 0.1 s (``sweep.wav``, one period), each starting with
    2.9 s of rest in the middle of a sweep (29 whole sweeps, one short of Alg. 2's 3 s), then one
    press at each of six markers; ``labels.csv``: rows of 0.2 s of a press (file, start_s, end_s,
    location name, marker x/y in cm, mean force in N).
``examples/spectra/touches.npz``
    a table of dB magnitude spectra in a foreign band (165 FFT bins of 450-sample frames at 48 kHz,
    2.45-19.95 kHz, the axis rounded as a plotting tool would), touches only (no hands-off rows),
    no force sensor, locations as positions in cm (1.5, 2.0, ..., 5.5), three folds (sessions),
    and the level of a raw FFT of int16 audio (about +100 dB).

Run from the repository root: ``python examples/make_examples.py`` (a few seconds).
"""

from __future__ import annotations

import csv
import shutil
import tempfile
from pathlib import Path

import numpy as np
import scipy.signal
import soundfile as sf

from sonicskin.dataset import Dataset
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

HERE = Path(__file__).resolve().parent
NAMES = ("A1", "B1", "C1", "A2", "B2", "C2")  # grid row-major: x = A..C, y = 1..2


def wav_example(out: Path, work: Path) -> None:
    fs, n = 16_000, 1600
    t = np.arange(n) / fs
    sweep = 0.5 * scipy.signal.chirp(t, f0=1000, t1=t[-1], f1=7000, method="logarithmic")
    sweep *= scipy.signal.windows.tukey(n, 0.05)
    rig = Rig(fs_hz=fs, f_lo_hz=1000, f_hi_hz=7000, n_chirp=n, pwm_hz=(), pwm_halfwidth_hz=0.0, amplitude=0.5,
              name="lab-b", sweep_b64=Rig.encode_sweep(sweep.astype(np.float32)))
    sc = Scenario.load("stationary").replace(
        name="lab-b", sessions=3, layout={"kind": "grid", "nx": 3, "ny": 2, "spacing_cm": 1.5, "x0_cm": 3.0, "y0_cm": 11.0},
        touch_s=1.0, gap_s=0.4, calibration_s=2.9, session_interval_s=120, seed=11)
    simulate_dataset(sc, rig, work / "wav-sim", mode="overwrite", progress=False, log=lambda *_: None)
    ds = Dataset(work / "wav-sim")
    rec = out / "recordings"
    rec.mkdir(parents=True)
    rows = []
    for k, s in enumerate(ds.sessions):
        audio = np.concatenate([sf.read(ds.root / s / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(s)])
        sf.write(rec / f"s{k}.wav", audio, fs, subtype="PCM_16")
        _, lab = ds.read_session(s)
        loc = lab["location"]
        for ev in np.unique(loc[loc >= 0]):
            x, y = ds.layout.coords(np.array([ev]))[0]
            # A press as rows of 0.2 s with the load cell's mean force in each.
            for i in np.array_split(np.flatnonzero(loc == ev), max(1, int(np.sum(loc == ev)) // 2)):
                rows.append([f"s{k}.wav", f"{lab['t_s'][i[0]]:.3f}", f"{lab['t_s'][i[-1]] + rig.period_s:.3f}",
                             NAMES[int(ev)], f"{x:g}", f"{y:g}", f"{np.mean(lab['force_n'][i]):.2f}"])
    rows.sort(key=lambda r: (r[0], float(r[1])))
    with open(out / "labels.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n"])
        w.writerows(rows)
    sf.write(out / "sweep.wav", sweep.astype(np.float32), fs, subtype="FLOAT")


def spectra_example(out: Path, work: Path) -> None:
    rig = Rig(fs_hz=48_000, f_lo_hz=2450, f_hi_hz=19_950, n_chirp=450, pwm_hz=(), pwm_halfwidth_hz=0.0, amplitude=0.5,
              name="lab-c")
    positions_cm = 1.5 + 0.5 * np.arange(9)
    sc = Scenario.load("stationary").replace(
        name="lab-c", sessions=3, layout={"kind": "grid", "nx": 9, "ny": 1, "spacing_cm": 0.5, "x0_cm": 1.5, "y0_cm": 12.0},
        touch_s=1.0, gap_s=0.3, calibration_s=0.5, session_interval_s=120, seed=5)
    simulate_dataset(sc, rig, work / "spectra-sim", mode="overwrite", progress=False, log=lambda *_: None)
    t = Dataset(work / "spectra-sim").features(progress=False)
    rng = np.random.default_rng(0)
    keep = []
    for s in sorted(set(t["session"])):
        for loc in range(9):
            i = np.flatnonzero((t["session"] == s) & (t["location"] == loc))
            keep += sorted(rng.choice(i, size=min(40, i.size), replace=False))
    keep = np.asarray(keep)
    out.mkdir(parents=True)
    np.savez_compressed(
        out / "touches.npz",
        freqs_hz=np.round(np.linspace(2450, 19_950, rig.n_band), 1),        # 2.45-19.95 kHz as the lab plots it
        magnitude_db=np.round(t.X[keep] + 100.0, 2).astype(np.float32),     # raw-FFT level, two decimals
        location=positions_cm[t["location"][keep]],                         # position in cm, float
        session=np.array([f"fold{int(s[1:]) + 1}" for s in t["session"][keep]]))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for name, make in (("wav", wav_example), ("spectra", spectra_example)):
            if (HERE / name).exists():
                shutil.rmtree(HERE / name)
            make(HERE / name, Path(tmp))
    total = sum(p.stat().st_size for p in HERE.rglob("*") if p.is_file())
    print(f"examples written under {HERE} ({total / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
