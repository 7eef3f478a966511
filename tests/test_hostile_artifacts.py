"""Hostile inputs found by probing the artifact, training and live verbs by hand (notes/hostart-probes.md):
each case failed (a traceback or a silently wrong result) before its fix and must now be one clear line.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, refusal, refusals, run

from sonicskin.integrity import artifact_digest


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _edit_resealed(art: Path, edit) -> None:
    """Edit ``skin.json`` and recompute its digest with the package's own function, as a careful tamperer would."""
    meta = json.loads((art / "skin.json").read_text())
    edit(meta)
    meta["digest"] = artifact_digest(meta)
    (art / "skin.json").write_text(json.dumps(meta, indent=1))


# -- skin.json's selection report: free-form before, read by compare --artifact ------------------------------------
SELECTION_EDITS = [
    ("svm-a-string", lambda s: s.__setitem__("svm", "x"), r"selection\.svm must be a JSON object, got str"),
    ("params-missing", lambda s: s["svm"].pop("params"),
     r"selection is not the report model selection writes \(reading it fails with KeyError 'params'\)"),
    ("accuracy-a-string", lambda s: s["svm"]["estimate"].__setitem__("accuracy", "high"),
     r"selection is not the report model selection writes \(reading it fails with ValueError: Unknown format code"),
]


@pytest.mark.parametrize("name, edit, pattern", SELECTION_EDITS, ids=[c[0] for c in SELECTION_EDITS])
def test_a_broken_selection_report_is_one_line(cli_files, tmp_path, capsys, name, edit, pattern):
    """``compare --artifact`` prints the artifact's selection report; a resealed skin.json whose report is not
    what model selection writes ended in an AttributeError/KeyError traceback there."""
    import re

    art = _copy(cli_files["artifact"], tmp_path / "art")
    _edit_resealed(art, lambda m: edit(m["selection"]))
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", art, "--test", "s002",
                                "--out", tmp_path / "rep"])
    line = assert_one_line_error(code, err, "compare")
    assert re.search(rf"{re.escape(str(art / 'skin.json'))}: {pattern}", line), line
    assert line.endswith("; export the artifact again (`sonicskin export --run DIR` or `sonicskin fit-svm`)"), line


# -- live: a device that delivers audio the model cannot use ----------------------------------------------------
def _device(fault: str, good_s: float):
    """A fake audio interface: ``good_s`` seconds of the rig's chirp train with a little noise, then 6 s of
    ``fault`` (zeros, NaN, full-scale clipping); every block is queued at start (a device that keeps delivering)."""
    import numpy as np

    from sonicskin import acquire
    from sonicskin.dsp import rig_chirp

    class Device(acquire._QueueSource):
        def __init__(self, rig, device=None, **kw):
            super().__init__(rig, 1024, max_queued_s=30)

        def start(self):
            fs = int(self.rig.fs_hz)
            n = int((good_s + 6.0) * fs) // 1024 * 1024
            x = np.resize(rig_chirp(self.rig).astype(np.float32) * 0.1, n)
            x += np.random.default_rng(0).normal(0, 1e-3, n).astype(np.float32)
            bad = slice(int(good_s * fs), None)
            if fault == "noise":  # the transmitter off: the receiver hears its noise only
                x[bad] = np.random.default_rng(1).normal(0, 0.05, x[bad].size).astype(np.float32)
            else:
                x[bad] = {"zeros": 0.0, "nan": np.nan, "clip": 1.0}[fault]
            for k in range(0, n, 1024):
                self._deliver(x[k:k + 1024])

        def stop(self):
            pass

    return Device


LIVE_FAULTS = [
    ("zeros", 0.0, r"\d+ silent frame\(s\)\); the input is silent: is the transmitter playing and the receiver on input "
                   r"channel 0 \(--rx\)\? check the cable and the levels with `sonicskin check`"),
    ("nan", 1.0, r"\d+ nan frame\(s\)\); the driver delivers NaN/inf samples: restart the audio interface or its driver"),
    ("clip", 1.0, r"\d+ clipped frame\(s\)\); the input is clipped at full scale: lower the transmit amplitude or the input "
                  r"gain \(`sonicskin check` measures the level\)"),
]


