"""Importers: WAV recordings of any sweep and rate, and tables of spectra, round-trip into the dataset format."""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.dsp import rig_chirp
from sonicskin.importers import import_spectra, import_wav, label_layout, rig_from_axis
from sonicskin.importers._common import ImportDataError
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

SC = Scenario(sessions=2, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
              touch_s=1.0, gap_s=0.3, calibration_s=1.0, seed=8)


@pytest.fixture(scope="module")
def source(tmp_path_factory, rig):
    """A simulated dataset exported as a folder of WAVs + an interval label CSV, like another lab's data."""
    root = tmp_path_factory.mktemp("imp")
    simulate_dataset(SC, rig, root / "sim", progress=False, log=lambda *_: None)
    ds = Dataset(root / "sim")
    wavs = root / "wavs"
    wavs.mkdir()
    rows = []
    for s in ds.sessions:
        audio = np.concatenate([sf.read(ds.root / s / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(s)])
        sf.write(wavs / f"{s}.wav", audio, int(rig.fs_hz), subtype="FLOAT")
        _, lab = ds.read_session(s)
        loc = lab["location"]
        for ev in np.unique(loc[loc >= 0]):
            k = np.flatnonzero(loc == ev)
            half = rig.period_s / 2  # intervals cover their chirps with half a period to spare
            rows.append([f"{s}.wav", lab["t_s"][k[0]] - half, lab["t_s"][k[-1]] + half, int(ev),
                         *ds.layout.coords(np.array([ev]))[0], 2.0, 0, 0])
    with open(root / "labels.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n", "moving", "subject"])
        w.writerows(rows)
    sf.write(root / "sweep.wav", rig_chirp(rig).astype(np.float32), int(rig.fs_hz), subtype="FLOAT")
    return root, ds


@pytest.mark.parametrize("how", ["chirp", "sweep"])
def test_wav_import_round_trip(source, tmp_path, how, rig):
    root, ds = source
    if how == "chirp":
        kw = {"chirp_hz": (rig.f_lo_hz, rig.f_hi_hz), "period_s": rig.period_s, "amplitude": rig.amplitude}
    else:
        kw = {"sweep_wav": root / "sweep.wav"}
    out = import_wav(root / "wavs", root / "labels.csv", tmp_path / "imp", log=lambda *_: None, **kw)
    imp = Dataset(out)
    assert imp.sessions == ds.sessions and imp.rig.n_chirp == rig.n_chirp and imp.rig.fs_hz == rig.fs_hz
    a, b = ds.features(progress=False), imp.features(progress=False)
    # Same chirps, same labels, same features (the band of an imported sweep is found from its spectrum).
    np.testing.assert_array_equal(a["location"], b["location"])
    lo = np.searchsorted(imp.rig.freqs_hz[imp.rig.band_bins], rig.freqs_hz[rig.band_bins][0])
    common = min(a.X.shape[1], b.X.shape[1] - lo)
    np.testing.assert_allclose(a.X[:, :common], b.X[:, lo:lo + common], atol=0.05)
    if how == "sweep":
        assert imp.rig.sweep() is not None and "the transmitted sweep differs" in imp.rig.mismatch(rig)


