"""Data-side hostile findings of issue 27: each was accepted silently, destroyed data or gave a traceback; now each
is refused with one line naming the problem and the fix, or recovered with a one-line warning.

Inputs are built from the CLI tests' small rig and tiny 3-marker scenario (cli_helpers)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import SMALL_RIG, TINY_SCENARIO, assert_one_line_error, press_rows, run, session_audio

from sonicskin.dataset import Dataset
from sonicskin.errors import ArtifactError
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def five(tmp_path_factory):
    """The tiny scenario with 5 sessions on the small rig, and its YAMLs."""
    root = tmp_path_factory.mktemp("five")
    (root / "small.yaml").write_text(SMALL_RIG)
    (root / "tiny.yaml").write_text(TINY_SCENARIO)
    simulate_dataset(Scenario.load(root / "tiny.yaml").replace(sessions=5), Rig.load(root / "small.yaml"), root / "data",
                     progress=False, log=lambda *_: None)
    return root


# -- 27.5: a refused concurrent writer never touches the other's dataset ------------------------------------------------
HOLDER = """
import sys
from pathlib import Path
from sonicskin.dataset import writer_lock
out = Path(sys.argv[1])
with writer_lock(out):
    (out / "dataset.json").write_text("{}")  # what the first `simulate` has written when the second one starts
    print("held", flush=True)
    sys.stdin.readline()
"""


@pytest.fixture
def holder(tmp_path):
    """Another process writing the dataset folder tmp_path/X (it holds the folder's writer lock until released)."""
    out = tmp_path / "X"
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                         cwd=REPO)
    assert p.stdout.readline().strip() == "held"
    yield out
    p.stdin.write("\n")
    p.stdin.close()
    p.wait()


BUSY = ("is being written by another process (a `sonicskin simulate`, `record` or import into the same folder); wait for "
        "it to finish, or choose another --out")


def test_a_second_simulate_into_a_folder_being_written_is_refused_and_removes_nothing(holder, capsys, five):
    """Two `simulate --out X` at once: one was refused ("already holds a dataset"), then its clean-up removed X and the
    other died with `[Errno 2] No such file or directory: X/s000`, leaving nothing."""
    for extra in ([], ["--overwrite"], ["--resume"]):
        code, _, err = run(capsys, ["simulate", "--scenario", five / "tiny.yaml", "--rig", five / "small.yaml", "--out", holder,
                                    "--quiet", *extra])
        assert assert_one_line_error(code, err, "simulate") == f"sonicskin simulate: error: {holder} {BUSY}"
        assert sorted(p.name for p in holder.iterdir()) == ["dataset.json"] and (holder / "dataset.json").read_text() == "{}"


def _spectra(five: Path, path: Path, sessions=("s000", "s001")) -> Path:
    """The five-session dataset's chirps as an import-spectra table (magnitudes in dB, labels, sessions)."""
    ds = Dataset(five / "data")
    t = ds.features(sessions=list(sessions), progress=False)
    np.savez(path, freqs_hz=ds.rig.freqs_hz[ds.rig.band_bins], magnitude_db=t.X.astype(float), location=t["location"],
             session=t["session"], force_n=t["force_n"], x_cm=t["x_cm"], y_cm=t["y_cm"])
    return path


def test_an_import_into_a_folder_being_written_is_refused_and_removes_nothing(holder, tmp_path, five):
    from sonicskin.dataset import DatasetError
    from sonicskin.importers import import_spectra

    table = _spectra(five, tmp_path / "t.npz")
    for mode in ("create", "overwrite"):
        with pytest.raises(DatasetError) as e:
            import_spectra(table, holder, rig=Rig.load(five / "small.yaml"), mode=mode, log=lambda *_: None)
        assert str(e.value) == f"{holder} {BUSY}"
    assert sorted(p.name for p in holder.iterdir()) == ["dataset.json"]
    assert not (tmp_path / ".X.importing").exists()


def test_the_writer_lock_is_released_and_a_later_writer_proceeds(tmp_path, five):
    from sonicskin.dataset import writer_lock

    out = tmp_path / "d"
    with writer_lock(out), writer_lock(out):  # reentrant within one process (the CLI's clean-up and the writer)
        pass
    code = subprocess.run([sys.executable, "-c", HOLDER.replace("sys.stdin.readline()", "pass"), str(out)], cwd=REPO,
                          capture_output=True, text=True).returncode
    assert code == 0  # another process takes it once this one let go