@pytest.mark.parametrize("fault, good_s, pattern", LIVE_FAULTS, ids=[c[0] for c in LIVE_FAULTS])
def test_live_on_a_device_delivering_unusable_audio_stops_with_one_line(cli_files, monkeypatch, capsys, fault, good_s,
                                                                        pattern):
    """A device that delivers only zeros (or dies into NaN / clipping after 1 s) kept the loop running: every frame
    skipped, no event, exit 0 at the end: a robot would read 'no touch' from a blind sensor."""
    import re

    from sonicskin import acquire

    monkeypatch.setattr(acquire, "SoundDeviceSource", _device(fault, good_s))
    code, out, err = run(capsys, ["live", "--device", "0", "--artifact", cli_files["artifact"], "--rig", cli_files["rig"],
                                  "--duration", "20", "--no-status"])
    lines = err.strip().splitlines()
    assert code == 2 and out == "" and "Traceback" not in err, err
    assert lines[-2].startswith('{"summary"'), err  # the run's counters are still printed
    assert re.fullmatch(r"sonicskin live: error: the device delivers audio but none of the last 3\.0 s gave a usable chirp "
                        rf"\({pattern}", lines[-1]), lines[-1]


def test_api_listener_raises_on_unusable_audio(cli_files, monkeypatch):
    """The Python API hands the same error to the caller's thread (iteration ends with it)."""
    from sonicskin import acquire
    from sonicskin.api import Listener
    from sonicskin.live import InputUnusable

    monkeypatch.setattr(acquire, "SoundDeviceSource", _device("zeros", 1.0))
    lst = Listener(cli_files["artifact"], device=0, rig=cli_files["rig"], duration_s=20)
    with pytest.raises(InputUnusable, match=r"none of the last 3\.0 s gave a usable chirp \(\d+ silent(, 1 dropout)? frame\(s\)\)"):
        list(lst)


# -- training options that reached Lightning (tracebacks) or were taken silently ---------------------------------
TRAIN_REFUSALS = [
    (["--trainer.devices", "0"], "--trainer.devices must be an integer >= 1, -1 (every device), auto, or a list of device "
                                 "indices, got '0'"),
    (["--trainer.devices", "-3"], "--trainer.devices must be an integer >= 1, -1 (every device), auto, or a list of device "
                                  "indices, got '-3'"),
    (["--trainer.devices", "[0]"], "--trainer.devices must be a number of processes (an integer >= 1) on the CPU; device "
                                   "index lists are for GPUs, got [0]"),
    (["--trainer.accelerator", "gpu"], "No supported gpu backend found! (`sonicskin train --help` lists the "
                                       "model/data/trainer options)"),
    (["--trainer.strategy", "ddp_spawn"], "--trainer.strategy must be auto or ddp (the network's location layer is built "
                                          "when training starts, which a spawned or forked worker cannot hand back), got "
                                          "'ddp_spawn'"),
    (["--model.kernel", "maybe"], "--model.kernel must be true, false or auto, got 'maybe'"),
    # allocated before anything runs: 24 GB and 17 GB, the OOM killer's (seen: a SIGKILL after 3 minutes)
    (["--model.n_centres", "100000000"], "--model.n_centres must be an integer from 0 to 100000 (the SVM's support vectors; "
                                         "0: chosen when training starts), got 100000000"),
    (["--model.hidden", "[65536, 65536]"], "--model.hidden must be layers of at most 50 million weights together (these "
                                           "have 4,315 million), got [65536, 65536]"),
]