def test_spectra_import_round_trip(source, tmp_path, rig, capsys):
    _, ds = source
    t = ds.features(progress=False)
    table = tmp_path / "spectra.npz"
    np.savez(table, freqs_hz=rig.freqs_hz[rig.band_bins], magnitude_db=t.X.astype(float), location=t["location"],
             x_cm=np.nan_to_num(t["x_cm"]), y_cm=np.nan_to_num(t["y_cm"]), session=t["session"], force_n=t["force_n"])
    out = import_spectra(table, tmp_path / "imp", rig=rig, log=lambda *_: None)
    imp = Dataset(out)
    b = imp.features(progress=False)
    np.testing.assert_array_equal(b["location"], t["location"])
    # Levels are normalised (peak -6 dBFS); the gain is stored, and undoing it gives the table back.
    gain = imp.meta["source"]["gain_db"]
    strong = t.X > -80 + max(0.0, -gain)  # 24-bit audio in between: deep notches sit near its noise floor
    np.testing.assert_allclose(b.X[strong] - gain, t.X[strong], atol=0.05)
    # It trains like simulated data.  This tiny set has 1 s (9 chirps) of rest per session, less than
    # the minimum reference of 10 chirps: relative inputs fall back to absolute ones, with a warning.
    capsys.readouterr()
    assert main(["fit-svm", "--data", str(out), "--out", str(tmp_path / "art"), "--n-bins", "40"]) == 0
    assert "sonicskin fit-svm: warning:" in (err := capsys.readouterr().err) and "using absolute features" in err, err
    assert json.loads((tmp_path / "art/skin.json").read_text())["features"]["mode"] == "absolute"
    assert main(["fit-svm", "--data", str(out), "--out", str(tmp_path / "art2"), "--n-bins", "40", "--mode", "absolute"]) == 0


def test_importers_reject_malformed_input(source, tmp_path, rig):
    root, _ = source
    bad = tmp_path / "bad.csv"
    bad.write_text("file,start,end\nx.wav,0,1\n")
    with pytest.raises(ValueError, match="lacks columns"):
        import_wav(root / "wavs", bad, tmp_path / "o1", chirp_hz=(20e3, 80e3), period_s=rig.period_s)
    bad.write_text("file,start_s,end_s,location,x_cm,y_cm\nnope.wav,0,1,0,1,1\n")
    with pytest.raises(ValueError, match="not in"):
        import_wav(root / "wavs", bad, tmp_path / "o2", chirp_hz=(20e3, 80e3), period_s=rig.period_s)
    with pytest.raises(ValueError, match="give the transmitted sweep"):
        import_wav(root / "wavs", root / "labels.csv", tmp_path / "o3")
    odd = tmp_path / "wavs"
    odd.mkdir()
    sf.write(odd / "a.wav", np.zeros(48000, np.float32), 48000)
    sf.write(odd / "b.wav", np.zeros(44100, np.float32), 44100)
    bad.write_text("file,start_s,end_s,location,x_cm,y_cm\na.wav,0,1,0,1,1\n")
    with pytest.raises(ValueError, match="different sample rates"):
        import_wav(odd, bad, tmp_path / "o4", chirp_hz=(5e3, 15e3), period_s=0.1)
    table = tmp_path / "t.npz"
    np.savez(table, freqs_hz=np.linspace(30e3, 50e3, 10), magnitude_db=np.full((2, 10), -20.0), location=np.array([0, 1]),
             x_cm=np.array([0.0, 1.0]), y_cm=np.array([0.0, 0.0]), session=np.array(["a", "a"]))
    with pytest.raises(ValueError, match="the rig's band is"):
        import_spectra(table, tmp_path / "o5", rig=rig)
    np.savez(table, freqs_hz=np.linspace(10e3, 90e3, 10), magnitude_db=np.full((2, 10), np.nan), location=np.array([0, 1]),
             x_cm=np.array([0.0, 1.0]), y_cm=np.array([0.0, 0.0]), session=np.array(["a", "a"]))
    with pytest.raises(ValueError, match="NaN"):
        import_spectra(table, tmp_path / "o6", rig=rig)
    with pytest.raises(ValueError, match="missing arrays"):
        np.savez(table, freqs_hz=np.arange(3))
        import_spectra(table, tmp_path / "o7", rig=Rig())


# -- data as it comes -----------------------------------------------------------------

