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
