"""Hostile data inputs the earlier corpora missed (notes/hostdata-probes.md): each one gave a traceback, a hang or a
silently wrong dataset before; now it is refused with one line naming the problem and the fix, or read correctly.

Inputs are built from a small simulated dataset (the CLI tests' small rig and tiny scenario) exported the way another
lab's data comes: WAV recordings with an interval CSV, and a table of spectra.
"""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from cli_helpers import SMALL_RIG, TINY_SCENARIO, assert_one_line_error, run, write_recordings

from sonicskin.dataset import Dataset
from sonicskin.dsp import rig_chirp
from sonicskin.errors import SonicskinError
from sonicskin.importers import import_spectra, import_wav, rig_from_axis
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

QUIET = {"log": lambda *_: None}
HEADER = ["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n", "moving", "subject"]


@pytest.fixture(scope="module")
def src(tmp_path_factory):
    """Two sessions of the small rig as float WAVs + an interval CSV (one row per press) + the sweep; and a spectra table."""
    root = tmp_path_factory.mktemp("hostile")
    (root / "small.yaml").write_text(SMALL_RIG)
    (root / "tiny.yaml").write_text(TINY_SCENARIO)
    rig = Rig.load(root / "small.yaml")
    simulate_dataset(Scenario.load(root / "tiny.yaml").replace(sessions=2), rig, root / "data", progress=False, log=lambda *_: None)
    ds = Dataset(root / "data")
    rows = [HEADER, *write_recordings(ds, root / "rec", tail=("2.5", "0", "0"))]
    _write(root / "labels.csv", rows)
    sf.write(root / "sweep.wav", rig_chirp(rig).astype(np.float32), int(rig.fs_hz), subtype="FLOAT")
    t = ds.features(progress=False)
    table = {"freqs_hz": rig.freqs_hz[rig.band_bins], "magnitude_db": t.X.astype(float), "location": t["location"],
             "session": t["session"], "force_n": t["force_n"], "x_cm": t["x_cm"], "y_cm": t["y_cm"]}
    return {"root": root, "rig": rig, "rows": rows, "table": table}


def _write(path: Path, rows) -> None:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    path.write_text(buf.getvalue())


def _chirp(rig: Rig, period_s: float | None = None, band=None) -> dict:
    return {"chirp_hz": band or (rig.f_lo_hz, rig.f_hi_hz), "period_s": period_s or rig.period_s, "amplitude": rig.amplitude}


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert isinstance(exc, (SonicskinError, ValueError)) and msg and "\n" not in msg, repr(exc)
    return msg


def _refused(fn, *args, **kw) -> str:
    with pytest.raises((SonicskinError, ValueError)) as e:
        fn(*args, **kw)
    return _one_line(e.value)


@pytest.fixture
def inp(src, tmp_path):
    """A private copy of the recordings and labels: (folder, labels path, rows to edit)."""
    shutil.copytree(src["root"] / "rec", tmp_path / "rec")
    return tmp_path / "rec", tmp_path / "labels.csv", [list(r) for r in src["rows"]]


# -- the label CSV -----------------------------------------------------------------------------------------------
def _col(name: str) -> int:
    return HEADER.index(name)


LABEL_CASES = [
    ("duplicated column", lambda rows: [r.append("force_n" if i == 0 else "0") for i, r in enumerate(rows)],
     "labels.csv: column 'force_n' appears 2 times in the header; keep one"),
    ("misspelled optional column", lambda rows: rows[0].__setitem__(_col("force_n"), "force"),
     "labels.csv: column 'force' is not a label column; did you mean 'force_n'?"),
    ("optional column in other case", lambda rows: rows[0].__setitem__(_col("subject"), "Subject"),
     "labels.csv: column 'Subject' is not a label column; did you mean 'subject'?"),
    ("row with fewer values", lambda rows: rows.__setitem__(2, rows[2][:5]),
     "labels.csv line 3: 5 values for 9 columns; a missing value, or a decimal comma (write 3.5, not 3,5)? fix the row"),
    ("unquoted decimal comma", lambda rows: rows.__setitem__(2, rows[2][:6] + ["2", "5"] + rows[2][7:]),
     "labels.csv line 3: 10 values for 9 columns"),
    ("subject 1.5", lambda rows: rows[2].__setitem__(_col("subject"), "1.5"),
     "labels.csv: line 3: subject = 1.5, but a subject is a whole number >= 0; fix the value"),
    ("force as text", lambda rows: rows[2].__setitem__(_col("force_n"), "heavy"),
     "labels.csv line 3: force_n = 'heavy' is not a number; write plain numbers"),
    ("digits with an underscore", lambda rows: rows[2].__setitem__(_col("start_s"), "1_0"),
     "labels.csv line 3: start_s = '1_0' is not a number"),
    ("location with an underscore among ids", lambda rows: rows[2].__setitem__(_col("location"), "1_0"),
     "labels.csv: location labels mix numbers ('0') and names ('1_0'); use one kind for every location"),
    ("location inf", lambda rows: rows[2].__setitem__(_col("location"), "inf"),
     "labels.csv: location 'inf' is not a location"),
    ("interval between two sweep starts", lambda rows: rows[1].__setitem__(_col("end_s"), f"{float(rows[1][1]) + 0.001:.6f}"),
     "labels.csv line 2: the interval 3.49732-3.49832 s of s000.wav holds no sweep start"),
    ("one location at two places", lambda rows: rows[4].__setitem__(_col("x_cm"), str(float(rows[4][_col("x_cm")]) + 5)),
     "labels.csv: location '0' is at (9.4, 12.5) cm in row 0 but at (14.4, 12.5) cm in row 3, 5 cm apart"),
    ("two locations at one place", lambda rows: [r.__setitem__(_col("x_cm"), "9.4") for r in rows[1:] if r[3] == "1"],
     "labels.csv: locations '0' and '1' are both at (9.4, 12.5) cm; two markers cannot share a place"),
    ("x_cm without y_cm", lambda rows: rows[2].__setitem__(_col("y_cm"), ""),
     "labels.csv: row 1 (location '1') has x_cm 10.6 but y_cm nan; give both coordinates of a marker, or neither"),
]


