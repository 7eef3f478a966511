"""``sonicskin <verb>``: the cases of issue 9.5 (one clear line, nothing half-made) and issue 11's
"one set of options on every verb"."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run

from sonicskin.cli import build_parser

MODEL_VERBS = ("evaluate", "fit-svm", "train", "export", "compare")


def _tree(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# -- values checked while parsing --------------------------------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    (["simulate", "--set", "sessions=abc"], ["sessions", "whole number"]),
    (["simulate", "--set", "no_such_key=1"], ["no_such_key", "valid keys"]),
    (["simulate", "--set", "peak_force_n=3"], ["peak_force_n", "list"]),
    (["simulate", "--set", "novalue"], ["KEY=VALUE"]),
    (["simulate", "--sessions", "0"], ["--sessions", "> 0"]),
    (["live", "--udp", "notaport"], ["--udp", "1-65535"]),
    (["live", "--udp", "host:0"], ["port must be 1-65535"]),
    (["live", "--duration", "-1"], ["--duration", "> 0"]),
    (["live", "--duration", "nan"], ["--duration", "finite"]),
    (["record", "--out", "x", "--touch-s", "0"], ["--touch-s", "> 0"]),
    (["fit-svm", "--data", "d", "--out", "a", "--n-bins", "-3"], ["--n-bins", "> 0"]),
    (["evaluate", "--data", "d", "--mode", "sideways"], ["--mode", "invalid choice"]),
    (["evaluate", "--data", "d", "--bogus"], ["unrecognized arguments: --bogus"]),
    (["nosuchverb"], ["invalid choice"]),
])
def test_bad_values_are_one_line(capsys, tmp_path, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, argv)
    line = assert_one_line_error(code, err)
    for w in words:
        assert w in line
    assert _tree(tmp_path) == []  # nothing written


def test_simulate_set_is_typed_against_the_scenario(capsys, tmp_path, cli_files):
    out = tmp_path / "d"
    code, _, err = run(capsys, ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--out", out,
                                "--quiet", "--set", "sessions=1", "--set", "touch_s=0.3", "--set", "calibration_s=1"])
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "s000"]


# -- files that are not what they claim ---------------------------------------------------------------------
def test_dataset_json_that_is_a_list(capsys, tmp_path):
    (tmp_path / "dataset.json").write_text("[1, 2, 3]")
    for argv in (["evaluate", "--data", tmp_path], ["fit-svm", "--data", tmp_path, "--out", tmp_path / "art"]):
        line = assert_one_line_error(*run(capsys, argv)[::2])
        assert "JSON object" in line and "got a JSON list" in line
    assert not (tmp_path / "art").exists()


def test_export_of_a_file_that_is_no_checkpoint(capsys, tmp_path):
    line = assert_one_line_error(*run(capsys, ["export", "--run", "README.md", "--out", tmp_path / "a"])[::2], "export")
    assert "not a checkpoint" in line
    pytest.importorskip("torch")
    fake = tmp_path / "fake.ckpt"
    fake.write_bytes(b"#!/bin/sh\nnot a pickle at all\n")
    line = assert_one_line_error(*run(capsys, ["export", "--run", fake, "--out", tmp_path / "a"])[::2], "export")
    assert "checkpoint" in line and str(fake) in line and "sonicskin train" in line
    assert not (tmp_path / "a").exists()


def test_compare_with_a_missing_artifact(capsys, cli_files):
    line = assert_one_line_error(*run(capsys, ["compare", "--data", cli_files["data"], "--artifact", "artifacts/nope"])[::2],
                                 "compare")
    assert "artifacts/nope is not a sonicskin artifact" in line and "fit-svm" in line


def test_export_refuses_split_options(capsys, tmp_path):
    line = assert_one_line_error(*run(capsys, ["export", "--run", tmp_path, "--out", tmp_path / "a", "--n-bins", "40"])[::2])
    assert "checkpoint" in line and "sonicskin train" in line


# -- live ------------------------------------------------------------------------------------------------------
def _strict_json(text: str):
    def no_constants(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=no_constants)


def test_live_summary_is_strict_json_even_without_chirps(capsys, cli_files):
    code, _, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--scenario", cli_files["scenario"],
                                "--rig", cli_files["rig"], "--fast", "--duration", "0.002", "--no-status"])
    assert code == 0, err
    summary = _strict_json(err.strip().splitlines()[-1])["summary"]
    assert summary["chirps"] == 0 and summary["latency_ms_median"] is None


def test_live_refuses_an_artifact_of_another_layout(capsys, cli_files):
    # The 3-marker artifact on the 36-marker aluminium plate (its own rig would also differ: the layout is checked first).
    line = assert_one_line_error(*run(capsys, ["live", "--artifact", cli_files["artifact"], "--scenario", "plate-aluminium",
                                               "--rig", cli_files["rig"], "--fast", "--duration", "1"])[::2], "live")
    assert "3 markers" in line and "36" in line


def test_live_net_without_artifact_fails_before_any_work(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = assert_one_line_error(*run(capsys, ["live", "--model", "net", "--fast"])[::2], "live")
    assert "--artifact" in line and "sonicskin export" in line
    assert _tree(tmp_path) == []  # no one-shot dataset or SVM was made


# -- writers leave nothing half-made ------------------------------------------------------------------------
def test_record_without_portaudio_leaves_nothing(capsys, tmp_path, monkeypatch):
    from sonicskin import acquire

    def no_portaudio():
        raise acquire.AudioError("the PortAudio library is not installed; on Debian/Ubuntu: sudo apt-get install libportaudio2")

    monkeypatch.setattr(acquire, "import_sounddevice", no_portaudio)
    out = tmp_path / "rec"
    line = assert_one_line_error(*run(capsys, ["record", "--device", "0", "--out", out])[::2], "record")
    assert "PortAudio" in line
    assert not out.exists()


def _spectra_table(path, *, nan: bool = False):
    f = np.linspace(15e3, 85e3, 141)
    rng = np.random.default_rng(0)
    n = 60
    loc = np.repeat([-1, 0, 1], n // 3)
    mag = -40 + rng.normal(0, 1, (n, f.size)) + 3 * loc[:, None]
    if nan:
        mag[-1, 7] = np.nan  # in the last session: the first is read before
    np.savez(path, freqs_hz=f, magnitude_db=mag,
             location=loc, x_cm=np.where(loc >= 0, loc * 1.2, np.nan), y_cm=np.where(loc >= 0, 0.0, np.nan),
             session=np.repeat(["a", "b"], n // 2), force_n=np.where(loc >= 0, 2.0, 0.0))


def test_failed_import_leaves_nothing_and_the_retry_runs(capsys, tmp_path):
    bad, good, out = tmp_path / "bad.npz", tmp_path / "good.npz", tmp_path / "imported"
    _spectra_table(bad, nan=True)
    line = assert_one_line_error(*run(capsys, ["import-spectra", "--table", bad, "--out", out])[::2], "import-spectra")
    assert "NaN" in line
    assert _tree(tmp_path) == ["bad.npz"]  # no lone dataset.json, no staging folder
    _spectra_table(good)
    code, _, err = run(capsys, ["import-spectra", "--table", good, "--out", out])
    assert code == 0, err
    assert (out / "dataset.json").is_file() and sorted(p.name for p in out.iterdir() if p.is_dir()) == ["a", "b"]
    # The same flags as every writer: create refuses, --resume completes, --overwrite replaces.
    line = assert_one_line_error(*run(capsys, ["import-spectra", "--table", good, "--out", out])[::2])
    assert "--resume" in line and "--overwrite" in line
    shutil.rmtree(out / "b")
    assert run(capsys, ["import-spectra", "--table", good, "--out", out, "--resume"])[0] == 0
    assert (out / "b" / "session.json").is_file()
    assert run(capsys, ["import-spectra", "--table", good, "--out", out, "--overwrite"])[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "good.npz", "imported"]


def test_failed_simulate_leaves_nothing(capsys, tmp_path, cli_files, monkeypatch):
    from sonicskin.sim import generate

    def boom(*a, **k):
        raise ValueError("simulated failure before the first part")

    real = generate.simulate_dataset

    def fail_after_meta(sc, rig, out, **kw):
        from sonicskin.dataset import DatasetWriter
        DatasetWriter(out, rig, sc.make_layout(), source={}, mode=kw.get("mode", "create"))  # the lone dataset.json
        boom()

    monkeypatch.setattr(generate, "simulate_dataset", fail_after_meta)
    out = tmp_path / "d"
    argv = ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--out", out, "--quiet",
            "--set", "sessions=1", "--set", "calibration_s=1", "--set", "touch_s=0.3"]
    assert_one_line_error(*run(capsys, argv)[::2], "simulate")
    assert not out.exists()
    monkeypatch.setattr(generate, "simulate_dataset", real)
    code, _, err = run(capsys, argv)  # the retry is not blocked
    assert code == 0, err


# -- one set of options on every model verb ----------------------------------------------------------------
def _subparser(verb: str) -> argparse.ArgumentParser:
    return build_parser()._subparsers._group_actions[0].choices[verb]


@pytest.mark.parametrize("verb", MODEL_VERBS)
def test_model_verbs_share_the_options(verb):
    help_text = " ".join(_subparser(verb).format_help().split())
    for opt in ("--n-bins GAMMA", "--mode {relative,absolute}", "--train SESSION", "--val SESSION", "--test SESSION",
                "--test-subjects ID"):
        assert opt in help_text, (verb, opt)
    assert ("(default: chosen by validation in fit-svm, train, export and compare; the paper's 300 in evaluate; "
            "never more than the band's usable bins)") in help_text


def test_every_option_has_help_with_its_default():
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices
    missing = []
    for verb, sp in verbs.items():
        assert sp.description, f"`sonicskin {verb} --help` has no description"
        for act in sp._actions:
            if isinstance(act, argparse._HelpAction) or not act.option_strings or act.help == argparse.SUPPRESS:
                continue
            if act.help == "lightning_help" or act.dest == "help":
                continue
            if not act.help or (not act.required and "default" not in act.help):
                missing.append(f"{verb} {act.option_strings[0]}")
    assert not missing, missing


def test_default_gamma_is_chosen_within_the_usable_bins_but_an_explicit_one_is_checked(capsys, tmp_path, cli_files):
    # three sessions of one press per marker: gamma is chosen by cross-validation over the passes (issue 15)
    code, out, err = run(capsys, ["fit-svm", "--data", cli_files["data"], "--out", tmp_path / "a", "--mode", "absolute"])
    assert code == 0, err
    skin = json.loads((tmp_path / "a" / "skin.json").read_text())
    chosen = skin["selection"]["svm"]["params"]["n_bins"]
    assert skin["selection"]["svm"]["status"] == "validated" and 100 <= chosen <= 250
    assert len(skin["features"]["bins"]) == chosen and f"chose gamma {chosen}," in out
    line = assert_one_line_error(*run(capsys, ["fit-svm", "--data", cli_files["data"], "--out", tmp_path / "b",
                                               "--n-bins", "300"])[::2], "fit-svm")
    assert "--n-bins 300 is more than the 250 usable bins" in line
    assert not (tmp_path / "b").exists()


def test_split_options_are_checked_before_work(capsys, cli_files):
    line = assert_one_line_error(*run(capsys, ["evaluate", "--data", cli_files["data"], "--train", "s000",
                                               "--test", "s000"])[::2], "evaluate")
    assert "both --train and --test" in line
    line = assert_one_line_error(*run(capsys, ["evaluate", "--data", cli_files["data"], "--test", "s009"])[::2], "evaluate")
    assert "s009" in line and "s000, s001, s002" in line


def test_evaluate_takes_n_bins_mode_and_test(capsys, tmp_path, cli_files):
    code, out, err = run(capsys, ["evaluate", "--data", cli_files["data"], "--out", tmp_path / "r", "--n-bins", "40",
                                  "--mode", "absolute", "--train", "s001", "--test", "s002", "--no-ablations"])
    assert code == 0, err
    rep = json.loads((tmp_path / "r" / "report.json").read_text())
    assert rep["train_sessions"] == ["s001"] and rep["test_sessions"] == ["s002"]


def test_alpha_and_beta_options_reach_the_artifact(capsys, tmp_path, cli_files):
    """Alg. 2's refresh interval and reference length: one default each (FeatureSpec's), set by --alpha-s/--beta-s."""
    from sonicskin.features import FeatureSpec

    argv = ["fit-svm", "--data", cli_files["data"], "--n-bins", "40"]
    for opts, want in (([], (FeatureSpec.alpha_s, FeatureSpec.beta_s)), (["--alpha-s", "600", "--beta-s", "2"], (600, 2))):
        out = tmp_path / f"svm{len(opts)}"
        code, _, err = run(capsys, [*argv, "--out", out, *opts])
        assert code == 0, err
        skin = json.loads((out / "skin.json").read_text())
        assert (skin["features"]["alpha_s"], skin["features"]["beta_s"]) == want
        assert (skin["calibration"]["alpha_s"], skin["calibration"]["beta_s"]) == want
    line = assert_one_line_error(*run(capsys, [*argv, "--out", tmp_path / "bad", "--alpha-s", "1", "--beta-s", "2"])[::2])
    assert line == ("sonicskin fit-svm: error: --alpha-s 1 is shorter than the no-touch reference it refreshes "
                    "(--beta-s 2); give an interval of at least the reference's length")
    assert not (tmp_path / "bad").exists()


def test_alpha_and_beta_options_reach_the_network_artifact(capsys, tmp_path, cli_files):
    """train (LightningCLI's data.alpha_s/beta_s), export and its refit keep them: compare runs all three."""
    pytest.importorskip("lightning")
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--n-bins", "40", "--alpha-s", "900", "--beta-s",
                                "2.5", "--runs", tmp_path / "runs", "--out", tmp_path / "rep", "--trainer.max_epochs", "1"])
    assert code == 0, err
    skin = json.loads((tmp_path / "runs" / "compare-tiny" / "artifact" / "skin.json").read_text())
    assert skin["training"]["refit"] and (skin["features"]["alpha_s"], skin["features"]["beta_s"]) == (900, 2.5)


