"""Model selection on the user's own presses (sonicskin.selection, issue 15): presses, folds, choices that
follow the data, validation that never sees test sessions, the pooled force model and the network's touch decision."""

import json
import shutil

import numpy as np
import pytest
from cli_helpers import reseal

from sonicskin.force import PerLocationForce, PooledForce, PooledSVR
from sonicskin.selection import (
    PAPER,
    gamma_grid,
    make_cv,
    press_ids,
    press_passes,
    select_force,
    select_localizer,
)


def test_press_ids_are_runs_of_one_location_within_a_session():
    loc = np.array([-1, -1, 0, 0, 0, -1, 1, 1, 0, 0, 0, 2, 2])
    ses = np.array(["a"] * 10 + ["b"] * 3)
    # the run of 0s continues across the session change at row 10: a new press there
    assert press_ids(loc, ses).tolist() == [-1, -1, 0, 0, 0, -1, 1, 1, 2, 2, 3, 4, 4]
    seg = np.array(["x"] * 4 + ["y"] * 9)  # a segment change inside a run also starts a new press
    assert press_ids(loc, ses, seg).tolist() == [-1, -1, 0, 0, 1, -1, 2, 2, 3, 3, 4, 5, 5]
    p = press_ids(loc, ses)
    assert press_passes(p, loc).tolist() == [-1, -1, 0, 0, 0, -1, 0, 0, 1, 1, 2, 0, 0]


def test_folds_never_split_a_press_and_train_every_location():
    loc = np.repeat(np.tile(np.arange(4), 3), 5)  # 3 passes over 4 locations, 5 chirps per press
    ses = np.repeat(["s0"], loc.size)
    press = press_ids(loc, ses)
    passes = press_passes(press, loc)
    cv, how = make_cv(passes, location=loc)
    assert how == "3-fold cross-validation over passes"
    for tr, te in cv.split(np.zeros((loc.size, 1)), loc):
        assert not set(press[tr]) & set(press[te])
        assert set(loc[tr]) == set(range(4))
    assert make_cv(np.zeros(8, int))[0] is None
    # one location pressed once: it could not be trained in the fold that holds its press -> no cross-validation
    once = np.r_[passes, 0, 0]
    assert make_cv(once, location=np.r_[loc, 4, 4]) == (None, "one press per location and no validation session")
    # a validation session: train on the rest, score on it
    cv, how = make_cv(passes, val=np.arange(loc.size) >= 40, location=loc)
    assert how == "validation session" and cv.get_n_splits() == 1


def _rig_data(n_informative: int, *, n_feat: int = 600, n_loc: int = 5, n_pass: int = 3, per_press: int = 8,
              effect: float = 1.0, seed: int = 0):
    """Touch chirps of a synthetic rig: each location shifts ``n_informative`` bins, the rest is noise."""
    rng = np.random.default_rng(seed)
    means = np.zeros((n_loc, n_feat))
    means[:, :n_informative] = rng.normal(0, effect, (n_loc, n_informative))
    loc = np.repeat(np.tile(np.arange(n_loc), n_pass), per_press)
    press_shift = np.repeat(rng.normal(0, 0.3, (n_loc * n_pass, n_feat)), per_press, axis=0)  # each press is a bit off
    X = means[loc] + press_shift + rng.normal(0, 1.0, (loc.size, n_feat))
    press = press_ids(loc, np.zeros(loc.size, int))
    return X, loc, press, press_passes(press, loc)


def test_gamma_follows_the_number_of_informative_bins():
    few = select_localizer(*_rig_data(40, effect=0.7), log=lambda m: None)
    many = select_localizer(*_rig_data(600, effect=0.2), log=lambda m: None)
    assert few["status"] == many["status"] == "validated"
    grid = gamma_grid(600)
    assert grid[0] == PAPER["n_bins"] and min(grid) == 100 and max(grid) == 600
    assert few["params"]["n_bins"] < many["params"]["n_bins"]
    assert many["params"]["n_bins"] == 600 and few["params"]["n_bins"] <= 150
    # the estimate is what the chosen candidate scored on presses it was not trained on
    assert 0.0 <= few["estimate"]["accuracy"] <= 1.0 and few["estimate"]["n_presses"] == 15
    assert few["cv"][0]["accuracy"] == pytest.approx(max(r["accuracy"] for r in few["cv"]))
    lc = many["learning_curve"]
    assert lc["presses_per_location"] == [1, 2] and len(lc["accuracy"]) == 2