@pytest.mark.parametrize("axis, fs, n", [
    (np.arange(23, 188) * 48000 / 450, 48_000, 450),                # bin centres, exact
    (np.round(np.linspace(2450, 19950, 165), 1), 48_000, 450),       # as a plot labels it: off by 3 Hz
    (np.arange(23, 188) * 48000 / 450 - 48000 / 900, 48_000, 450),   # bin edges instead of centres
    (np.arange(2134, 8534) * 9.375, 192_000, 20_480),                # the paper's rig
])
def test_rig_from_axis_known_answers(axis, fs, n):
    r = rig_from_axis(axis, log=lambda *_: None)
    assert (r.fs_hz, r.n_chirp, r.n_band) == (fs, n, axis.size)


def test_rig_from_axis_takes_fs_or_frame_and_refuses_nonsense():
    axis = np.round(np.linspace(2450, 19950, 165), 1)
    assert rig_from_axis(axis, frame=450, log=lambda *_: None).fs_hz == 48_000
    assert rig_from_axis(axis, fs_hz=96_000, log=lambda *_: None).n_chirp == 900
    with pytest.raises(ValueError, match="check both"):
        rig_from_axis(axis, fs_hz=48_000, frame=400)
    with pytest.raises(ValueError, match="not evenly spaced"):
        rig_from_axis(np.r_[1000.0, 1100.0, 1300.0, 1400.0])
    with pytest.raises(ValueError, match="above the Nyquist"):
        rig_from_axis(axis, fs_hz=30_000)


def test_labels_of_any_kind_become_a_layout():
    out = []
    ids, layout, names = label_layout(np.array([1.5, 2.0, 2.5, -1.0, 1.5, np.nan]), log=out.append)
    # Floats are positions in cm: three locations, never truncated to integers.
    assert ids.tolist() == [0, 1, 2, -1, 0, -1] and names == {0: "1.5", 1: "2", 2: "2.5"}
    np.testing.assert_allclose(layout.xy_cm, [[1.5, 0], [2.0, 0], [2.5, 0]])
    assert any("1.5 ->   0" in line for line in out)
    ids, layout, names = label_layout(["7", "3", "", "7"], [8.4, 1.0, np.nan, 8.4], [1.2, 0.0, np.nan, 1.2], log=out.append)
    assert ids.tolist() == [7, 3, -1, 7] and layout.ids == (3, 7)  # integers stay ids
    np.testing.assert_allclose(layout.coords(np.array([7])), [[8.4, 1.2]])
    with pytest.warns(UserWarning, match="placed 1 cm apart"):
        ids, layout, names = label_layout(np.array(["wrist", "elbow", "none", "wrist"]), log=out.append)
    assert ids.tolist() == [1, 0, -1, 1] and names == {0: "elbow", 1: "wrist"}
    with pytest.raises(ValueError, match="need at least two"):
        label_layout(["a", "a", "rest"], log=out.append)


def _table(path, **kw):
    f = np.round(np.linspace(2450, 19950, 165), 1)
    rng = np.random.default_rng(0)
    loc = np.repeat([0.5, 1.0, 1.5], 20)
    z = {"freqs_hz": f, "magnitude_db": 60 + 3 * rng.standard_normal((loc.size, f.size)) + 5 * loc[:, None],
         "location": loc, "session": np.repeat(["a", "b"], 30)}
    z.update(kw)
    np.savez(path, **z)
    return path


