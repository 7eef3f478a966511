"""The random scenario family (issue 15.5): every seed another rig, held-out seeds fixed and apart from design seeds."""

import json

import numpy as np
import pytest
import yaml

from sonicskin.rig import Rig, load_yaml, resolve_config
from sonicskin.sim.channel import MATERIALS
from sonicskin.sim.scenario import RandomFamily, Scenario, family_seeds, is_family
from sonicskin.sim.simulator import Simulator
from tests.cli_helpers import SMALL_RIG, run


def test_heldout_seeds_are_fixed_many_and_disjoint_from_design_seeds():
    seeds = family_seeds("random")
    assert len(seeds["heldout"]) >= 10 and len(set(seeds["heldout"])) == len(seeds["heldout"])
    assert not set(seeds["heldout"]) & set(seeds["design"])
    # issue 26: 20 new held-out seeds, the earlier 12 kept apart as "previous" (seen by earlier rounds)
    assert seeds["heldout"] == tuple(range(7033, 7053)) and seeds["previous"] == tuple(range(7001, 7033))
    with pytest.raises(ValueError, match=r"seeds \[7001\] are both held-out and previous seeds"):
        RandomFamily.from_dict({"family": "random", "seeds": {"heldout": [7001], "previous": [7001, 7002]}})
    with pytest.raises(ValueError, match=r"seeds \[3\] are both design and held-out seeds"):
        RandomFamily.from_dict({"family": "random", "seeds": {"design": [1, 2, 3], "heldout": [3, 4]}})
    assert is_family("random") and not is_family("stationary")


def test_two_seeds_draw_different_rigs_and_one_seed_the_same_rig():
    a, b = Scenario.load("random", seed=0), Scenario.load("random", seed=1)
    assert a.to_dict() == Scenario.load("random", seed=0).to_dict()  # deterministic
    da, db = a.to_dict(), b.to_dict()
    differ = {k for k in da if da[k] != db[k]}
    assert {"geometry", "tx_cm", "rx_cm", "layout", "loss_factor", "channel", "link_seed", "temperature"} <= differ
    rig = Rig.from_dict(yaml.safe_load(SMALL_RIG))
    ga, gb = Simulator(a, rig).channel.G_rs, Simulator(b, rig).channel.G_rs
    assert ga.shape == gb.shape and not np.allclose(np.abs(ga), np.abs(gb))


@pytest.mark.parametrize("seed", range(0, 40, 3))
def test_every_draw_is_a_valid_rig_within_the_sourced_ranges(seed):
    fam = RandomFamily.from_dict(load_yaml(resolve_config("random", "scenarios")))
    sc = fam.draw(seed)
    mat = MATERIALS[sc.material]
    assert mat.eta * 0.5 - 1e-5 <= sc.loss_factor <= mat.eta * 2.0 + 1e-5
    assert 1e-3 - 1e-6 <= sc.channel["irregularity"] <= 1e-2 + 1e-6
    L = sc.geometry["length_cm"]
    lay = sc.make_layout()
    assert 4 <= len(lay) <= 16 and sc.repeats == 1 and sc.train_repeats is None and sc.sessions == 4
    # Markers lie between the transducers along the link (>= 2.5 cm from each) and on the surface.
    assert (lay.xy_cm[:, 1] >= sc.tx_cm[1] + 2.5 - 1e-6).all() and (lay.xy_cm[:, 1] <= sc.rx_cm[1] - 2.5 + 1e-6).all()
    assert 0 < sc.tx_cm[1] < L and 0 < sc.rx_cm[1] < L
    if sc.geometry["kind"] == "plate":
        W = sc.geometry["width_cm"]
        assert (lay.xy_cm[:, 0] >= 2 - 1e-6).all() and (lay.xy_cm[:, 0] <= W - 2 + 1e-6).all()
    # One person per session, each pressing every marker once.
    assert sc.subject_per_session and 1 <= len(sc.subjects) <= 3


def test_simulate_cli_draws_the_rig_of_the_seed(tmp_path, capsys):
    (tmp_path / "small.yaml").write_text(SMALL_RIG)
    out = tmp_path / "r5"
    code, _, err = run(capsys, ["simulate", "--scenario", "random", "--seed", "5", "--rig", tmp_path / "small.yaml",
                                "--out", out, "--sessions", "2", "--quiet"])
    assert code == 0, err
    src = json.loads((out / "dataset.json").read_text())["source"]["scenario"]
    want = Scenario.load("random", seed=5).to_dict()
    assert src["name"] == "random-5" and src["geometry"] == want["geometry"] and src["loss_factor"] == want["loss_factor"]
    assert src["sessions"] == 2


def test_benchmark_summary_pairs_rigs_and_floors_score_the_named_split(cli_files, tmp_path):
    """bench_random_rigs: paired differences and t intervals by hand; the floors fit s000 and score s002 + s003."""
    import importlib.util
    from pathlib import Path

    from scipy import stats

    from sonicskin.dataset import Dataset
    from sonicskin.features import touch_mask

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_random_rigs.py"
    spec = importlib.util.spec_from_file_location("bench_random_rigs", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    acc_net, acc_svm, svc = [0.8, 0.6, 0.7], [0.7, 0.6, 0.5], [0.6, 0.65, 0.5]
    rows = [{"net": {"accuracy": a, "within_2cm": a, "force_rmse_n": 2.0, "missed_touch": 0.0, "false_touch": 0.0},
             "svm": {"accuracy": b, "within_2cm": b, "force_rmse_n": 1.0 + i, "missed_touch": 0.0, "false_touch": 0.0},
             "floor": {"svc_accuracy": c, "svr_force_rmse_n": 1.5, "mean_force_rmse_n": 3.0}}
            for i, (a, b, c) in enumerate(zip(acc_net, acc_svm, svc))]
    S = bench.summarize(rows)
    d = np.array(acc_net) - np.array(acc_svm)  # 0.1, 0.0, 0.2
    half = stats.t.ppf(0.975, 2) * d.std(ddof=1) / np.sqrt(3)
    p = S["pairs"]["accuracy/net - accuracy/svm"]
    assert p["mean"] == pytest.approx(0.1) and p["ci95"] == pytest.approx([0.1 - half, 0.1 + half])
    assert S["pairs"]["accuracy/svm - accuracy/svc_floor"]["mean"] == pytest.approx(np.mean([0.1, -0.05, 0.0]))
    assert S["pairs"]["force_rmse_n/svm - force_rmse_n/svr_floor"]["mean"] == pytest.approx(0.5)
    assert S["values"]["force_rmse_n/svm"] == {"mean": pytest.approx(2.0), "std": pytest.approx(1.0), "n": 3}
    # Floors on a real dataset: trained on s000's touches, scored on every touch chirp of the test sessions.
    ds = Dataset(cli_files["data"])
    fl = bench.floors(ds, train=["s000"])
    t = ds.features(progress=False)
    assert fl["n_test_touch"] == int((np.isin(t["session"], ["s002", "s003"]) & touch_mask(t)).sum())
    assert fl["n_train_touch"] == int(((t["session"] == "s000") & touch_mask(t)).sum())
    assert fl["n_bins"] == int(ds.rig.allowed_mask.sum()) and 0 <= fl["svc_accuracy"] <= 1
    assert fl["svr_force_rmse_n"] > 0 and fl["mean_force_rmse_n"] > 0