def test_one_press_per_location_falls_back_to_the_paper_with_a_reason():
    X, loc, press, passes = _rig_data(40, n_pass=1)
    msgs = []
    sel = select_localizer(X, loc, press, passes, log=msgs.append)
    assert sel["status"] == "fallback" and sel["params"] == {"n_bins": 300, "C": 10.0, "kernel_width": 1.0}
    assert msgs == ["warning: model selection needs a validation session or at least two presses per location "
                    "(one press per location and no validation session); keeping the paper's gamma 300, C 10, "
                    "kernel width 'scale'"]


def test_pooled_force_wins_when_force_is_shared_across_locations_and_round_trips_json():
    rng = np.random.default_rng(1)
    n_loc, n_pass, per = 4, 3, 20
    loc = np.repeat(np.tile(np.arange(n_loc), n_pass), per)
    F = rng.uniform(1, 10, loc.size)
    w = rng.normal(0, 1, 30)
    inputs = np.outer(F, w) / 5 + rng.normal(0, 0.5, (loc.size, 30))  # one physics for every location
    E = 10 * np.log10(np.mean(10 ** (inputs / 10), axis=1))
    press = press_ids(loc, np.zeros(loc.size, int))
    sel = select_force(E, loc, inputs, F, press, press_passes(press, loc), log=lambda m: None)
    assert sel["model"] == "pooled-ridge" and sel["estimate"]["rmse_n"] < sel["fourier1_rmse_n"]
    assert sel["estimate"]["rmse_n"] < 0.5 * sel["constant_rmse_n"]
    pf = PooledForce(sel["alpha"]).fit(inputs, F, loc)
    back = PerLocationForce.from_dict(json.loads(json.dumps(pf.to_dict())))
    assert isinstance(back, PooledForce)
    np.testing.assert_allclose(back.predict(E, loc, inputs=inputs), pf.predict(E, loc, inputs=inputs), rtol=1e-12)