# -- 27.6: --test names exactly the sessions tested ------------------------------------------------------------------------
@pytest.mark.slow
def test_compare_tests_exactly_the_test_sessions(five, capsys, tmp_path, monkeypatch):
    """`compare --train s000 --val none --test s001` on 5 sessions trained, then tested s001..s004."""
    pytest.importorskip("lightning")
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, ["compare", "--data", five / "data", "--train", "s000", "--val", "none", "--test", "s001",
                                  "--n-bins", "40", "--out", tmp_path / "r", "--trainer.max_epochs", "1",
                                  "--trainer.enable_progress_bar", "false"])
    assert code == 0, err
    assert "  sessions: train s000 | validation none | test s001" in out.splitlines()
    assert json.loads((tmp_path / "r" / "compare.json").read_text())["test_sessions"] == ["s001"]


def test_evaluate_tests_exactly_the_test_sessions(five, capsys, tmp_path):
    code, out, err = run(capsys, ["evaluate", "--data", five / "data", "--train", "s000", "--val", "s001", "--test", "s002",
                                  "--no-ablations", "--n-bins", "40", "--out", tmp_path / "r"])
    assert code == 0, err
    assert json.loads((tmp_path / "r" / "report.json").read_text())["test_sessions"] == ["s002"]


# -- 27.8: NaN is never written as a JSON literal, and a NaN field is named ----------------------------------------------
def _strict(text: str):
    def no_constants(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=no_constants)


def test_compare_json_writes_null_for_what_is_not_a_number(cli_files, tmp_path):
    from sonicskin.compare import compare_artifact, save_comparison

    res = compare_artifact(cli_files["artifact"], cli_files["data"], sessions=["s002"], latency=False)
    res["models"]["svm"]["continuous_error_cm"]["median"] = float("nan")  # e.g. no finite position to score
    res["models"]["svm"]["force"]["xcorr"] = np.float64("nan")
    save_comparison(res, tmp_path, Dataset(cli_files["data"]).layout)
    doc = _strict((tmp_path / "compare.json").read_text())
    assert doc["models"]["svm"]["continuous_error_cm"]["median"] is None and doc["models"]["svm"]["force"]["xcorr"] is None


def test_a_nan_in_an_artifacts_parity_is_refused_naming_the_field(cli_files, tmp_path):
    """It was `Out of range float values are not JSON compliant` (a ValueError from the digest) without the field."""
    from sonicskin.runtime import SkinRuntime

    art = tmp_path / "art"
    shutil.copytree(cli_files["artifact"], art)
    meta = json.loads((art / "skin.json").read_text())
    meta["models"]["svm"]["parity"]["max_abs_scores"] = math.nan
    (art / "skin.json").write_text(json.dumps(meta))  # Python's json writes the NaN literal, and reads it back
    with pytest.raises(ArtifactError) as e:
        SkinRuntime(art, "svm")
    assert str(e.value) == (f"{art / 'skin.json'}: models.svm.parity.max_abs_scores is nan: NaN and Infinity are not JSON "
                            f"numbers; export the artifact again (`sonicskin export --run DIR` or `sonicskin fit-svm`)")


def test_a_nan_in_an_hparam_is_refused_at_writing_naming_the_field(cli_files, tmp_path):
    from sonicskin.artifact import skin_json
    from sonicskin.features import FeatureSpec

    meta = json.loads((cli_files["artifact"] / "skin.json").read_text())
    out = tmp_path / "a"
    out.mkdir()
    shutil.copy(cli_files["artifact"] / "svm.onnx", out)
    svm = {k: v for k, v in meta["models"]["svm"].items() if k not in ("sha256", "probe")}
    svm["parity"] = {**svm["parity"], "decision_tol": float("inf")}
    with pytest.raises(ArtifactError) as e:
        skin_json(out, rig=meta["rig"], layout=meta["layout"], spec=FeatureSpec.from_dict(meta["features"]), min_force_n=0.5,
                  training=meta["training"], models={"svm": svm})
    assert str(e.value) == (f"{out / 'skin.json'} would hold a NaN or infinite value: models.svm.parity.decision_tol is inf; "
                            f"pass finite values to the options it came from (model.*, trainer.*) and train or fit again")
    assert not (out / "skin.json").exists()