@pytest.mark.parametrize("argv, message", refusals(TRAIN_REFUSALS))
def test_training_options_lightning_refuses_are_one_line(cli_files, capsys, argv, message):
    """Lightning's own refusals (MisconfigurationException, TypeError from its device parser) were tracebacks,
    ``ddp_spawn`` one after training (the spawned worker's kernel layer does not fit the parent's module), and a
    misspelt ``--model.kernel`` meant ``true`` without a word."""
    pytest.importorskip("lightning")
    assert refusal(capsys, ["train", "--data", cli_files["data"], "--n-bins", "60", "--trainer.max_epochs", "1",
                            "--trainer.default_root_dir", str(cli_files["root"] / "never"), *argv]) == message
    assert not (cli_files["root"] / "never").exists()


SPLIT_REFUSALS = [
    ("s000", "validation sessions s000 are training sessions too (train s000); validate on sessions that do not train: "
             "s001, s002"),
    ("s099", "validation sessions s099 are not in the dataset (train s000); validate on sessions that do not train: "
             "s001, s002"),
]


@pytest.mark.parametrize("val, message", SPLIT_REFUSALS, ids=[c[0] for c in SPLIT_REFUSALS])
@pytest.mark.parametrize("how", ["--val", "--data.val_sessions"])
def test_validation_on_a_training_or_missing_session_is_refused(cli_files, tmp_path, capsys, val, message, how):
    """``train --val s000`` (the default training session) validated on the training data and reported it as
    'validation on s000'; ``--val s099`` (no such session) trained with no validation metrics at all, exit 0."""
    pytest.importorskip("lightning")
    argv = ["--val", val] if how == "--val" else [f"--data.val_sessions=[{val}]"]
    code, _, err = run(capsys, ["train", "--data", cli_files["data"], "--n-bins", "60", "--trainer.max_epochs", "1",
                                "--model.hidden", "[8]", "--trainer.default_root_dir", str(tmp_path / "run"), *argv])
    assert assert_one_line_error(code, err, "train") == f"sonicskin train: error: {message}"


# -- check: windows and simulated motors outside what the check can measure ---------------------------------------
CHECK_REFUSALS = [
    (["--rest", "0.001"], "--rest 0.001 s holds fewer than the 9 chirp periods the check needs at rest (5.3 ms each): "
                          "give --rest 0.1 or more"),
    (["--rest", "1e9"], "--rest 1e+09: give seconds in (0, 600]"),
    (["--press", "1e9"], "--press 1e+09: give seconds in (0, 600]"),
    (["--sim-motors", "nan"], "--sim-motors nan: motor activity is a number from 0 (robot still) to 1 (full)"),
    (["--sim-motors", "inf"], "--sim-motors inf: motor activity is a number from 0 (robot still) to 1 (full)"),
    (["--sim-motors", "-1"], "--sim-motors -1.0: motor activity is a number from 0 (robot still) to 1 (full)"),
]


@pytest.mark.parametrize("argv, message", refusals(CHECK_REFUSALS))
def test_check_windows_and_motors_out_of_range_are_one_line(cli_files, tmp_path, capsys, argv, message):
    """``--rest 0.001`` failed the chirp lock and blamed the cables ('no chirp on any input'), ``--rest 1e9`` was a
    numpy MemoryError traceback, ``--sim-motors inf`` an IndexError traceback, ``nan`` and ``-1`` ran silently."""
    assert refusal(capsys, ["check", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--rest", "1",
                            "--press", "1", "--out", tmp_path / "o", *argv]) == message
    assert not (tmp_path / "o").exists()


# -- the Python API's keywords -------------------------------------------------------------------------------------
API_REFUSALS = [
    ({"blocksize": -5}, "blocksize must be an integer from 1 to 1048576 (audio frames per block), got -5"),  # hung
    ({"blocksize": 0}, "blocksize must be an integer from 1 to 1048576 (audio frames per block), got 0"),  # ZeroDivision
    ({"duration_s": "5"}, "duration_s must be > 0 (a finite number of seconds) or None (until stop()), got '5'"),  # TypeError
    ({"watchdog_s": float("nan")}, "watchdog_s must be a finite number of seconds > 0, got nan"),  # no watchdog, silently
    ({"tx": -1, "device": 0}, "tx must be a 0-based channel number (an integer >= 0), got -1"),
    ({"artifact": None}, "artifact must be the path of an artifact folder, got None"),  # TypeError
]