@pytest.mark.parametrize("name, mutate, words", LABEL_CASES, ids=[c[0] for c in LABEL_CASES])
def test_label_csv_mistakes_are_refused(src, inp, tmp_path, name, mutate, words):
    rec, labels, rows = inp
    mutate(rows)
    _write(labels, rows)
    msg = _refused(import_wav, rec, labels, tmp_path / "out", **_chirp(src["rig"]), **QUIET)
    assert words in msg, msg
    assert not (tmp_path / "out").exists()


def test_a_nul_byte_in_the_labels_is_refused(src, inp, tmp_path):
    rec, labels, rows = inp
    _write(labels, rows)
    labels.write_text(labels.read_text() + "s000.wav,1,2,0\x00,,,,,\n")
    assert "labels.csv: holds NUL bytes; it is not a text CSV" in _refused(import_wav, rec, labels, tmp_path / "o",
                                                                            **_chirp(src["rig"]), **QUIET)


def test_excel_csv_reads_like_the_clean_one(src, inp, tmp_path):
    """A BOM (Excel's 'CSV UTF-8'), CRLF line endings, spaces after the header's commas and an extra notes column
    give exactly the labels of the clean file (the extra column with a warning)."""
    rec, labels, rows = inp
    clean = Dataset(import_wav(rec, src["root"] / "labels.csv", tmp_path / "clean", **_chirp(src["rig"]), **QUIET))
    rows[0] = [rows[0][0]] + [" " + c for c in rows[0][1:]] + ["notes"]
    for r in rows[1:]:
        r.append("ok")
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\r\n").writerows(rows)
    labels.write_bytes(b"\xef\xbb\xbf" + buf.getvalue().encode())
    with pytest.warns(UserWarning, match=r"columns \['notes'\] are not label columns and are ignored"):
        excel = Dataset(import_wav(rec, labels, tmp_path / "excel", **_chirp(src["rig"]), **QUIET))
    for s in clean.sessions:
        a, b = clean.read_session(s)[1], excel.read_session(s)[1]
        for c in ("location", "force_n", "x_cm", "segment"):
            np.testing.assert_array_equal(a[c], b[c])


# -- the recordings and the sweep ----------------------------------------------------------------------------------
def _edit(rec: Path, name: str, fn, subtype="FLOAT") -> None:
    x, fs = sf.read(rec / name, dtype="float32")
    sf.write(rec / name, fn(x), fs, subtype=subtype)


def test_samples_beyond_full_scale_are_refused_not_clipped(src, inp, tmp_path):
    rec, labels, rows = inp
    _write(labels, rows)
    peak = float(np.abs(sf.read(rec / "s001.wav", dtype="float32")[0]).max())
    _edit(rec, "s001.wav", lambda x: x * (4.0 / peak))
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    assert "s001.wav: samples reach 4, beyond full scale (1.0): the dataset's 24-bit parts would clip them; scale every " \
           "recording by one gain (at most 0.25) and import again" in msg, msg


def test_clipped_sweeps_are_refused_at_import(src, inp, tmp_path):
    rec, labels, rows = inp
    _write(labels, rows)
    _edit(rec, "s000.wav", lambda x: np.clip(x * 20, -1, 1), subtype="PCM_16")
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    assert "s000.wav: " in msg and "sweeps are clipped at full scale" in msg and "record again with a lower input gain" in msg


@pytest.mark.parametrize("what, kw, words", [
    ("noise instead of a recording", None, "s001.wav: consecutive sweep periods of 1024 samples do not repeat (median "
                                           "correlation 0.00): the file holds no sweep of this period"),
    ("--period twice the sweep's", {"period_s": 2048 / 192000}, "s000.wav: the recording repeats every 1024 samples, not "
                                                                 "every 2048: the sweep period is 0.00533333 s"),
    ("--period 1 % long", {"period_s": 1034 / 192000}, "s000.wav: the recording repeats every 1024 samples, not every 1034 "
                                                        "(correlation 1.00 against 0.36): the sweep period is 0.005333333 s"),
    ("--period one sample short", {"period_s": 1023 / 192000}, "s000.wav: the recording repeats every 1024 samples, not every "
                                                               "1023"),
    ("--period half the sweep's", {"period_s": 512 / 192000}, "s000.wav: consecutive sweep periods of 512 samples do not repeat"),
    ("--chirp in another band", {"band": (5000.0, 15000.0)}, "s000.wav: 0.0% of the repeating signal's power lies in the "
                                                              "sweep band 5-15 kHz"),
])
def test_a_sweep_that_does_not_describe_the_recordings_is_refused(src, inp, tmp_path, what, kw, words):
    rec, labels, rows = inp
    _write(labels, rows)
    if kw is None:
        _edit(rec, "s001.wav", lambda x: (0.1 * np.random.default_rng(0).standard_normal(x.size)).astype(np.float32))
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(src["rig"], **(kw or {})), **QUIET)
    assert words in msg and "check --period/--chirp or --sweep" in msg, msg