# -- 27.9: outputs inside the input dataset's folder --------------------------------------------------------------------
def test_simulate_and_fit_svm_into_a_dataset_folder_are_refused(cli_files, capsys, tmp_path):
    data = tmp_path / "d"
    shutil.copytree(cli_files["data"], data)
    before = sorted(p.relative_to(data).as_posix() for p in data.rglob("*"))
    code, _, err = run(capsys, ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--out",
                                data / "s003", "--quiet"])
    assert assert_one_line_error(code, err, "simulate") == (
        f"sonicskin simulate: error: --out {data / 's003'} is inside the dataset {data}: a dataset written there would become "
        f"part of that dataset's folder; choose an --out outside it")
    code, _, err = run(capsys, ["fit-svm", "--data", data, "--out", data / "art", "--n-bins", "40"])
    assert assert_one_line_error(code, err, "fit-svm") == (
        f"sonicskin fit-svm: error: --out {data / 'art'} is inside the dataset {data}: an artifact written there would "
        f"become part of that dataset's folder; choose an --out outside it")
    assert sorted(p.relative_to(data).as_posix() for p in data.rglob("*") if ".cache" not in p.parts) == \
        [b for b in before if not b.startswith(".cache")]


def _hands_off(session, edit) -> None:
    """Rewrite the label rows of ``session`` whose location ``edit`` accepts as hands-off, then reseal its manifest."""
    from cli_helpers import reseal

    for csv in sorted(session.glob("part-*.csv")):
        lines = csv.read_text().splitlines()
        head = lines[0].split(",")
        i = {c: head.index(c) for c in ("location", "x_cm", "y_cm", "force_n", "segment")}
        rows = []
        for ln in lines[1:]:
            r = ln.split(",")
            if edit(r[i["location"]]):
                r[i["location"]], r[i["x_cm"]], r[i["y_cm"]], r[i["force_n"]], r[i["segment"]] = "-1", "nan", "nan", "0", "gap"
            rows.append(",".join(r))
        csv.write_text("\n".join([lines[0], *rows]) + "\n")
    reseal(session)


# -- 27.10: locations the training sessions never touched -----------------------------------------------------------------
def test_evaluate_warns_about_locations_never_trained(five, capsys, tmp_path):
    data = tmp_path / "d"
    shutil.copytree(five / "data", data)
    _hands_off(data / "s000", lambda loc: loc == "2")  # s000 without its presses of marker 2 (the robot still)
    code, _, err = run(capsys, ["evaluate", "--data", data, "--train", "s000", "--val", "s001", "--test", "s002",
                                "--no-ablations", "--n-bins", "40", "--out", tmp_path / "r"])
    line = assert_one_line_error(code, err, "evaluate")
    assert line == ("sonicskin evaluate: error: training session(s) s000 touch 2 of the layout's 3 locations (never trained: "
                    "2); the SVM needs a press at every location: train on sessions that touch every location (--train)")



def test_evaluate_with_a_hands_off_test_session_scores_the_others_quietly(five, capsys, tmp_path):
    """A test session without touches (every label row edited to hands-off) printed numpy's "Mean of empty slice"."""
    data = tmp_path / "data"
    shutil.copytree(five / "data", data)
    _hands_off(data / "s003", lambda loc: True)
    code, _, err = run(capsys, ["evaluate", "--data", data, "--train", "s000", "--val", "s001", "--test", "s002", "s003",
                                "--n-bins", "40", "--out", tmp_path / "r"])
    assert code == 0, err
    assert "empty slice" not in err and "RuntimeWarning" not in err
    over = json.loads((tmp_path / "r" / "report.json").read_text())["ablations"]["over_time"]
    assert [r["session"] for r in over] == ["s002"]  # s003 has nothing to score