@pytest.mark.parametrize("kw, message", API_REFUSALS, ids=["blocksize-negative", "blocksize-zero", "duration-string",
                                                          "watchdog-nan", "tx-negative", "artifact-none"])
def test_listener_keywords_are_checked_in_one_line(cli_files, kw, message):
    from sonicskin.api import listen
    from sonicskin.errors import SonicskinError

    kw = {"artifact": cli_files["artifact"], "rig": cli_files["rig"], "scenario": cli_files["scenario"], "fast": True,
          "duration_s": 2.0, **kw}
    with pytest.raises(SonicskinError) as e:
        next(iter(listen(kw.pop("artifact"), **kw)))
    assert str(e.value) == message


# -- SkinRuntime / SkinStream on arrays (the documented runtime API) --------------------------------------------------
def _stream(cli_files):
    import numpy as np

    from sonicskin.dataset import Dataset
    from sonicskin.feature_cache import load_features_cached
    from sonicskin.runtime import SkinRuntime

    t = load_features_cached(Dataset(cli_files["data"]), progress=False)
    m = t["session"] == "s002"
    return SkinRuntime(cli_files["artifact"], "svm"), np.array(t.X[m], np.float32), np.array(t["time_s"][m])


def _nan_rows(X):
    X = X.copy()
    X[700:710] = float("nan")
    return X


RUNTIME_REFUSALS = [
    ("nan-rows", lambda rt, X, ts: rt.replay(_nan_rows(X), ts),  # predicted silently (no touch, NaN position)
     "the band features hold NaN or infinite values in 10 of {n} chirps (the first at row 700); drop those chirps (the "
     "live loop skips them) or compute the features again"),
    ("time-too-short", lambda rt, X, ts: rt.replay(X, ts[:-5]),  # IndexError
     "time_s must hold one time per chirp ({n},), got shape ({m},)"),
    ("time-backwards", lambda rt, X, ts: rt.replay(X, ts[::-1].copy()),  # accepted: refreshes scheduled on a wrong clock
     "time_s must be finite and non-decreasing (the stream clock of each chirp, in order): replay one stream at a time, "
     "in recording order"),
    ("inputs-wrong-width", lambda rt, X, ts: rt.predict_inputs(X[:3, :5]),  # onnxruntime's InvalidArgument
     "expected model inputs (n, {b}) (the artifact's bins; SkinRuntime.inputs makes them from band features), got (3, 5)"),
    ("chirp-wrong-width", lambda rt, X, ts: rt.stream().chirp(X[0, :5], 0.0),  # IndexError
     "expected one chirp's band features ({band},), got shape (5,)"),
    ("frame-wrong-length", lambda rt, X, ts: rt.stream().frame(X[0, :100], 0.0),  # numpy broadcast ValueError
     "expected one chirp-aligned frame of {L} samples (the artifact's rig), got shape (100,)"),
    ("chirp-nan", lambda rt, X, ts: rt.stream().chirp(_nan_rows(X)[705], 0.0),  # became the boot reference
     "the chirp's band features hold NaN or infinite values (a NaN, silent or clipped frame); skip that chirp, as the live "
     "loop does"),
]


@pytest.mark.parametrize("name, act, message", RUNTIME_REFUSALS, ids=[c[0] for c in RUNTIME_REFUSALS])
def test_runtime_arrays_are_checked_in_one_line(cli_files, name, act, message):
    from sonicskin.runtime import ArtifactError

    rt, X, ts = _stream(cli_files)
    with pytest.raises(ArtifactError) as e:
        act(rt, X, ts)
    assert str(e.value) == message.format(n=len(X), m=len(X) - 5, b=len(rt.spec.bins), band=rt.rig.n_band, L=rt.rig.n_chirp)