def test_a_sweep_wav_of_several_periods_and_two_sweeps_are_refused(src, inp, tmp_path, capsys):
    rec, labels, rows = inp
    _write(labels, rows)
    x = rig_chirp(src["rig"]).astype(np.float32)
    sf.write(tmp_path / "sw4.wav", np.tile(x, 4), int(src["rig"].fs_hz), subtype="FLOAT")
    msg = _refused(import_wav, rec, labels, tmp_path / "o", sweep_wav=tmp_path / "sw4.wav", **QUIET)
    assert msg == "the sweep WAV repeats every 1024 samples: it holds 4 periods of the sweep, not one; cut it to one period " \
                  "(1024 samples)", msg
    code, _, err = run(capsys, ["import-wav", "--wav-dir", rec, "--labels", labels, "--out", tmp_path / "o", "--sweep",
                                src["root"] / "sweep.wav", "--chirp", "20000", "80000", "--period", str(src["rig"].period_s)])
    assert assert_one_line_error(code, err, "import-wav").endswith(
        "give the transmitted sweep one way: --sweep SWEEP.wav, or --chirp F_LO F_HI --period S; not both")
    assert not (tmp_path / "o").exists()


def test_resume_refuses_a_changed_folder_or_changed_labels(src, inp, tmp_path):
    """Sessions are numbered in file order: a recording added before the others used to shift every session, so --resume
    imported a file twice and the new one never; edited labels would mix two label files in one dataset."""
    rec, labels, rows = inp
    _write(labels, rows)
    out = import_wav(rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    shutil.rmtree(out / "s001")  # an interrupted import
    shutil.copy(rec / "s001.wav", rec / "a_new.wav")
    msg = _refused(import_wav, rec, labels, out, **_chirp(src["rig"]), mode="resume", **QUIET)
    assert "cannot resume" in msg and "['s000.wav', 's001.wav'], the folder now holds ['a_new.wav', 's000.wav', 's001.wav']" in msg
    (rec / "a_new.wav").unlink()
    rows[1][_col("force_n")] = "3.5"
    _write(labels, rows)
    msg = _refused(import_wav, rec, labels, out, **_chirp(src["rig"]), mode="resume", **QUIET)
    assert "labels.csv changed since the import began; pass --overwrite" in msg
    rows[1][_col("force_n")] = "2.5"
    _write(labels, rows)  # the same labels again: the resume completes
    import_wav(rec, labels, out, **_chirp(src["rig"]), mode="resume", **QUIET)
    assert Dataset(out).sessions == ["s000", "s001"]


# -- tables of spectra ------------------------------------------------------------------------------------------------
def _table(src, tmp_path, **over) -> Path:
    z = dict(src["table"])
    for k, v in over.items():
        if v is None:
            z.pop(k)
        else:
            z[k] = v(z) if callable(v) else v
    np.savez(tmp_path / "t.npz", **z)
    return tmp_path / "t.npz"


def _row(value):
    def fn(z):
        m = z["magnitude_db"].copy()
        m[5] = value
        return m
    return fn


SPECTRA_CASES = [
    ("frequencies in kHz", {"freqs_hz": lambda z: z["freqs_hz"] / 1000},
     "the axis (20.0625-79.875, bins 0.1875 apart) would mean FFT frames of 5.33 s; freqs_hz must be in Hz (are these kHz? "
     "multiply by 1000), or pass --fs and --frame"),
    ("axis from 0 Hz", {"freqs_hz": lambda z: z["freqs_hz"] - z["freqs_hz"][0]},
     "freqs_hz starts at 0 Hz; the table's columns are the sweep band's FFT bins, above 0 Hz"),
    ("negative frequencies", {"freqs_hz": lambda z: z["freqs_hz"] - 50_000}, "freqs_hz starts at -29937.5 Hz"),
    ("no rows", {k: (lambda z, k=k: z[k][:0]) for k in ("magnitude_db", "location", "session", "force_n", "x_cm", "y_cm")},
     "t.npz: magnitude_db has no rows; the table holds no spectra"),
    ("every row the same", {"magnitude_db": lambda z: np.full_like(z["magnitude_db"], -30.0)},
     "t.npz: every row of magnitude_db is the same spectrum; the table holds no measurements"),
    ("one row at +1e5 dB", {"magnitude_db": _row(1e5)}, "t.npz: magnitude_db spans 1e+05 dB"),
    ("one row at -1e300 dB", {"magnitude_db": _row(-1e300)}, "t.npz: magnitude_db spans 1e+300 dB (row 5: -1e+300"),
    ("y_cm without x_cm", {"x_cm": None}, "t.npz: has y_cm but not x_cm; give both coordinates of each marker, or neither"),
]


@pytest.mark.parametrize("name, over, words", SPECTRA_CASES, ids=[c[0] for c in SPECTRA_CASES])
def test_spectra_table_mistakes_are_refused(src, tmp_path, name, over, words):
    table = _table(src, tmp_path, **over)
    msg = _refused(import_spectra, table, tmp_path / "out", **QUIET)  # the kHz axis used to run for minutes: its
    assert words in msg, msg  # time now is a figure of benchmarks/bench_input_checks.py (no wall clock in tests)
    assert not (tmp_path / "out").exists()


def test_rig_from_axis_refuses_dc_through_the_cli(src, tmp_path, capsys):
    """Was an AssertionError traceback."""
    table = _table(src, tmp_path, freqs_hz=lambda z: z["freqs_hz"] - z["freqs_hz"][0])
    code, _, err = run(capsys, ["import-spectra", "--table", table, "--out", tmp_path / "o"])
    assert "freqs_hz starts at 0 Hz" in assert_one_line_error(code, err, "import-spectra")
    with pytest.raises(SonicskinError, match="freqs_hz starts at -1 Hz"):
        rig_from_axis(np.arange(-1.0, 100.0), log=lambda *_: None)


# -- scenario YAML ---------------------------------------------------------------------------------------------------
def _tiny(**over) -> dict:
    import yaml

    d = yaml.safe_load(TINY_SCENARIO)
    d.update(over)
    return d


GRID = {"kind": "grid", "nx": 3, "ny": 1, "spacing_cm": 1.2, "x0_cm": 9.4, "y0_cm": 12.5}
SCENARIO_CASES = [  # (what, override, the message); the first four were tracebacks, the others silently simulated
    ("geometry kind sphere", {"geometry": {"kind": "sphere", "radius_cm": 3.0}}, "geometry kind must be 'tube' or 'plate', got 'sphere'"),
    ("plate without length", {"geometry": {"kind": "plate", "width_cm": 20.0}},
     "geometry (plate) {'kind': 'plate', 'width_cm': 20.0} lacks ['length_cm']"),
    ("radius as text", {"geometry": {"kind": "tube", "radius_cm": "big", "length_cm": 25.0}},
     "geometry radius_cm must be a positive number of cm, got 'big'"),
    ("grid without spacing", {"layout": {k: v for k, v in GRID.items() if k != "spacing_cm"}}, "lacks ['spacing_cm']"),
    ("grid nx as text", {"layout": {**GRID, "nx": "3"}}, "marker counts (counts, nx, ny) are whole numbers >= 1"),
    ("unknown channel key", {"channel": {"foo": 1}}, "unknown channel keys ['foo']; valid keys: ['irregularity',"),
    ("misspelled geometry key", {"geometry": {"kind": "plate", "width_cm": 20.0, "length_cm": 25.0, "lenght_cm": 5}},
     "unknown geometry (plate) keys ['lenght_cm']; valid keys: ['kind', 'length_cm', 'width_cm']"),
    ("misspelled layout key", {"layout": {**GRID, "spacing": 2.0}}, "unknown layout (grid) keys ['spacing']"),
    ("misspelled temperature key", {"temperature": {"ambient": 30.0}}, "unknown temperature keys ['ambient']"),
    ("unknown motion key", {"motion": {"enabled": False, "speed": 3}}, "unknown motion keys ['speed']"),
    ("motion enabled as text", {"motion": {"enabled": "no"}}, "motion.enabled must be true or false, got 'no'"),
    ("grid nx 2.5", {"layout": {**GRID, "nx": 2.5}}, "marker counts (counts, nx, ny) are whole numbers >= 1"),
    ("negative ring count", {"layout": {"kind": "rings", "counts": [-3, 5], "spacing_cm": 1.2}}, "whole numbers >= 1"),
    ("spacing 0", {"layout": {**GRID, "spacing_cm": 0.0}}, "layout spacing_cm must be > 0 (markers apart), got 0.0"),
    ("markers off the plate", {"layout": {**GRID, "x0_cm": 100.0}},
     "layout marker 0 at (100, 12.5) cm lies outside the plate (x 0..20, y 0..25 cm); move the layout"),
    ("receiver on the transmitter", {"rx_cm": [4.0, 2.5]}, "tx_cm [4.0, 2.5] and rx_cm [4.0, 2.5] are less than 1 cm apart"),
    ("a person listed twice", {"subjects": [0, 0]}, "subjects [0, 0] name a person twice"),
    ("warm-up time 0", {"temperature": {"ambient_c": 23.0, "warmup_c": 5.0, "warmup_tau_s": 0.0}},
     "temperature.warmup_tau_s must be > 0 s, got 0.0"),
    ("name that is a path", {"name": "../../x"}, "scenario name '../../x' is not a plain name"),
]


@pytest.mark.parametrize("what, over, words", SCENARIO_CASES, ids=[c[0] for c in SCENARIO_CASES])
def test_scenario_mistakes_are_refused(what, over, words):
    with pytest.raises(SonicskinError if what == "name that is a path" else ValueError) as e:
        Scenario.from_dict(_tiny(**over))
    assert words in _one_line(e.value), str(e.value)


def test_scenario_mistakes_are_one_line_through_the_cli(src, tmp_path, capsys):
    """The KeyError / TypeError tracebacks of a hand-written scenario, and a name that would have put the default
    output folder (data/<name>) outside data/."""
    import yaml

    for over in ({"geometry": {"kind": "plate", "width_cm": 20.0}}, {"channel": {"foo": 1}}, {"name": "../../x"}):
        (tmp_path / "sc.yaml").write_text(yaml.safe_dump(_tiny(**over)))
        code, _, err = run(capsys, ["simulate", "--scenario", tmp_path / "sc.yaml", "--rig", src["root"] / "small.yaml",
                                    "--out", tmp_path / "out"])
        assert_one_line_error(code, err, "simulate")
        assert not (tmp_path / "out").exists()
    assert Scenario.from_dict(_tiny()).make_layout().xy_cm.shape == (3, 2)  # the valid one still loads


# -- dataset folders ---------------------------------------------------------------------------------------------------
COLS = ["chirp", "t_s", "time_s", "segment", "location", "x_cm", "y_cm", "force_n", "moving", "temperature_c", "subject"]


def _reseal(d: Path) -> None:
    from cli_helpers import reseal

    reseal(d)


def test_a_copied_session_is_refused(src, tmp_path, capsys):
    """A session folder copied within the dataset (its session.json binds it to this dataset.json, so the manifest
    accepted it) was trained and tested on twice: evaluate reported the copy of its training session as test data."""
    d = tmp_path / "data"
    shutil.copytree(src["root"] / "data", d, ignore=shutil.ignore_patterns(".cache"))
    shutil.copytree(d / "s000", d / "s002")
    code, _, err = run(capsys, ["evaluate", "--data", d, "--out", tmp_path / "rep", "--no-ablations", "--n-bins", "40"])
    assert assert_one_line_error(code, err, "evaluate").endswith(
        "data: sessions s000 and s002 hold the same recording (identical part-00000.flac): a copied session is trained and "
        "tested on twice; remove the copy")
    (d / "s002" / "session.json").unlink()  # an unfinished copy: compared by its bytes
    with pytest.raises(SonicskinError, match="sessions s000 and s002 hold the same recording"):
        Dataset(d).features(progress=False)
    shutil.rmtree(d / "s002")
    assert len(Dataset(d).features(progress=False)) > 0


@pytest.mark.parametrize("what, edit, words", [
    ("a touched chirp in the calibration segment", {"segment": "calibration"},
     "segment = 'calibration' but a chirp with a location (>= 0) is in a 'touch' segment"),
    ("a touched chirp without coordinates", {"x_cm": "nan"}, "x_cm = nan but a touched chirp (location >= 0) has finite coordinates"),
])
def test_touch_rows_must_be_touch_rows(src, tmp_path, what, edit, words):
    """Hand-edited labels (resealed): a touch labelled calibration entered the no-touch reference, a touch without a
    position entered the distance metrics as NaN."""
    d = tmp_path / "data"
    shutil.copytree(src["root"] / "data", d, ignore=shutil.ignore_patterns(".cache"))
    p = d / "s001" / "part-00000.csv"
    rows = list(csv.reader(io.StringIO(p.read_text())))
    k = next(i for i, r in enumerate(rows[1:], 1) if r[COLS.index("location")] != "-1")
    for c, v in edit.items():
        rows[k][COLS.index(c)] = v
    _write(p, rows)
    _reseal(d / "s001")
    with pytest.raises(SonicskinError) as e:
        Dataset(d).read_session("s001")
    assert words in _one_line(e.value)


# -- round 2: channels, dropouts, copies -------------------------------------------------------------------------------
def test_a_noisy_recording_of_a_moving_robot_is_imported(tmp_path):
    """The sweep checks must not refuse valid data: the 'moving' scenario at full motion level (consecutive periods
    correlate about 0.8) imports."""
    root = tmp_path
    (root / "small.yaml").write_text(SMALL_RIG)
    rig = Rig.load(root / "small.yaml")
    sc = Scenario.load("moving").replace(sessions=1, touch_s=0.5, moving_s=5.0, calibration_s=2.0,
                                         layout={"kind": "rings", "counts": [3], "spacing_cm": 1.2, "x0_cm": 2.4, "y0_cm": 11.9})
    simulate_dataset(sc, rig, root / "mv", progress=False, log=lambda *_: None)
    ds = Dataset(root / "mv")
    (root / "rec").mkdir()
    x = np.concatenate([sf.read(ds.root / "s000" / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts("s000")])
    sf.write(root / "rec" / "m.wav", x, int(rig.fs_hz), subtype="FLOAT")
    _, lab = ds.read_session("s000")
    rows = [HEADER]
    loc = lab["location"]
    edges = np.flatnonzero(np.diff(loc)) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, loc.size]):  # one row per press (a run of one location)
        if loc[a] >= 0:
            rows.append(["m.wav", f"{lab['t_s'][a] - 0.002:.6f}", f"{lab['t_s'][b - 1] + 0.002:.6f}", str(loc[a]), "", "", "", "0", "0"])
    _write(root / "labels.csv", rows)
    out = import_wav(root / "rec", root / "labels.csv", root / "imp", **_chirp(rig), **QUIET)
    np.testing.assert_array_equal(Dataset(out).read_session("s000")[1]["location"], lab["location"])


