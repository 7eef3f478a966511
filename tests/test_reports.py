"""Reports that are true on any data (issue 15.6): the split they name is the split they scored, every touch
chirp of touch-only data is scored, short sessions and SVM-only artifacts work, missing locations are named."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from sonicskin.dataset import Dataset, Split
from sonicskin.features import touch_mask
from sonicskin.fit import build_svm_artifact, prepare
from sonicskin.importers import import_spectra
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario
from tests.cli_helpers import assert_one_line_error, run

EX = Path(__file__).resolve().parents[1] / "examples"
QUIET = {"log": lambda *_: None}


@pytest.fixture(scope="module")
def four_sessions(cli_files, tmp_path_factory) -> Path:
    """The tiny scenario with four sessions (s000-s003)."""
    out = tmp_path_factory.mktemp("rep") / "tiny4"
    sc = Scenario.load(cli_files["scenario"]).replace(sessions=4)
    simulate_dataset(sc, Rig.load(cli_files["rig"]), out, progress=False, **QUIET)
    return out


def _spectra(tmp: Path, name: str, per_location: int, drop: dict | None = None) -> Path:
    """A touch-only spectra table cut from the shipped example: ``per_location`` chirps of each marker per
    session (``drop``: session -> location labels (cm) left out), imported into a dataset."""
    with np.load(EX / "spectra/touches.npz") as z:
        d = {k: z[k] for k in z.files}
    keep = np.zeros(d["session"].size, bool)
    for s in np.unique(d["session"]):
        for loc in np.unique(d["location"]):
            if drop and loc in drop.get(str(s), ()):
                continue
            keep[np.flatnonzero((d["session"] == s) & (d["location"] == loc))[:per_location]] = True
    table = tmp / f"{name}.npz"
    np.savez(table, freqs_hz=d["freqs_hz"], **{k: d[k][keep] for k in ("magnitude_db", "location", "session")})
    return import_spectra(table, tmp / name, **QUIET)


def test_split_with_no_validation_tests_every_other_session(four_sessions):
    t = Dataset(four_sessions).features(progress=False)
    assert Split.make(t, train_sessions=["s000", "s001"], val_sessions=[]).to_dict() == {
        "train": ["s000", "s001"], "val": [], "test": ["s002", "s003"]}
    # The default (val None) still validates on the next session.
    assert Split.make(t, train_sessions=["s000"]).to_dict() == {"train": ["s000"], "val": ["s001"], "test": ["s002", "s003"]}
    p = prepare(four_sessions, n_bins=40, train_sessions=["s000", "s001"], val_sessions=[], progress=False)
    assert p.split.test == ("s002", "s003")


def test_val_none_and_test_reach_training_as_an_empty_validation(four_sessions, capsys):
    from sonicskin.cli import build_parser
    from sonicskin.cli.train import _train_args

    def overrides(*argv):
        a, extra = build_parser().parse_known_args(["compare", "--data", str(four_sessions), *argv])
        args = _train_args(a, str(four_sessions), extra)
        return {args[i]: args[i + 1] for i in range(len(args) - 1) if args[i].startswith("--data.")}

    o = overrides("--train", "s000", "s001", "--test", "s002", "s003")
    assert json.loads(o["--data.train_sessions"]) == ["s000", "s001"] and json.loads(o["--data.val_sessions"]) == []
    o = overrides("--train", "s000", "--val", "none")
    assert json.loads(o["--data.val_sessions"]) == []
    o = overrides("--train", "s000", "--val", "NONE", "--test", "s003")
    assert json.loads(o["--data.val_sessions"]) == []  # --test s003 with no validation: s001, s002 are not used
    code, _, err = run(capsys, ["compare", "--data", four_sessions, "--val", "none", "s001"])
    line = assert_one_line_error(code, err, "compare")
    assert "'none' means no validation session; give it alone" in line


def test_evaluate_report_names_its_sessions_and_counts(four_sessions, tmp_path, capsys):
    code, out, err = run(capsys, ["evaluate", "--data", four_sessions, "--train", "s000", "--test", "s002", "s003",
                                  "--n-bins", "40", "--no-ablations", "--out", tmp_path / "rep"])
    assert code == 0, err
    rep = json.loads((tmp_path / "rep/report.json").read_text())
    assert (rep["train_sessions"], rep["val_sessions"], rep["test_sessions"]) == (["s000"], ["s001"], ["s002", "s003"])
    assert "sessions: train s000 | validation s001 | test s002, s003 (validation held out" in out
    t = Dataset(four_sessions).features(progress=False)
    m = np.isin(t["session"], ["s002", "s003"]) & touch_mask(t)
    assert rep["chirps_per_location"] == {str(i): int(np.sum(t["location"][m] == i)) for i in (0, 1, 2)}
    assert rep["localization"]["n"] == m.sum()


def test_artifact_without_test_sessions_asks_for_them(cli_files, capsys):
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", cli_files["artifact"]])
    line = assert_one_line_error(code, err, "compare")
    assert "was trained on every session of its data (s000, s001, s002)" in line and "--test SESSION" in line


def test_svm_only_artifact_report_names_sessions_counts_and_training_overlap(cli_files, tmp_path, capsys):
    code, out, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", cli_files["artifact"],
                                  "--test", "s002", "--out", tmp_path / "cmp"])
    assert code == 0, err
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    assert list(res["models"]) == ["svm"] and "network" not in out
    assert res["split"] == {"train": ["s000", "s001", "s002"], "val": [], "test": ["s002"]}
    assert "sessions: train s000, s001, s002 | validation none | test s002" in out
    assert res["trained_on_test"] == ["s002"] and "note: s002 trained or validated this artifact: not a held-out test" in out
    # The per-location counts are the touch chirps of s002, counted here from the labels.
    t = Dataset(cli_files["data"]).features(progress=False)
    m = (t["session"] == "s002") & touch_mask(t)
    want = {str(i): int(np.sum(t["location"][m] == i)) for i in (0, 1, 2)}
    assert res["chirps_per_location"] == want and all(n > 0 for n in want.values())
    assert f"scored {sum(want.values())} touch chirps" in out
    assert res["models"]["svm"]["localization"]["n"] == sum(want.values())


def test_touch_only_short_sessions_are_scored_on_every_chirp(tmp_path, capsys):
    # 2 chirps per marker and session: 18-chirp sessions, shorter than a 3 s boot calibration (28 chirps).
    data = _spectra(tmp_path, "short", 2)
    build_svm_artifact(data, tmp_path / "art", train_sessions=["fold1"], progress=False, **QUIET)
    code, out, err = run(capsys, ["compare", "--data", data, "--artifact", tmp_path / "art", "--out", tmp_path / "cmp"])
    assert code == 0, err
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    assert res["split"]["test"] == ["fold2", "fold3"]
    assert res["chirps_per_location"] == {str(i): 4 for i in range(9)}  # 2 per session x 2 test sessions, none skipped
    assert res["models"]["svm"]["localization"]["n"] == 36 and res["coverage_note"] is None
    assert "scored 36 touch chirps: 4 at each of 9 locations" in out
    assert "note: no boot calibration on fold2, fold3 (fewer than the 320 hands-off chirps it needs at the start)" in out
    assert res["models"]["svm"]["detection"]["measurable"] is False


def test_rest_too_short_for_a_reference_scores_every_touch(cli_files, tmp_path, capsys):
    # 0.04 s of rest (7 chirps on the small rig, fewer than MIN_REST_CHIRPS): training falls back to absolute
    # inputs, and a 3 s boot calibration would swallow every press of these 0.3 s-press sessions.
    sc = Scenario.load(cli_files["scenario"]).replace(calibration_s=0.04, gap_s=0.03, touch_s=0.3)
    data = tmp_path / "shortrest"
    simulate_dataset(sc, Rig.load(cli_files["rig"]), data, progress=False, **QUIET)
    with pytest.warns(UserWarning, match="using absolute features"):
        build_svm_artifact(data, tmp_path / "art", n_bins=60, train_sessions=["s000"], progress=False, **QUIET)
    code, out, err = run(capsys, ["compare", "--data", data, "--artifact", tmp_path / "art", "--out", tmp_path / "cmp"])
    assert code == 0, err
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    t = Dataset(data).features(progress=False)
    m = np.isin(t["session"], ["s001", "s002"]) & touch_mask(t)
    assert res["models"]["svm"]["localization"]["n"] == m.sum() > 0
    assert res["no_boot_sessions"] == ["s001", "s002"] and "note: no boot calibration on s001, s002" in out


def test_fewer_locations_than_the_layout_are_named(tmp_path, capsys):
    data = _spectra(tmp_path, "part", 20, drop={"fold3": (5.0, 5.5)})  # the two last markers never touched in fold3
    build_svm_artifact(data, tmp_path / "art", train_sessions=["fold1", "fold2"], progress=False, **QUIET)
    code, out, err = run(capsys, ["compare", "--data", data, "--artifact", tmp_path / "art", "--out", tmp_path / "cmp"])
    assert code == 0, err
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    ds = Dataset(data)
    missing = [str(i) for i, xy in zip(ds.layout.ids, ds.layout.xy_cm) if xy[0] in (5.0, 5.5)]
    assert len(missing) == 2 and all(res["chirps_per_location"][k] == 0 for k in missing)
    assert (f"note: the scored chirps touch 7 of the layout's 9 locations (never touched: {', '.join(missing)}); "
            f"accuracy is over the touched ones only") in out
    assert res["models"]["svm"]["localization"]["n"] == 7 * 20


def test_relative_artifact_on_a_session_without_rest_is_one_line(cli_files, tmp_path, capsys):
    # The artifact's inputs are relative; its test stream here has every hands-off chirp removed.
    from sonicskin.compare import replay_sessions
    from sonicskin.runtime import SkinRuntime

    t = Dataset(cli_files["data"]).features(progress=False)
    te = t.select((t["session"] == "s002") & (t["location"] >= 0))
    with pytest.raises(ValueError, match=r"session s002 starts with 0 hands-off chirps, fewer than the \d+ \(3 s\) .* "
                                         r"record 3 s of rest first, or train with --mode absolute"):
        replay_sessions(SkinRuntime(cli_files["artifact"], "svm"), te, ["s002"])


@pytest.mark.slow
def test_compare_train_two_test_two_trains_without_validation_and_tests_both(four_sessions, tmp_path, monkeypatch, capsys):
    pytest.importorskip("lightning")
    monkeypatch.chdir(tmp_path)
    data = tmp_path / "tiny4"
    shutil.copytree(four_sessions, data)
    code, out, err = run(capsys, ["compare", "--data", data, "--train", "s000", "s001", "--test", "s002", "s003",
                                  "--n-bins", "40", "--runs", tmp_path / "runs", "--out", tmp_path / "cmp",
                                  "--trainer.max_epochs", "1", "--trainer.enable_progress_bar", "false"])
    assert code == 0, err
    res = json.loads((tmp_path / "cmp/compare.json").read_text())
    assert res["split"] == {"train": ["s000", "s001"], "val": [], "test": ["s002", "s003"]}
    assert "sessions: train s000, s001 | validation none | test s002, s003" in out
    assert "(no validation session: on the training sessions s000, s001)" in out  # the val_ metrics of training
    skin = json.loads((tmp_path / "runs/compare-tiny4/artifact/skin.json").read_text())
    assert skin["training"]["split"]["val"] == [] and skin["training"]["split"]["test"] == ["s002", "s003"]
    t = Dataset(data).features(progress=False)
    m = np.isin(t["session"], ["s002", "s003"]) & touch_mask(t)
    # Every touch chirp of both test sessions is scored (the boot calibration takes the rest before the first press).
    assert sum(res["chirps_per_location"].values()) == m.sum() and set(res["models"]) == {"net", "svm", "lda"}


def test_seed_comparison_report_names_each_scenarios_split():
    from sonicskin.seeds import METRICS, format_markdown, summarize

    runs = {s: [{"train_seed": 0, "split": {"train": ["s000"], "val": [], "test": ["s001", "s002"]},
                 "net": {m: 0.5 for m in METRICS}, "svm": {m: 0.4 + 0.01 * s for m in METRICS}}] for s in (0, 1)}
    md = format_markdown({"sim_seeds": [0, 1], "train_seeds": [0],
                          "scenarios": {"moving": {"summary": summarize(runs), "runs": {str(k): v for k, v in runs.items()}}}})
    assert "- moving: train s000 | validation none | test s001, s002" in md


def test_seed_comparison_report_prints_the_plain_floors_and_tolerates_older_results():
    from sonicskin.seeds import METRICS, format_markdown, summarize

    def runs(floor):
        return {s: [{"train_seed": 0, "split": {"train": ["s000"], "val": [], "test": ["s001"]},
                     "net": {m: 0.5 for m in METRICS}, "svm": {m: 0.4 for m in METRICS},
                     **({"floor": floor(s)} if floor else {})}] for s in (0, 1)}

    with_floor = runs(lambda s: {"accuracy": 0.7 + 0.1 * s, "lda_accuracy": 0.9, "force_rmse_n": 1.5})
    older = runs(None)  # a results file written before the floors existed
    md = format_markdown({"sim_seeds": [0, 1], "train_seeds": [0], "scenarios": {
        "moving": {"summary": summarize(with_floor), "runs": {str(k): v for k, v in with_floor.items()}},
        "drift": {"summary": summarize(older), "runs": {str(k): v for k, v in older.items()}}}})
    floors = md[md.index("Plain scikit-learn floors"):]
    row = next(line for line in floors.splitlines() if line.startswith("| moving |"))
    # mean and sample std over the two seeds: SVC 75 ± 7.1 %, LDA 90 ± 0, no normalized SVC, SVR 1.50 N
    assert "75" in row and "7.1" in row and "90" in row and "1.50" in row
    assert "| drift | n/a | n/a | n/a | n/a |" in md