def test_a_chirp_with_a_bad_time_is_refused_and_the_stream_goes_on(cli_files):
    """Issue 37: Stream.chirp with a NaN/inf/non-number time raised a raw error after changing state (a NaN in the boot
    stopped every later chirp); OnlineReference checks the time at the door, so the stream is as if it never came."""
    from sonicskin.errors import SonicskinError

    rt, X, ts = _stream(cli_files)
    hit, clean = rt.stream(), rt.stream()
    beta = hit.reference.beta
    for i in range(beta + 20):
        if i in (3, beta + 5):  # inside the boot window, and after it
            for bad in (float("nan"), float("inf"), "soon"):
                with pytest.raises(SonicskinError, match="^stream time t_s must be a number of seconds"):
                    hit.chirp(X[i], bad)
        a, b = hit.chirp(X[i], ts[i]), clean.chirp(X[i], ts[i])
        assert (a is None) == (b is None) and (a is None or (a.touch == b.touch).all())
    assert hit.reference.refreshes == clean.reference.refreshes == 1


def test_runtime_replay_of_a_clean_stream_still_runs(cli_files):
    rt, X, ts = _stream(cli_files)
    p = rt.replay(X, ts)
    assert len(p.touch) == len(X) and p.touch.any() and p.calibrating.any() and not p.calibrating.all()


# -- an output path where a file is in the way -------------------------------------------------------------------
def test_an_output_folder_that_is_a_file_names_the_problem(cli_files, tmp_path, capsys):
    """``--out`` naming a file (or a path below one) printed only ``[Errno 17] File exists: '...'``."""
    f = tmp_path / "f"
    f.write_text("x")
    code, _, err = run(capsys, ["check", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--rest", "1",
                                "--press", "1", "--out", f])
    assert assert_one_line_error(code, err, "check") == (f"sonicskin check: error: cannot use {f} as a folder: it, or a "
                                                         f"folder above it, is a file (File exists); choose another output "
                                                         f"path or move the file")
    code, _, err = run(capsys, ["fit-svm", "--data", cli_files["data"], "--n-bins", "60", "--out", f / "art"])
    assert assert_one_line_error(code, err, "fit-svm").startswith(f"sonicskin fit-svm: error: cannot use {f} as a folder")
    assert f.read_text() == "x"


# -- live: where the events go ----------------------------------------------------------------------------------------
def _live_cmd(cli_files) -> str:
    import shlex
    import sys

    return " ".join(shlex.quote(str(a)) for a in [sys.executable, "-m", "sonicskin", "live", "--artifact", cli_files["artifact"],
                                                  "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--fast",
                                                  "--no-status"])


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("redirect, message", [
    ("> /dev/full", "sonicskin live: error: cannot write the touch events to stdout (No space left on device): the file or "
                    "device it goes to is full or gone; write them where there is room (`sonicskin live ... > events.jsonl`)"),
    (">&-", "sonicskin live: error: stdout is closed, so the touch events would go nowhere; send them to a file or a pipe "
            "(`sonicskin live ... > events.jsonl`), or add --udp/--lsl"),
], ids=["stdout-full", "stdout-closed"])
def test_live_events_that_cannot_be_written_are_one_line(cli_files, redirect, message):
    """A full stdout was a bare '[Errno 28] No space left on device'; a closed one (``>&-``) dropped every event and
    exited 0."""
    import os
    import subprocess

    p = subprocess.run(["sh", "-c", f"{_live_cmd(cli_files)} {redirect}"], capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith("sonicskin: warning: the simulated session")]
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert lines == [message], p.stderr


@pytest.mark.parametrize("cb", ["EarlyStopping", "ModelCheckpoint"])
def test_a_callback_monitoring_a_metric_never_logged_is_refused_before_training(cli_files, capsys, cb):
    """EarlyStopping on a misspelt metric was a RuntimeError traceback after the first epoch (ModelCheckpoint ended with
    Lightning's message after it)."""
    pytest.importorskip("lightning")
    code, _, err = run(capsys, ["train", "--data", cli_files["data"], "--n-bins", "60", "--trainer.max_epochs", "1",
                                "--trainer.default_root_dir", str(cli_files["root"] / "never"), f"--trainer.callbacks+={cb}",
                                "--trainer.callbacks.monitor=val_accuracy"])
    assert assert_one_line_error(code, err, "train") == (
        f"sonicskin train: error: {cb} monitors 'val_accuracy', which sonicskin train does not log; monitor one of val_loss, "
        f"val_acc, val_force_rmse, val_detect, train_loss, train_acc, train_force_rmse, train_detect")
    assert not (cli_files["root"] / "never").exists()