def test_the_pooled_svr_wins_where_force_bends_the_spectrum_nonlinearly_and_runs_as_scikit_learns():
    """Force that saturates the inputs (a firm press changes little more): neither a ridge nor a per-location energy
    curve follows it, the pooled SVR does (issue 36: the SVR floor is a candidate); its numbers in skin.json predict
    what scikit-learn's StandardScaler + SVR() predicts."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVR

    rng = np.random.default_rng(2)
    n_loc, n_pass, per = 4, 3, 25
    loc = np.repeat(np.tile(np.arange(n_loc), n_pass), per)
    F = rng.uniform(0.5, 10, loc.size)
    w = rng.normal(0, 1, 30)
    inputs = np.outer(np.tanh((F - 5) / 1.5), w) * 3 + np.outer(np.cos(F), rng.normal(0, 1, 30)) + rng.normal(0, 0.2, (loc.size, 30))
    E = 10 * np.log10(np.mean(10 ** (inputs / 10), axis=1))
    press = press_ids(loc, np.zeros(loc.size, int))
    sel = select_force(E, loc, inputs, F, press, press_passes(press, loc), log=lambda m: None)
    ridge = min(r["rmse_n"] for r in sel["cv"] if r["model"] == "PooledRidge")
    assert sel["model"] == "pooled-svr" and sel["estimate"]["rmse_n"] < min(ridge, sel["fourier1_rmse_n"])
    m = PooledSVR().fit(inputs, F)
    back = PerLocationForce.from_dict(json.loads(json.dumps(m.to_dict())))
    assert isinstance(back, PooledSVR)
    wider = np.column_stack([inputs, rng.normal(size=(loc.size, 5))])  # it reads its first inputs only
    got = back.predict(E, loc, inputs=wider)
    np.testing.assert_allclose(got, make_pipeline(StandardScaler(), SVR()).fit(inputs, F).predict(inputs), atol=1e-3)


@pytest.mark.slow
def test_validation_never_sees_test_sessions(cli_files, tmp_path):
    """fit-svm trained on s000 + s001 (two presses per location: cross-validated): the test session s002's audio and
    labels changed -> bit-identical choice, svm.onnx and skin.json (but the data path)."""
    import soundfile as sf

    from sonicskin.fit import build_svm_artifact

    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(cli_files["data"], a, ignore=shutil.ignore_patterns(".cache"))
    shutil.copytree(cli_files["data"], b, ignore=shutil.ignore_patterns(".cache"))
    for part in sorted((b / "s002").glob("part-*.flac")):
        x, sr = sf.read(part, dtype="float32")
        sf.write(part, np.clip(x * 0.5 + 0.01 * np.random.default_rng(0).standard_normal(x.size), -1, 1), sr,
                 format="FLAC", subtype="PCM_24")
    for csv in sorted((b / "s002").glob("part-*.csv")):
        lines = csv.read_text().splitlines()
        head, rows = lines[0], [r.split(",") for r in lines[1:]]
        col = head.split(",").index("location")
        for r in rows:  # every touch label moved to another location
            if int(r[col]) >= 0:
                r[col] = str((int(r[col]) + 1) % 3)
        csv.write_text("\n".join([head] + [",".join(r) for r in rows]) + "\n")
    # The edit is a deliberate new recording of s002, so its manifest is re-sealed (else the reader refuses it).
    reseal(b / "s002")
    skins = [build_svm_artifact(d, tmp_path / f"art-{d.name}", train_sessions=["s000", "s001"], progress=False,
                                log=lambda m: None) for d in (a, b)]
    assert skins[0]["selection"]["svm"]["status"] == "validated"
    assert skins[0]["selection"] == skins[1]["selection"]
    for s in skins:
        s["training"].pop("data")
        s["training"].pop("svm_train_time_s")
        s.pop("digest")  # covers training.data, the one field that names the (different) dataset folder
    assert skins[0] == skins[1]
    assert (tmp_path / "art-a/svm.onnx").read_bytes() == (tmp_path / "art-b/svm.onnx").read_bytes()


def test_network_touch_decision_follows_the_chosen_detector():
    pytest.importorskip("torch")
    from sonicskin.training.quick import choose_detector

    from sonicskin.kinds.net import NetHead
    from sonicskin.rig import Layout

    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, (50, 6))
    logits = np.log(np.full((50, 4), 0.25))
    det = {"mode": "input-rms", "bias": 0.0, "threshold": 1.0, "reference": [0.0] * 6, "bins": 6}
    p = NetHead({"detector": det}, Layout.grid(3, 1, 1.0)).decide([logits, np.zeros((50, 3))], x)
    np.testing.assert_array_equal(p.touch, np.sqrt(np.mean(x ** 2, 1)) >= 1.0)  # the head applies the chosen detector
    # choose_detector (which runs that same head) keeps the misses within half a point of the input-RMS detector's
    rng = np.random.default_rng(0)
    touch = np.r_[np.ones(200, bool), np.zeros(200, bool)]
    X = np.where(touch[:, None], rng.normal(0, 2.0, (400, 6)), rng.normal(0, 0.3, (400, 6)))
    logits = np.zeros((400, 4))
    logits[:, -1] = np.where(touch & (rng.random(400) < 0.1), 5.0, -5.0)  # the head misses 10 % and never false-alarms
    logits[~touch, -1] = 5.0
    d = choose_detector(logits, X, touch, ~touch, threshold=1.0, reference=np.zeros(6), how="test")
    assert d["rates"]["head"]["missed"] > 0.05
    assert d["rates"][d["detector"]]["missed"] <= d["rates"]["input-rms"]["missed"] + 0.005


def test_threshold_sits_in_the_middle_of_a_clean_gap_and_prefers_fewer_misses():
    from sonicskin.selection import select_threshold

    d = select_threshold(np.array([2.0, 3.0, 5.0]), np.array([0.2, 0.5, 1.0]), how="val")
    assert d["threshold"] == pytest.approx(1.5) and d["missed_touch_rate"] == d["false_touch_rate"] == 0.0
    # overlap: J = 2/3 both at 0.65 (no miss, one false touch) and at 1.5 (one miss, none false): the lower wins
    d = select_threshold(np.array([0.8, 2.0, 3.0]), np.array([0.2, 0.5, 1.0]), how="val")
    assert d["threshold"] == pytest.approx(0.65) and d["missed_touch_rate"] == 0.0
    assert d["false_touch_rate"] == pytest.approx(1 / 3)


def test_intervals_stay_inside_what_the_quantity_can_be():
    # Per-press RMSEs of 0.1 and 5 N: the plain t interval of their mean reaches far below 0 N, which no RMSE can.
    from sonicskin.metrics import t_interval as _t_interval

    lo, hi = _t_interval(np.array([0.1, 5.0]))
    assert lo < -20 and hi > 25
    assert _t_interval(np.array([0.1, 5.0]), (0.0, np.inf)) == [0.0, hi]
    assert _t_interval(np.array([0.9, 1.0, 0.2]), (0.0, 1.0))[1] == 1.0  # an accuracy stays <= 1
    assert all(np.isnan(_t_interval(np.array([3.0]), (0.0, np.inf))))  # one press: no interval, not a clipped 0
