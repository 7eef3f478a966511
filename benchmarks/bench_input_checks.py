"""How long the input checks take on inputs that once ran for minutes (issue 27.2: timings are printed here, never
asserted in a test, so the suite passes at any machine load).

Each row is one hostile input that the tests check for its answer (tests/test_hostile_data.py,
tests/test_integrity_data.py); here only its wall time on this machine is measured and printed:

    input                                          before the fix       wall time here
    label_layout, 20 000 distinct locations        13 s                 (seconds on this machine)
    ...

    python benchmarks/bench_input_checks.py [--work DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cli_helpers import SMALL_RIG, TINY_SCENARIO, write_recordings  # noqa: E402  (the tests' small rig, tiny scenario)


def _timed(fn) -> tuple[float, str]:
    """(seconds, outcome) of ``fn()``: "accepted", or the first words of the one-line refusal."""
    from sonicskin.errors import SonicskinError

    t0 = time.perf_counter()
    try:
        fn()
        what = "accepted"
    except (SonicskinError, ValueError) as e:
        what = "refused: " + str(e)[:60]
    return time.perf_counter() - t0, what


def _recordings(work: Path) -> tuple[Path, Path, list[list[str]], object]:
    """The tiny scenario as WAV recordings and an interval CSV (one row per press), as tests/test_hostile_data.py makes."""
    from sonicskin.dataset import Dataset
    from sonicskin.rig import Rig
    from sonicskin.sim.generate import simulate_dataset
    from sonicskin.sim.scenario import Scenario

    (work / "small.yaml").write_text(SMALL_RIG)
    (work / "tiny.yaml").write_text(TINY_SCENARIO)
    rig = Rig.load(work / "small.yaml")
    simulate_dataset(Scenario.load(work / "tiny.yaml").replace(sessions=2), rig, work / "data", progress=False,
                     log=lambda *_: None)
    ds = Dataset(work / "data")
    rows = [["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n"], *write_recordings(ds, work / "rec")]
    return work / "rec", work / "labels.csv", rows, (rig, ds)


def _write(path: Path, rows) -> None:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    path.write_text(buf.getvalue())


def run(work: Path) -> list[tuple[str, str, float, str]]:
    from sonicskin.cli import main
    from sonicskin.importers import import_spectra, import_wav, label_layout

    rows_out = []
    n = 20_000
    s, what = _timed(lambda: label_layout(np.arange(n), np.arange(n) * 0.01, np.zeros(n), log=lambda *_: None))
    rows_out.append(("label_layout, 20 000 distinct locations", "13 s", s, what))
    rec, labels, rows, (rig, ds) = _recordings(work)
    _write(labels, rows + [list(rows[1]) for _ in range(n)])
    chirp = {"chirp_hz": (rig.f_lo_hz, rig.f_hi_hz), "period_s": rig.period_s, "amplitude": rig.amplitude}
    s, what = _timed(lambda: import_wav(rec, labels, work / "o", **chirp, log=lambda *_: None))
    rows_out.append(("import-wav, 20 000 copies of one label interval", "74 s", s, what))
    t = ds.features(progress=False)
    np.savez(work / "t.npz", freqs_hz=rig.freqs_hz[rig.band_bins] / 1000, magnitude_db=t.X.astype(float),
             location=t["location"], session=t["session"])
    s, what = _timed(lambda: import_spectra(work / "t.npz", work / "o2", log=lambda *_: None))
    rows_out.append(("import-spectra, frequencies in kHz", "minutes", s, what))
    for argv in (["simulate", "--sessions", "1000000000"], ["simulate", "--set", "touch_s=1.0e+12"],
                 ["record", "--touch-s", "1e12", "--fast"]):
        with contextlib.redirect_stderr(io.StringIO()) as err:
            t0 = time.perf_counter()
            code = main([*argv, "--out", str(work / "o3"), "--rig", str(work / "small.yaml"), "--scenario",
                         str(work / "tiny.yaml")])
            s = time.perf_counter() - t0
        rows_out.append((" ".join(argv), "memory error", s, f"exit {code}: " + err.getvalue().strip()[:60]))
    return rows_out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", help="folder for the simulated recordings (default: a temporary folder)")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = run(work)
    w = max(len(r[0]) for r in rows)
    print(f"{'input':{w}}  {'before the fix':>14}  {'wall time here':>14}  outcome")
    for name, before, s, what in rows:
        print(f"{name:{w}}  {before:>14}  {s:>12.2f} s  {what}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