def test_a_loopback_channel_a_dropout_and_a_copied_recording_are_refused(src, inp, tmp_path):
    """Each was imported silently: the transmitter's loopback on channel 0 (flat features, no touch in them), half a
    second of zeros (the model verbs later refused the whole dataset without naming the file), and one recording under
    two names (two sessions of the same chirps)."""
    rec, labels, rows = inp
    _write(labels, rows)
    rig = src["rig"]
    ref = rig_chirp(rig).astype(np.float32) * rig.amplitude
    x, fs = sf.read(rec / "s000.wav", dtype="float32")
    sf.write(rec / "s000.wav", np.stack([np.resize(ref, x.size), x], 1), fs, subtype="FLOAT")
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(rig), **QUIET)
    assert msg.endswith("s000.wav: channel 0 is the transmitted sweep itself (correlation 1.000 with it), not a received one: "
                        "a loopback or the playback file; pass --channel N for the receiver's channel (the file has 2)"), msg
    sf.write(rec / "s000.wav", x, fs, subtype="FLOAT")

    def dropout(y):
        y = y.copy()
        y[300_000:396_000] = 0
        return y
    _edit(rec, "s001.wav", dropout)
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(rig), **QUIET)
    assert "s001.wav: 92 of" in msg and "sweeps are silent (the first is sweep 293, 1.567 s): a dropout in the recording" in msg
    shutil.copy(rec / "s000.wav", rec / "s001.wav")
    msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(rig), **QUIET)
    assert msg.endswith("s001.wav: holds the same samples as s000.wav: one recording would be two sessions (trained and "
                        "tested on twice); remove the copy"), msg
    assert not (tmp_path / "o").exists()