# -- 27.7: a feature cache whose content was edited (its key kept) ---------------------------------------------------------
def _rewrite_cache(path: Path, *, fix_digest: bool, **changes) -> None:
    from sonicskin.dataset import FeatureTable
    from sonicskin.feature_cache import _content_digest

    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for k, fn in changes.items():
        arrays[k] = fn(arrays[k])
    if fix_digest:  # a careful editor: the stored digest recomputed too; the label CSVs still tell
        t = FeatureTable(arrays["X"], {k[6:]: v for k, v in arrays.items() if k.startswith("label_")})
        arrays["content"] = np.array(_content_digest(t))
    np.savez(path, **arrays)


@pytest.mark.parametrize("fix_digest", [False, True], ids=["digest-kept", "digest-recomputed"])
def test_a_cache_with_edited_labels_is_rebuilt_with_a_warning(cli_files, capsys, tmp_path, fix_digest):
    """fit-svm trained on the edited labels and wrote another svm.onnx from the same recordings."""
    data = tmp_path / "d"
    shutil.copytree(cli_files["data"], data, ignore=shutil.ignore_patterns(".cache"))
    assert run(capsys, ["fit-svm", "--data", data, "--out", tmp_path / "a1", "--n-bins", "40"])[0] == 0
    (cache,) = (data / ".cache").glob("features-*.npz")
    _rewrite_cache(cache, fix_digest=fix_digest, label_location=lambda v: np.where(v >= 0, (v + 1) % 3, v))
    code, _, err = run(capsys, ["fit-svm", "--data", data, "--out", tmp_path / "a2", "--n-bins", "40"])
    assert code == 0, err
    why = ("its column 'location' of session s000 differs from the session's label CSVs" if fix_digest else
           "its content does not match the digest stored with it")
    warning = f"sonicskin fit-svm: warning: {cache}: {why}; the cache was edited (its key kept): rebuilt from the recordings"
    assert err.splitlines().count(warning) == 1, err
    assert (tmp_path / "a2" / "svm.onnx").read_bytes() == (tmp_path / "a1" / "svm.onnx").read_bytes()
    code, _, err = run(capsys, ["fit-svm", "--data", data, "--out", tmp_path / "a3", "--n-bins", "40"])
    assert code == 0 and "cache" not in err  # the rebuilt cache is trusted again


# -- 27.9: --force-csv on the simulated device -------------------------------------------------------------------------------
def test_record_refuses_a_force_sensor_on_the_simulated_device(cli_files, capsys, tmp_path):
    """`record --force-csv missing.csv` on the simulated device was silently ignored."""
    for opt, val in (("--force-csv", tmp_path / "missing.csv"), ("--force-serial", "/dev/ttyUSB9")):
        code, _, err = run(capsys, ["record", "--out", tmp_path / "rec", "--scenario", cli_files["scenario"], "--rig",
                                    cli_files["rig"], "--fast", opt, val])
        assert assert_one_line_error(code, err, "record") == (
            f"sonicskin record: error: {opt} {val}: the simulated device (--device sim) measures its own force and reads no "
            f"force sensor; drop {opt}, or record from an audio interface (--device NAME|INDEX)")
        assert not (tmp_path / "rec").exists()


# -- 27.10: a session named twice, rest rows of imported tables, a full disk --------------------------------------------------
def test_a_session_named_twice_counts_once_with_a_warning(cli_files, capsys, tmp_path):
    code, _, err = run(capsys, ["fit-svm", "--data", cli_files["data"], "--train", "s000", "s000", "s001", "--out",
                                tmp_path / "a", "--n-bins", "40"])
    assert code == 0, err
    assert "sonicskin fit-svm: warning: --train names s000 more than once; each session counts once" in err.splitlines()
    assert json.loads((tmp_path / "a" / "skin.json").read_text())["training"]["split"]["train"] == ["s000", "s001"]


def test_import_spectra_keeps_later_rest_rows_as_no_touch_chirps(five, tmp_path):
    """Every hands-off row was labelled "calibration" (the boot reference's rest), the later ones too."""
    from sonicskin.importers import import_spectra

    table = _spectra(five, tmp_path / "t.npz", sessions=("s000", "s001", "s002"))
    out = import_spectra(table, tmp_path / "d", rig=Rig.load(five / "small.yaml"), log=lambda *_: None)
    src = Dataset(five / "data").features(sessions=["s000", "s001", "s002"], progress=False)
    t = Dataset(out).features(progress=False)
    for s in ("s000", "s001", "s002"):
        loc, seg = t["location"][t["session"] == s], t["segment"][t["session"] == s]
        first = int(np.argmax(loc >= 0))
        assert first > 10 and (seg[:first] == "calibration").all()
        later_rest = (loc < 0) & (np.arange(loc.size) > first)
        assert later_rest.sum() > 5 and (seg[later_rest] == "gap").all() and (seg[loc >= 0] == "touch").all()
        assert np.array_equal(loc, src["location"][src["session"] == s])


