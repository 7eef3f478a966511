"""The shipped examples (examples/): every verb runs on them, from import to compare, as the README walks through."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from sonicskin.cli import main
from sonicskin.dataset import Dataset

EX = Path(__file__).resolve().parents[1] / "examples"


def _cli(*args) -> int:
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def lab_c(tmp_path_factory):
    """The touch-only spectra table: foreign band, float cm labels, no force, no rig file, no dB offset."""
    out = tmp_path_factory.mktemp("ex") / "lab-c"
    assert _cli("import-spectra", "--table", EX / "spectra/touches.npz", "--out", out) == 0
    return out


@pytest.fixture(scope="module")
def lab_b(tmp_path_factory):
    out = tmp_path_factory.mktemp("ex") / "lab-b"
    assert _cli("import-wav", "--wav-dir", EX / "wav/recordings", "--labels", EX / "wav/labels.csv",
                "--sweep", EX / "wav/sweep.wav", "--out", out) == 0
    return out


def test_examples_are_small_and_complete():
    files = [p for p in EX.rglob("*") if p.is_file()]
    assert sum(p.stat().st_size for p in files) < 3e6
    assert {p.name for p in files} >= {"make_examples.py", "touches.npz", "labels.csv", "sweep.wav", "s0.wav", "s1.wav", "s2.wav"}


def test_spectra_example_imports_without_a_rig(lab_c, capsys):
    ds = Dataset(lab_c)
    # 48 kHz, 450-sample frames, 165 bins: from the axis alone (rounded to 0.1 Hz, off the grid by 3 Hz).
    assert (ds.rig.fs_hz, ds.rig.n_chirp, ds.rig.n_band) == (48_000, 450, 165)
    # Nine float positions 0.5 cm apart: nine locations (not truncated to integers), x = the label in cm.
    assert len(ds.layout) == 9
    np.testing.assert_allclose(ds.layout.xy_cm[:, 0], 1.5 + 0.5 * np.arange(9))
    assert ds.meta["source"]["labels"]["1"] == "2"
    assert ds.meta["source"]["gain_db"] < -60  # the +100 dB raw-FFT level is normalised away
    t = ds.features(progress=False)
    assert (t["location"] >= 0).all() and np.isnan(t["force_n"]).all()


def test_touch_only_evaluate_reports_what_it_can(lab_c, tmp_path, capsys):
    assert _cli("evaluate", "--data", lab_c, "--out", tmp_path / "rep") == 0
    text = capsys.readouterr().out
    rep = json.loads((tmp_path / "rep/report.json").read_text())
    assert rep["localization"]["accuracy"] > 0.8 and rep["localization"]["n"] == 720  # chance: 11 %
    assert rep["n_bins"] == 165  # gamma 300 clamped to the table's bins
    assert rep["detection"] == {"measurable": False, "reason": "not measurable on this data: no hands-off chirps"}
    assert rep["force"]["measurable"] is False and "no force sensor" in rep["force"]["reason"]
    assert "0.00 N" not in text and "not measurable on this data" in text and "absent: no force sensor" in text


@pytest.mark.slow
def test_touch_only_fit_svm_and_compare(lab_c, tmp_path, monkeypatch, capsys):
    pytest.importorskip("lightning")
    art = tmp_path / "art"
    assert _cli("fit-svm", "--data", lab_c, "--out", art) == 0
    skin = json.loads((art / "skin.json").read_text())
    # gamma chosen by cross-validation over the three folds' presses (issue 15), at most the table's 165 bins
    chosen = skin["selection"]["svm"]["params"]["n_bins"]
    assert skin["selection"]["svm"]["status"] == "validated" and 100 <= chosen <= 165
    assert skin["features"]["mode"] == "absolute" and len(skin["features"]["bins"]) == chosen
    assert skin["models"]["svm"]["detection"] is False and skin["models"]["svm"]["force"]["curves"] == {}
    monkeypatch.chdir(tmp_path)
    # The network's gamma is chosen the same way (validation session s001 here), within the table's 165 bins.
    assert _cli("compare", "--data", lab_c, "--runs", tmp_path / "runs", "--out", tmp_path / "cmp",
                "--trainer.max_epochs", "2", "--trainer.enable_progress_bar", "false") == 0
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    cmp_skin = json.loads((tmp_path / "runs/compare-lab-c/artifact/skin.json").read_text())
    # features.bins lists every usable bin (the network reads them all); the SVM reads the first n_bins (OSPA order)
    n_svm = cmp_skin["selection"]["svm"]["params"]["n_bins"]
    assert len(cmp_skin["features"]["bins"]) == 165 and cmp_skin["models"]["svm"]["n_in"] == n_svm <= 165
    for m in ("net", "svm"):
        r = res["models"][m]
        assert r["localization"]["accuracy"] > 0.5, m
        assert r["force"]["measurable"] is False and r["detection"]["measurable"] is False
    assert "0.00 N" not in capsys.readouterr().out


@pytest.mark.slow
def test_wav_example_runs_every_verb(lab_b, tmp_path, monkeypatch, capsys):
    ds = Dataset(lab_b)
    assert (ds.rig.fs_hz, ds.rig.n_chirp) == (16_000, 1600) and ds.rig.sweep() is not None
    assert sorted(ds.meta["source"]["labels"].values()) == ["A1", "A2", "B1", "B2", "C1", "C2"]
    assert _cli("evaluate", "--data", lab_b, "--out", tmp_path / "rep") == 0
    text = capsys.readouterr().out
    # 2.9 s of rest from mid-sweep: 29 whole sweeps, one short of beta = 3 s = 30; used with a note.
    assert "29 consecutive hands-off chirps, fewer than beta = 30" in text
    rep = json.loads((tmp_path / "rep/report.json").read_text())
    assert rep["beta_chirps"] == 29
    assert rep["localization"]["accuracy"] > 0.6  # chance: 17 %
    assert 0 <= rep["detection"]["false_touch_rate"] < 0.5 and 0 <= rep["detection"]["missed_touch_rate"] < 0.5
    assert 0 < rep["force"]["rmse_n"] < 5 and rep["force"]["xcorr"] > 0.5
    pytest.importorskip("lightning")
    assert _cli("fit-svm", "--data", lab_b, "--out", tmp_path / "art") == 0
    assert json.loads((tmp_path / "art/skin.json").read_text())["features"]["beta_s"] == pytest.approx(2.9)
    monkeypatch.chdir(tmp_path)
    assert _cli("compare", "--data", lab_b, "--runs", tmp_path / "runs", "--out", tmp_path / "cmp",
                "--data.n_bins", "60", "--trainer.max_epochs", "2", "--trainer.enable_progress_bar", "false") == 0
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    assert res["models"]["svm"]["localization"]["accuracy"] > 0.5
    assert np.isfinite(res["models"]["svm"]["force"]["rmse_n"])


def test_make_examples_is_the_source(tmp_path, monkeypatch):
    """The committed script regenerates the committed table (same rows, labels and axis)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_examples", EX / "make_examples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.spectra_example(tmp_path / "spectra", tmp_path)
    with np.load(tmp_path / "spectra/touches.npz") as new, np.load(EX / "spectra/touches.npz") as old:
        for k in ("freqs_hz", "location", "session"):
            np.testing.assert_array_equal(new[k], old[k])
        np.testing.assert_allclose(new["magnitude_db"], old["magnitude_db"], atol=0.02)
    shutil.rmtree(tmp_path / "spectra")