def test_location_names_differing_only_in_case_are_refused(src, tmp_path):
    names = np.array(["rest", "wrist", "Wrist ", "elbow"])
    table = _table(src, tmp_path, location=lambda z: names[z["location"] + 1], x_cm=None, y_cm=None)
    msg = _refused(import_spectra, table, tmp_path / "o", **QUIET)
    assert "t.npz: location names 'Wrist' and 'wrist' differ only in case or spaces" in msg, msg


def test_a_complete_session_whose_parts_are_gone_is_refused_not_skipped(src, tmp_path):
    d = tmp_path / "data"
    shutil.copytree(src["root"] / "data", d, ignore=shutil.ignore_patterns(".cache"))
    for p in (d / "s001").glob("part-*"):
        p.unlink()
    assert Dataset(d).sessions == ["s000", "s001"]
    with pytest.raises(SonicskinError) as e:
        Dataset(d).features(progress=False)
    assert "s001/part-00000.flac is missing but session.json lists it" in _one_line(e.value)


@pytest.mark.parametrize("over, words", [
    ({"noise": {"sensor_rms": "loud"}}, "noise.sensor_rms must be a finite number, got 'loud'"),  # was a TypeError
    ({"bond": {"tan_delta": "x"}}, "bond.tan_delta must be a finite number, got 'x'"),  # was a numpy UFuncNoLoopError
    ({"noise": {"sensor_rms": -1.0}}, "noise.sensor_rms must be >= 0, got -1.0"),
    ({"noise": {"pwm_harmonics": 2.5}}, "noise.pwm_harmonics must be a whole number >= 0, got 2.5"),
    ({"bond": {"fr_hz": -5.0}}, "bond.fr_hz must be > 0, got -5.0"),
    ({"channel": {"transducer_radius_m": 0.5}}, "channel.transducer_radius_m is the piezo discs' bonded radius in metres"),
])
def test_scenario_noise_bond_and_disc_values_are_checked(over, words):
    with pytest.raises(ValueError) as e:
        Scenario.from_dict(_tiny(**over))
    assert words in _one_line(e.value)