def test_a_full_disk_names_the_file(cli_files, capsys, tmp_path, monkeypatch):
    """`[Errno 28] No space left on device` and no path: /dev/full stands in for the full disk."""
    from sonicskin.dataset import DatasetWriter

    out = tmp_path / "sim"
    made = DatasetWriter.__init__

    def then_full(self, *a, **k):  # the new dataset's first part's temporary file lands on a full device
        made(self, *a, **k)
        (out / "s000").mkdir()
        (out / "s000" / "part-00000.flac.tmp").symlink_to("/dev/full")

    monkeypatch.setattr(DatasetWriter, "__init__", then_full)
    code, _, err = run(capsys, ["simulate", "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--out", out,
                                "--quiet"])
    assert assert_one_line_error(code, err, "simulate") == (
        f"sonicskin simulate: error: [Errno 28] No space left on device (free some space there, or write elsewhere): "
        f"'{out / 's000' / 'part-00000.flac'}'")


# -- 27.11: a recording whose last labelled chirp is cut short -------------------------------------------------------------
def test_a_last_chirp_cut_short_is_dropped_with_a_warning(five, tmp_path, capsys):
    """A recording stopped ~200 samples early inside its last labelled chirp was refused whole ("the interval ... holds no
    sweep start", though it holds one); it imported before that check (1157add).  An interval without any sweep start
    is still refused (tests/test_hostile_data.py)."""
    import soundfile as sf

    from sonicskin.dsp import frame_stream, rig_chirp

    ds = Dataset(five / "data")
    rig = ds.rig
    (tmp_path / "rec").mkdir()
    rows = [["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n"]]
    for s in ("s000", "s001"):
        audio = session_audio(ds, s)
        rows += press_rows(ds, s)
        if s == "s000":  # the last sweep labelled a touch, and the recording stopped 200 samples before its end
            frames, offset = frame_stream(audio, rig_chirp(rig))  # where the importer finds the sweeps (received)
            start = offset + (frames.shape[0] - 1) * rig.n_chirp
            audio = audio[:start + rig.n_chirp - 200]
            last = start / rig.fs_hz
            a, b = float(f"{last - 0.002:.6f}"), float(f"{last + 0.002:.6f}")
            x, y = ds.layout.coords(np.array([0]))[0]
            rows.append(["s000.wav", f"{a:.6f}", f"{b:.6f}", "0", f"{x:g}", f"{y:g}", "3"])
            line = len(rows)
        sf.write(tmp_path / "rec" / f"{s}.wav", audio, int(rig.fs_hz), subtype="FLOAT")
    (tmp_path / "labels.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    sf.write(tmp_path / "sweep.wav", rig_chirp(rig).astype(np.float32), int(rig.fs_hz), subtype="FLOAT")
    code, _, err = run(capsys, ["import-wav", "--wav-dir", tmp_path / "rec", "--labels", tmp_path / "labels.csv", "--sweep",
                                tmp_path / "sweep.wav", "--out", tmp_path / "d"])
    assert code == 0, err
    warning = (f"sonicskin import-wav: warning: {tmp_path / 'labels.csv'} line {line}: the interval {a:g}-"
               f"{b:g} s of s000.wav holds only the sweep starting at {last:.4f} s, which the recording cuts "
               f"short (200 of its {rig.n_chirp} samples missing at the end of the file): that chirp is left out")
    assert [ln for ln in err.splitlines() if "warning" in ln] == [warning]
    got = Dataset(tmp_path / "d")
    assert got.sessions == ["s000", "s001"]
    t = got.features(progress=False)
    assert (t["session"] == "s000").sum() == len(frames) - 1  # every whole sweep: the cut one left out
    assert sorted(set(t["location"][(t["session"] == "s000") & (t["location"] >= 0)].tolist())) == list(ds.layout.ids)