def test_spectra_import_is_all_or_nothing_and_resumes(tmp_path):
    quiet = dict(log=lambda *_: None)
    table = _table(tmp_path / "t.npz")
    bad = _table(tmp_path / "bad.npz", session=np.array(["a"] * 30 + ["b"] * 29 + ["c"]),
                 force_n=np.r_[np.ones(59), np.nan])
    out = tmp_path / "ds"
    # A failure half-way (here: the writer refuses an unknown mode) leaves nothing behind.
    with pytest.raises(ValueError, match="mode must be"):
        import_spectra(table, out, mode="append", **quiet)
    assert not out.exists() and not any(tmp_path.glob(".ds*"))
    import sonicskin.importers.spectra as imp

    calls = []
    real = imp._write_session

    def fail_second(w, s, *a):
        calls.append(s)
        if len(calls) == 2:
            raise RuntimeError("disk full")
        return real(w, s, *a)

    imp._write_session = fail_second
    try:
        with pytest.raises(RuntimeError, match="disk full"):
            import_spectra(bad, out, **quiet)
    finally:
        imp._write_session = real
    assert not out.exists() and not any(tmp_path.glob(".ds*"))
    import_spectra(table, out, **quiet)
    with pytest.raises(FileExistsError, match="--resume .* --overwrite"):
        import_spectra(table, out, **quiet)
    assert main(["import-spectra", "--table", str(table), "--out", str(out)]) == 2
    # --resume keeps finished sessions (and re-imports one whose folder was lost).
    shutil.rmtree(out / "b")
    first = (out / "a" / "part-00000.flac").stat().st_mtime_ns
    assert main(["import-spectra", "--table", str(table), "--out", str(out), "--resume"]) == 0
    assert (out / "a" / "part-00000.flac").stat().st_mtime_ns == first and Dataset(out).sessions == ["a", "b"]
    assert main(["import-spectra", "--table", str(table), "--out", str(out), "--overwrite"]) == 0
    assert Dataset(out).features(progress=False).X.shape == (60, 165)


def test_spectra_import_refuses_linear_magnitudes_without_linear(tmp_path):
    db = np.load(_table(tmp_path / "t.npz"))["magnitude_db"]
    # Spread over orders of magnitude, they would span thousands of "dB" and import as silence: refused.
    table = _table(tmp_path / "lin.npz", magnitude_db=10 ** (db / 20))
    with pytest.raises(ImportDataError, match=r"spans \d\.\d+e\+03 dB .*: they look like linear magnitudes: import with --linear"):
        import_spectra(table, tmp_path / "a", log=lambda *_: None)
    assert not (tmp_path / "a").exists()
    # Below 1 they span less than a dB: imported, with a warning.
    with pytest.warns(UserWarning, match="looks linear.*--linear"):
        import_spectra(_table(tmp_path / "small.npz", magnitude_db=10 ** ((db - 100) / 20)), tmp_path / "s", log=lambda *_: None)
    a = Dataset(import_spectra(table, tmp_path / "b", linear=True, log=lambda *_: None)).features(progress=False)
    ref = Dataset(import_spectra(tmp_path / "t.npz", tmp_path / "c", log=lambda *_: None))
    # --linear converts with 20 log10: the same dataset as the dB table, up to the normalising gain.
    b = ref.features(progress=False)
    np.testing.assert_allclose(a.X - a.X.mean(), b.X - b.X.mean(), atol=0.05)


def test_wav_import_resume_and_overwrite_on_the_shipped_example(tmp_path, capsys):
    ex = Path(__file__).resolve().parents[1] / "examples" / "wav"
    args = ["import-wav", "--wav-dir", str(ex / "recordings"), "--labels", str(ex / "labels.csv"), "--sweep",
            str(ex / "sweep.wav"), "--out", str(tmp_path / "ds")]
    assert main(args) == 0
    assert main(args) == 2 and "pass --resume to continue it or --overwrite" in capsys.readouterr().err
    shutil.rmtree(tmp_path / "ds" / "s002")
    assert main(args + ["--resume"]) == 0 and "2 were there already" in capsys.readouterr().out
    assert Dataset(tmp_path / "ds").sessions == ["s000", "s001", "s002"]
    assert main(args + ["--overwrite"]) == 0 and not any(tmp_path.glob(".ds*"))
    # Labels the CSV cannot hold: one clear line, nothing written.
    bad = tmp_path / "bad.csv"
    bad.write_text("file,start_s,end_s,location\ns0.wav,1,2,A1\n")
    assert main(args[:4] + [str(bad)] + args[5:-1] + [str(tmp_path / "new")]) == 2
    assert "need at least two" in capsys.readouterr().err and not (tmp_path / "new").exists()