def test_a_misspelled_array_of_the_table_is_refused(src, tmp_path):
    """'force' instead of 'force_n' was ignored: the dataset said 'no force sensor' and the forces were lost."""
    z = dict(src["table"])
    z["force"] = z.pop("force_n")
    np.savez(tmp_path / "t.npz", **z)
    msg = _refused(import_spectra, tmp_path / "t.npz", tmp_path / "o", **QUIET)
    assert "t.npz: array 'force' is not one the importer reads; did you mean 'force_n'?" in msg, msg
    z["junk"] = z.pop("force")  # an array with an unrelated name is simply not read
    np.savez(tmp_path / "t.npz", **z)
    assert Dataset(import_spectra(tmp_path / "t.npz", tmp_path / "o", **QUIET)).sessions == ["s000", "s001"]


def test_a_file_named_cache_in_the_dataset_does_not_stop_training(src, tmp_path, capsys):
    """The feature cache is an optimisation: a file where its folder goes (or a full or read-only disk) was a one-line
    'Not a directory' error of fit-svm on a good dataset; now the features are simply not cached."""
    d = tmp_path / "data"
    shutil.copytree(src["root"] / "data", d, ignore=shutil.ignore_patterns(".cache"))
    (d / ".cache").write_text("not a folder")
    code, _, err = run(capsys, ["fit-svm", "--data", d, "--out", tmp_path / "art", "--n-bins", "40", "--mode", "absolute"])
    assert code == 0, err
    assert (tmp_path / "art" / "skin.json").is_file() and (d / ".cache").read_text() == "not a folder"


def test_a_pwm_line_the_recording_cannot_hold_is_refused(src, inp, tmp_path, capsys):
    """--pwm-hz 500000 (for 50000) on 192 kHz recordings notched nothing and was accepted; a negative line too."""
    rec, labels, rows = inp
    _write(labels, rows)
    code, _, err = run(capsys, ["import-wav", "--wav-dir", rec, "--labels", labels, "--out", tmp_path / "o", "--chirp", "20000",
                                "80000", "--period", str(src["rig"].period_s), "--pwm-hz", "500000"])
    assert assert_one_line_error(code, err, "import-wav").endswith(
        "pwm_hz 500000 Hz is outside 0..192000 Hz (the sample rate); the PWM lines to notch are frequencies of the motors' drive: "
        "check the value")
    with pytest.raises(ValueError, match="pwm_hz -30000 Hz is outside"):
        Rig(pwm_hz=[-30000.0])
    assert not (tmp_path / "o").exists()
    # The paper's 30/60/90 kHz default on a 96 kHz interface is no typo: 60 and 90 kHz lie beyond its band.
    assert Rig(fs_hz=96_000, f_hi_hz=40_000).pwm_hz == (30_000.0, 60_000.0, 90_000.0)


