"""Importers: WAV recordings of any sweep and rate, and tables of spectra, round-trip into the dataset format."""

import csv

import numpy as np
import pytest
import soundfile as sf

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.dsp import rig_chirp
from sonicskin.importers import import_spectra, import_wav
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


def test_spectra_import_round_trip(source, tmp_path, rig):
    _, ds = source
    t = ds.features(progress=False)
    table = tmp_path / "spectra.npz"
    np.savez(table, freqs_hz=rig.freqs_hz[rig.band_bins], magnitude_db=t.X.astype(float), location=t["location"],
             x_cm=np.nan_to_num(t["x_cm"]), y_cm=np.nan_to_num(t["y_cm"]), session=t["session"], force_n=t["force_n"])
    out = import_spectra(table, tmp_path / "imp", rig=rig, log=lambda *_: None)
    b = Dataset(out).features(progress=False)
    np.testing.assert_array_equal(b["location"], t["location"])
    strong = t.X > -80  # 24-bit audio in between: deep notches sit near its noise floor
    np.testing.assert_allclose(b.X[strong], t.X[strong], atol=0.05)
    # It trains like simulated data (this tiny set has 1 s of rest per session: absolute features).
    assert main(["fit-svm", "--data", str(out), "--out", str(tmp_path / "art"), "--n-bins", "40"]) == 2
    assert main(["fit-svm", "--data", str(out), "--out", str(tmp_path / "art"), "--n-bins", "40", "--mode", "absolute"]) == 0


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
    np.savez(table, freqs_hz=np.linspace(30e3, 50e3, 10), magnitude_db=np.zeros((2, 10)), location=np.array([0, 1]),
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
