"""Valid recordings are never refused by import-wav's checks of the sweep (period, repetition, band, clipping,
dropouts): rigs of the random family we did not design on, still and moving, exported as WAV + interval CSV the way
another lab's data comes, import with the labels they were simulated with.

(The hostile-input round's notes/hostdata_false_refusals.py, made a test: those checks were tuned on a few rigs, and a
refusal of good data is the failure nobody reports.)
"""

from __future__ import annotations

import csv

import numpy as np
import pytest
import soundfile as sf
from cli_helpers import SMALL_RIG

from sonicskin.dataset import Dataset
from sonicskin.importers import import_wav
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

QUIET = {"log": lambda *_: None}


def _export(rig: Rig, seed: int, root) -> tuple[Dataset, dict]:
    """One session of random-family rig ``seed`` (2 markers) simulated, then written as a float WAV + interval CSV."""
    sc = Scenario.load("random", seed=seed)
    sc = sc.replace(sessions=1, layout={**sc.layout, "nx": 2, "ny": 1}, touch_s=0.4, gap_s=0.2, calibration_s=1.0,
                    moving_s=min(sc.moving_s, 2.0), repeats=1, train_repeats=None)
    simulate_dataset(sc, rig, root / "sim", progress=False, **QUIET)
    ds = Dataset(root / "sim")
    s = ds.sessions[0]
    audio = np.concatenate([sf.read(ds.root / s / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(s)])
    (root / "rec").mkdir()
    sf.write(root / "rec" / "a.wav", audio, int(rig.fs_hz), subtype="FLOAT")
    _, lab = ds.read_session(s)
    loc = lab["location"]
    edges = np.flatnonzero(np.diff(loc)) + 1
    rows = [["file", "start_s", "end_s", "location"]]
    for a, b in zip(np.r_[0, edges], np.r_[edges, loc.size]):
        if loc[a] >= 0:  # one interval per press, a little wider than its chirps
            rows.append(["a.wav", f"{lab['t_s'][a] - 0.002:.6f}", f"{lab['t_s'][b - 1] + 0.002:.6f}", str(loc[a])])
    with open(root / "labels.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return ds, lab


@pytest.mark.slow
@pytest.mark.parametrize("rig_name, seed", [("small", 0), ("small", 3), ("small", 11), ("small", 42), ("small", 7001),
                                            ("small", 7005), ("jaco", 1), ("jaco", 2)])
def test_a_valid_recording_of_a_rig_we_did_not_design_on_imports_with_its_labels(tmp_path, rig_name, seed):
    if rig_name == "small":
        (tmp_path / "small.yaml").write_text(SMALL_RIG)
        rig = Rig.load(tmp_path / "small.yaml")
    else:
        rig = Rig.load(rig_name)
    sim, truth = _export(rig, seed, tmp_path)
    import_wav(tmp_path / "rec", tmp_path / "labels.csv", tmp_path / "imp", chirp_hz=(rig.f_lo_hz, rig.f_hi_hz),
               period_s=rig.period_s, amplitude=rig.amplitude, **QUIET)
    imp = Dataset(tmp_path / "imp")
    _, got = imp.read_session(imp.sessions[0])
    # every pressed chirp keeps its marker: per marker the same chirps, each found where the received sweep starts (the
    # transmitted start plus the link's delay: one shift for the whole recording, well under a period)
    shifts = []
    for v in sim.layout.ids:
        want_t, got_t = truth["t_s"][truth["location"] == v], got["t_s"][got["location"] == v]
        assert want_t.size >= 2 and got_t.size == want_t.size, (v, want_t.size, got_t.size)
        shifts.append(got_t - want_t)
    shifts = np.concatenate(shifts)
    assert np.ptp(shifts) < 1.5 / rig.fs_hz and abs(shifts[0]) < rig.period_s / 4, (shifts.min(), shifts.max())