def test_live_runs_an_artifact_on_its_own_rig_without_rig(cli_files, capsys):
    """``live --artifact`` of a non-jaco rig was refused under the default --rig jaco ('... or run with the artifact's
    rig', with no word of --rig); the Python API already defaulted to the artifact's rig."""
    code, out, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--scenario", cli_files["scenario"], "--fast",
                                  "--no-status"])
    assert code == 0, err
    events = [json.loads(ln) for ln in out.splitlines()]
    assert events and all(e["kind"] in ("touch", "release") and e["location"] in (0, 1, 2) for e in events)
    code, _, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--scenario", cli_files["scenario"], "--fast",
                                "--no-status", "--rig", "jaco"])
    assert assert_one_line_error(code, err, "live").startswith("sonicskin live: error: the artifact was trained for another "
                                                                "rig (n_chirp: 1024 vs 20480")


# -- live --links: the links config ----------------------------------------------------------------------------------
LINK_CONFIGS = [
    ("ints", "links:\n  - 5\n  - 6\n", "link 0: expected a mapping {name, tx, rx}, got 5"),  # TypeError
    ("tx-missing", "links:\n  - {name: a, rx: 0}\n", "link 0: tx must be a 0-based channel number (an integer >= 0), "
                                                      "got nothing"),  # KeyError
    ("tx-fraction", "links:\n  - {name: a, tx: 0.7, rx: 0}\n", "link 0: tx must be a 0-based channel number (an integer "
                                                                ">= 0), got 0.7"),  # channel 0 silently
    ("rx-negative", "links:\n  - {name: a, tx: 0, rx: -3}\n", "link 0: rx must be a 0-based channel number (an integer "
                                                               ">= 0), got -3"),  # accepted
    ("links-a-mapping", "links: {name: a}\n", "a links config needs a non-empty 'links' list of {name, tx, rx}"),
    # the arm's name said "must be a text", a link's "must be a string": one wording
    ("arm-name-list", "name: [a, b]\nlinks:\n  - {name: a, tx: 0, rx: 0}\n", "name must be a string, got ['a', 'b']"),
    ("link-name-list", "links:\n  - {name: [a], tx: 0, rx: 0}\n", "link 0: name must be a string, got ['a']"),
]


@pytest.mark.parametrize("name, text, message", LINK_CONFIGS, ids=[c[0] for c in LINK_CONFIGS])
def test_a_broken_links_config_is_one_line(cli_files, tmp_path, capsys, name, text, message):
    cfg = tmp_path / "links.yaml"
    cfg.write_text("duplex: time\n" + text)
    code, _, err = run(capsys, ["live", "--links", cfg, "--device", "0", "--link-artifact", cli_files["artifact"],
                                "--rig", cli_files["rig"], "--no-status"])
    assert assert_one_line_error(code, err, "live") == f"sonicskin live: error: {cfg}: {message}"


# -- compare: options that were ignored, a session named twice --------------------------------------------------------
def test_compare_options_it_would_ignore_are_refused(cli_files, capsys, tmp_path, monkeypatch):
    """``compare --data D --epochs 5`` trained for the config's epochs (60 with moving) without a word; with --artifact
    a --config was ignored too."""
    monkeypatch.chdir(tmp_path)  # were it to train again, its runs/ go here
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--epochs", "5", "--out", tmp_path / "r"])
    assert assert_one_line_error(code, err, "compare") == (
        "sonicskin compare: error: --epochs sets the network epochs of --scenario runs; with --data pass "
        "--trainer.max_epochs N (or drop it with --artifact)")
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", cli_files["artifact"], "--test", "s002",
                                "--config", "other.yaml", "--out", tmp_path / "r"])
    assert assert_one_line_error(code, err, "compare").startswith("sonicskin compare: error: with --artifact the models are "
                                                                   "already trained")