def test_resume_of_an_import_made_before_the_file_list_was_recorded(src, inp, tmp_path):
    import json

    rec, labels, rows = inp
    _write(labels, rows)
    out = import_wav(rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    meta = json.loads((out / "dataset.json").read_text())
    del meta["source"]["files"], meta["source"]["labels_sha256"]
    (out / "dataset.json").write_text(json.dumps(meta))
    msg = _refused(import_wav, rec, labels, out, **_chirp(src["rig"]), mode="resume", **QUIET)
    assert msg.endswith("o: it was imported by an older sonicskin that did not record which files it holds; pass --overwrite "
                        "to import every recording again"), msg


def test_many_overlapping_intervals_are_checked_in_linear_time(src, inp, tmp_path):
    """20 000 copies of one interval took 74 s (every pair compared); a chain of overlaps is still checked link by link."""
    rec, labels, rows = inp
    _write(labels, rows + [list(rows[1]) for _ in range(20_000)])
    out = import_wav(rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)  # its time: benchmarks/bench_input_checks.py
    assert Dataset(out).sessions == ["s000", "s001"]
    a0, a1 = float(rows[1][1]), float(rows[1][2])
    chain = [list(rows[1]), list(rows[1]), list(rows[1])]
    chain[1][1:3] = [f"{a0 + 0.1:.6f}", f"{a1 + 0.3:.6f}"]  # overlaps the first, reaches further
    chain[2][1:6] = [f"{a1 + 0.1:.6f}", f"{a1 + 0.4:.6f}", "1", *rows[2][4:6]]  # overlaps only the second; location 1
    _write(labels, [rows[0], *chain, *rows[2:]])
    msg = _refused(import_wav, rec, labels, tmp_path / "o2", **_chirp(src["rig"]), **QUIET)
    assert "labels.csv lines 3 and 4: the intervals" in msg and "overlap with different labels (location '0' vs '1')" in msg, msg


def test_a_table_with_a_location_per_row_is_fast_or_refused():
    """20 000 distinct locations took 13 s in label_layout (a marker lookup rebuilt per marker, then a K x K distance
    matrix: 200 000 would have needed 320 GB); more locations than a layout holds are refused in one line."""
    import tracemalloc

    from sonicskin.importers import label_layout

    n = 20_000
    tracemalloc.start()  # memory, not time (the suite runs at any load): a K x K matrix of 20 000 markers is 3.2 GB
    try:
        ids, layout, _ = label_layout(np.arange(n), np.arange(n) * 0.01, np.zeros(n), log=lambda *_: None)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200e6 and len(layout) == n  # its time: benchmarks/bench_input_checks.py
    np.testing.assert_array_equal(layout.coords(ids[:3]), [[0.0, 0.0], [0.01, 0.0], [0.02, 0.0]])
    with pytest.raises(SonicskinError, match="labels: 100001 distinct touch locations, more than a layout holds"):
        label_layout(np.arange(100_001), None, None, log=lambda *_: None)


def test_a_session_pasted_twice_into_a_table_is_refused(src, tmp_path):
    z = dict(src["table"])
    a = z["session"] == "s000"
    z = {k: (np.concatenate([v, v[a]]) if k != "freqs_hz" else v) for k, v in z.items()}
    z["session"][-int(a.sum()):] = "s009"
    np.savez(tmp_path / "t.npz", **z)
    msg = _refused(import_spectra, tmp_path / "t.npz", tmp_path / "o", **QUIET)
    assert "t.npz: sessions 's000' and 's009' hold the same spectra row for row" in msg, msg


def test_a_recording_of_barely_two_sweeps_is_one_line(src, inp, tmp_path):
    """Two sweeps' worth of samples starting mid-sweep hold one whole sweep: the checks took means of empty arrays
    (numpy warnings printed as 'sonicskin: warning' lines) and the import went on."""
    rec, labels, rows = inp
    _write(labels, [rows[0], ["s000.wav", "0.0", "0.005", "0", "9.4", "12.5", "2.5", "0", "0"],
                    ["s000.wav", "0.005", "0.01", "1", "10.6", "12.5", "2.5", "0", "0"]])
    x, fs = sf.read(rec / "s000.wav", dtype="float32")
    for p in rec.iterdir():
        p.unlink()
    sf.write(rec / "s000.wav", x[500:500 + 2048 + 10], fs, subtype="FLOAT")
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        msg = _refused(import_wav, rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    assert not seen, [str(w.message) for w in seen]
    assert "s000.wav: holds 1 whole sweep of 1024 samples after the first sweep start; a recording needs at least two" in msg


def test_a_temperature_outside_what_a_link_can_be_at_is_refused_before_simulating(src, tmp_path, capsys):
    """ambient_c 1e6 simulated with five numpy 'divide by zero' warning lines, then failed writing the first part; now
    it is refused before any work."""
    import yaml

    (tmp_path / "sc.yaml").write_text(yaml.safe_dump(_tiny(temperature={"ambient_c": 1e6})))
    code, _, err = run(capsys, ["simulate", "--scenario", tmp_path / "sc.yaml", "--rig", src["root"] / "small.yaml", "--out",
                                tmp_path / "o"])
    line = assert_one_line_error(code, err, "simulate")
    assert "warning" not in err and line.endswith("temperature: ambient_c, warmup_c and swing_c reach 1e+06..1e+06 C, outside "
                                                   "the -100..200 C a link can be at; give degrees Celsius"), err
    with pytest.raises(ValueError, match=r"reach -127..178.6 C"):
        Scenario.from_dict(_tiny(temperature={"ambient_c": 23.0, "warmup_c": 5.6, "swing_c": -150.0}))


def test_times_in_minutes_get_a_warning(src, inp, tmp_path):
    """Intervals in minutes still fall inside the recordings (each holds a sweep start or two): not refusable, but
    every one ending in the first fifth of its recording is named."""
    import warnings

    rec, labels, rows = inp
    _write(labels, [rows[0], *[[r[0], f"{float(r[1]) / 60:.6f}", f"{float(r[2]) / 60:.6f}", *r[3:]] for r in rows[1:]]])
    with pytest.warns(UserWarning, match=r"labels.csv: every interval ends in the first fifth of its recording \(the last "
                                         r"at 0.0\d+ s; s00\d.wav is 5.\d+ s long\): are the times in seconds\?"):
        import_wav(rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    _write(labels, rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the clean labels: no such warning
        import_wav(rec, labels, tmp_path / "clean", **_chirp(src["rig"]), **QUIET)


def test_a_recording_without_label_rows_is_imported_as_hands_off_with_a_warning(src, inp, tmp_path):
    """Every row of one recording dropped from the labels: it became a session of rest, without a word."""
    from sonicskin.dataset import Dataset

    rec, labels, rows = inp
    last = rows[-1][0]
    _write(labels, [r for r in rows if r[0] != last])
    with pytest.warns(UserWarning, match=rf"labels.csv has no row for {last}: imported as hands-off \(no touch in it\); "
                                         r"if a recording holds presses, add their rows"):
        import_wav(rec, labels, tmp_path / "o", **_chirp(src["rig"]), **QUIET)
    ds = Dataset(tmp_path / "o")
    t = ds.features(progress=False)
    assert (t["location"][t["session"] == ds.sessions[-1]] < 0).all() and (t["location"] >= 0).any()


def test_forces_in_the_wrong_unit_are_reported_and_named_when_nothing_can_train(src, tmp_path, capsys):
    # Forces in kN (or a sensor's raw scale): every touch lighter than a press, so no chirp counts as a touch. The
    # import warns, and training says why it has no touch chirps instead of only that it has none.
    table = _table(src, tmp_path, force_n=lambda z: z["force_n"] / 1000)
    with pytest.warns(UserWarning, match=r"t\.npz: (\d+) of the \1 labelled touch chirps have force_n below 0\.5 N .*"
                                         r"force_n must be in newtons \(empty: no force sensor\)"):
        import_spectra(table, tmp_path / "kn", **QUIET)
    code, _, err = run(capsys, ["fit-svm", "--data", tmp_path / "kn", "--out", tmp_path / "art"])
    line = assert_one_line_error(code, err, "fit-svm")
    assert "OSPA needs touch chirps in the training split; got 0 (" in line and "must be in newtons" in line, line
    # One force on every touch is a placeholder: no force sensor, localization only (not every touch dropped).
    logged = []
    out = import_spectra(_table(src, tmp_path, force_n=lambda z: np.zeros(len(z["location"]))), tmp_path / "zero",
                         log=logged.append)
    assert f"{tmp_path / 't.npz'}: force_n is 0 N on every touch, a placeholder: taken as no force sensor (localization only)" in logged
    t = Dataset(out).features(progress=False)
    assert np.isnan(t["force_n"][t["location"] >= 0]).all()


def test_missing_label_and_sweep_files_are_named(src, inp, tmp_path):
    rec, labels, rows = inp
    _write(labels, rows)
    msg = _refused(import_wav, rec, tmp_path / "gone.csv", tmp_path / "out", **_chirp(src["rig"]), **QUIET)
    assert msg == f"{tmp_path / 'gone.csv'}: no such file; give the label CSV of touch intervals", msg
    msg = _refused(import_wav, rec, labels, tmp_path / "out", sweep_wav=tmp_path / "gone.wav", **QUIET)
    assert msg == f"{tmp_path / 'gone.wav'}: no such file", msg


def test_training_on_an_unfinished_session_says_so(src, tmp_path, capsys):
    shutil.copytree(src["root"] / "data", tmp_path / "d")
    (tmp_path / "d" / "s001" / "session.json").unlink()  # stopped before it was complete
    from sonicskin.fit import prepare
    with pytest.warns(UserWarning, match=r"session\(s\) s001 stopped before they were complete .*--resume"):
        prepare(tmp_path / "d", train_sessions=["s000", "s001"], allow_no_test=True, progress=False, log=lambda *_: None)
    code, _, err = run(capsys, ["evaluate", "--data", tmp_path / "d", "--val", "s009"])
    assert assert_one_line_error(code, err, "evaluate").endswith(f"session(s) s009 are not in {tmp_path / 'd'} (it has s000, s001)")


@pytest.mark.parametrize("verb", ["evaluate", "compare", "fit-svm"])
def test_an_out_that_is_a_file_is_refused_before_any_work(src, tmp_path, capsys, verb):
    (tmp_path / "report").write_text("keep me")
    code, out, err = run(capsys, [verb, "--data", src["root"] / "data", "--out", tmp_path / "report"])
    line = assert_one_line_error(code, err, verb)
    assert line.endswith(f"--out {tmp_path / 'report'} is a file; give a folder for what this writes (it is created)")
    assert out == "" and (tmp_path / "report").read_text() == "keep me"  # nothing was trained or written