def test_train_tip_names_a_real_verb(capsys, cli_files):
    pytest.importorskip("lightning")
    line = assert_one_line_error(*run(capsys, ["train", "--data", cli_files["data"], "--trainer.bogus", "1"])[::2], "train")
    assert "--trainer.bogus" in line and "`sonicskin train --help`" in line
    assert "sonicskin fit" not in line


def test_real_processes_print_one_line(tmp_path):
    """A few runs as a user makes them (a new process, the package's own entry point)."""
    import os
    import subprocess
    import sys

    (tmp_path / "listdata").mkdir()
    (tmp_path / "listdata" / "dataset.json").write_text("[]")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    for argv, words in ((["live", "--udp", "notaport"], "--udp"), (["evaluate", "--data", "listdata"], "JSON object"),
                        (["simulate", "--set", "sessions=abc"], "sessions")):
        r = subprocess.run([sys.executable, "-m", "sonicskin", *argv], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and words in r.stderr and "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["listdata"]


def test_library_warnings_are_one_line(capsys, monkeypatch):
    import warnings

    from sonicskin.cli import data

    def warn_and_fail(a):
        warnings.warn("something to know\n  across lines", UserWarning, stacklevel=1)
        return 0

    monkeypatch.setattr(data, "cmd_info", warn_and_fail)
    code, _, err = run(capsys, ["info"])
    assert code == 0 and err == "sonicskin info: warning: something to know across lines\n"