def test_compare_a_test_session_named_twice_is_scored_once(cli_files, capsys, tmp_path):
    """``--test s002 s002`` was 'operands could not be broadcast together with shapes (n,) (2n,)'."""
    code, out, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", cli_files["artifact"], "--test",
                                  "s002", "s002", "--out", tmp_path / "r"])
    assert code == 0, err
    assert "  sessions: train s000, s001, s002 | validation none | test s002" in out.splitlines()
    assert json.loads((tmp_path / "r" / "compare.json").read_text())["test_sessions"] == ["s002"]


# -- export --data: the checkpoint's recordings, not others under the same names --------------------------------------
@pytest.fixture(scope="module")
def trained(cli_files, tmp_path_factory):
    """A 1-epoch network on the cli_files dataset, and a dataset of the same rig, layout and session names but other
    recordings (another simulator seed)."""
    pytest.importorskip("lightning")
    from sonicskin.cli import main
    from sonicskin.rig import Rig
    from sonicskin.sim.generate import simulate_dataset
    from sonicskin.sim.scenario import Scenario

    root = tmp_path_factory.mktemp("trained")
    assert main(["train", "--data", str(cli_files["data"]), "--n-bins", "60", "--trainer.max_epochs", "1",
                 "--model.hidden", "[8]", "--trainer.default_root_dir", str(root / "run")]) == 0
    simulate_dataset(Scenario.load(cli_files["scenario"]).replace(seed=99), Rig.load(cli_files["rig"]), root / "other",
                     progress=False, log=lambda *_: None)
    return root


@pytest.mark.slow
def test_export_refuses_other_recordings_under_the_same_names(cli_files, trained, capsys, tmp_path):
    """``export --data`` of another recording with the checkpoint's rig, layout and session names trained the SVM on
    it, next to a network trained on the checkpoint's data, and skin.json named the checkpoint's data."""
    code, _, err = run(capsys, ["export", "--run", trained / "run", "--data", trained / "other", "--out", tmp_path / "a"])
    line = assert_one_line_error(code, err, "export")
    assert re.fullmatch(rf"sonicskin export: error: dataset {re.escape(str(trained / 'other'))}'s session\(s\) s000, s001, "
                        r"s002 are other recordings than checkpoint \S+\.ckpt was trained on \(their session\.json differs\); "
                        r"pass the dataset it was trained on \(a copy of it is fine\) with --data", line), line
    assert not (tmp_path / "a").exists()


@pytest.mark.slow
def test_export_of_a_copy_of_the_data_names_the_copy(cli_files, trained, capsys, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(cli_files["data"], copy)
    code, _, err = run(capsys, ["export", "--run", trained / "run", "--data", copy, "--out", tmp_path / "a"])
    assert code == 0, err
    assert json.loads((tmp_path / "a" / "skin.json").read_text())["training"]["data"] == str(copy.resolve())
    shutil.rmtree(copy / "s002")  # a session of the checkpoint's split missing (its test session)
    code, _, err = run(capsys, ["export", "--run", trained / "run", "--data", copy, "--out", tmp_path / "b"])
    assert re.fullmatch(rf"sonicskin export: error: dataset {re.escape(str(copy))} lacks session\(s\) s002 of checkpoint "
                        r"\S+\.ckpt's split \(train s000\); pass the dataset it was trained on \(--data\)",
                        assert_one_line_error(code, err, "export"))


RUNTIME_ARGS = [
    ({"rig": {"fs_hz": 1}}, "rig must be a sonicskin.rig.Rig, a rig name or a YAML path, got dict"),  # AttributeError
    ({"layout": "x"}, "layout must be a sonicskin.rig.Layout (e.g. a scenario's make_layout()), got str"),  # AttributeError
    ({"threads": -2}, "threads must be an integer from 1 to 1024 (onnxruntime's intra-op threads), got -2"),  # accepted
    ({"threads": "2"}, "threads must be an integer from 1 to 1024 (onnxruntime's intra-op threads), got '2'"),  # TypeError
    ({"folder": 5}, "folder must be the path of an artifact folder, got 5"),  # TypeError
]


@pytest.mark.parametrize("kw, message", RUNTIME_ARGS, ids=["rig-dict", "layout-str", "threads-negative", "threads-str",
                                                           "folder-int"])
def test_runtime_arguments_are_checked_in_one_line(cli_files, kw, message):
    from sonicskin.runtime import ArtifactError, SkinRuntime

    kw = {"folder": cli_files["artifact"], "model": "svm", **kw}
    with pytest.raises(ArtifactError) as e:
        SkinRuntime(kw.pop("folder"), **kw)
    assert str(e.value) == message


def test_runtime_takes_a_rig_name_or_yaml(cli_files):
    """``rig="jaco"`` was an AttributeError; now the rig is loaded and compared like any other."""
    from sonicskin.runtime import ArtifactError, SkinRuntime

    assert SkinRuntime(cli_files["artifact"], "svm", rig=cli_files["rig"]).rig.n_chirp == 1024
    with pytest.raises(ArtifactError, match=r"^the artifact was trained for another rig \(n_chirp: 1024 vs 20480"):
        SkinRuntime(cli_files["artifact"], "svm", rig="jaco")


def test_live_on_a_device_hearing_noise_without_a_chirp_stops_after_the_boot(cli_files, monkeypatch, capsys):
    """Noise alone (the transmitter off): the framer locked on it, the boot took it as the reference, and the loop
    emitted touch events at random (880 in 8 s), exit 0."""
    from sonicskin import acquire

    monkeypatch.setattr(acquire, "SoundDeviceSource", _device("noise", 0.0))
    code, out, err = run(capsys, ["live", "--device", "0", "--artifact", cli_files["artifact"], "--duration", "20",
                                  "--no-status"])
    assert code == 2 and out == "" and "Traceback" not in err, err
    assert re.fullmatch(r"sonicskin live: error: no chirp in the input: over the \d+ hands-off chirps of the boot calibration "
                        r"the received spectrum varies by 5\.\d dB from chirp to chirp \(a chirp repeats within ~0\.1 dB, "
                        r"noise alone varies by 5\.6 dB\); is the transmitter playing on output --tx and reaching the "
                        r"receiver\? check it with `sonicskin check`", err.strip().splitlines()[-1]), err


def test_channel_options_the_simulated_device_would_ignore_are_refused(cli_files, capsys, tmp_path):
    """``live --tx 99`` on the simulated device ran as if it were not there; ``check --tx 5`` too (``--rx 5`` was checked)."""
    code, _, err = run(capsys, ["live", "--artifact", cli_files["artifact"], "--scenario", cli_files["scenario"], "--fast",
                                "--tx", "99"])
    assert assert_one_line_error(code, err, "live") == ("sonicskin live: error: --tx/--rx choose the channels of a real "
                                                        "interface (--device NAME|INDEX); the simulated device has one link: "
                                                        "drop them")
    code, _, err = run(capsys, ["check", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--rest", "1",
                                "--press", "1", "--tx", "5", "--out", tmp_path / "o"])
    assert assert_one_line_error(code, err, "check") == "sonicskin check: error: --tx 5: the device has 2 outputs (0-1)"


def test_training_on_every_session_names_them_plainly(cli_files, capsys, tmp_path):
    """The refusal printed ``sessions [np.str_('s000'), ...]``."""
    pytest.importorskip("lightning")
    code, _, err = run(capsys, ["train", "--data", cli_files["data"], "--n-bins", "60", "--trainer.max_epochs", "1",
                                "--trainer.default_root_dir", str(tmp_path / "run"), "--data.train_sessions=[s000,s001,s002]"])
    assert assert_one_line_error(code, err, "train") == (
        "sonicskin train: error: no session left to test on (sessions s000, s001, s002; train s000, s001, s002; val none): "
        "leave one out of the training and validation sessions")
