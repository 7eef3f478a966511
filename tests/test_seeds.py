"""The multi-seed comparison's statistics: means, spreads and the paired interval over simulator seeds."""

import json

import numpy as np
import pytest

from sonicskin.seeds import METRICS, compare_seeds, format_markdown, save_seeds, summarize


def _row(acc_net, acc_svm):
    base = {m: 0.0 for m in METRICS}
    return {"net": {**base, "accuracy": acc_net}, "svm": {**base, "accuracy": acc_svm}}


def test_paired_interval_is_over_simulator_seeds():
    # Three simulated datasets; the network trained twice on each; the SVM once (deterministic).
    runs = {0: [_row(0.90, 0.88), _row(0.92, 0.88)],   # net - svm = +0.03 on average
            1: [_row(0.80, 0.80), _row(0.82, 0.80)],   # +0.01
            2: [_row(0.95, 0.91), _row(0.95, 0.91)]}   # +0.04
    s = summarize(runs)["accuracy"]
    d = np.array([0.03, 0.01, 0.04])
    half = 4.302652729911275 * d.std(ddof=1) / np.sqrt(3)  # t(0.975, 2 dof)
    assert s["diff_mean"] == pytest.approx(d.mean())
    assert s["diff_ci95"] == pytest.approx([d.mean() - half, d.mean() + half])
    assert s["net_mean"] == pytest.approx(np.mean([0.90, 0.92, 0.80, 0.82, 0.95, 0.95]))
    assert s["svm_std"] == pytest.approx(np.std([0.88, 0.80, 0.91], ddof=1))
    assert (s["n_sim_seeds"], s["n_net_runs"]) == (3, 6)
    md = format_markdown({"sim_seeds": [0, 1, 2], "train_seeds": [0, 1], "scenarios": {"moving": {"summary": summarize(runs)}}})
    assert "| moving | accuracy | 89.0 ± 6.5 % | 86.3 ± 5.7 % | n/a | +2.7 [-1.1, +6.5] % |" in md


def test_bad_requests_say_what_to_do(tmp_path):
    with pytest.raises(ValueError, match="unknown scenario.*the comparison knows"):
        compare_seeds(["mooving"], cache=tmp_path, out=tmp_path)
    with pytest.raises(ValueError, match="at least 2 simulator seeds"):
        compare_seeds(["moving"], sim_seeds=[0], cache=tmp_path, out=tmp_path)


def test_seeds_json_is_strict_json(tmp_path):
    # No force sensor in the test sessions: the force RMSE is NaN, and so is its interval. seeds.json wrote them as
    # NaN literals, which strict JSON readers (jq, JavaScript's JSON.parse) refuse; they are null now.
    runs = {s: [{k: {**_row(0.9, 0.8)[k], "force_rmse_n": float("nan")} for k in ("net", "svm")}] for s in (0, 1)}
    save_seeds({"sim_seeds": [0, 1], "train_seeds": [0], "scenarios": {"moving": {"summary": summarize(runs)}}}, tmp_path)

    def refuse(literal):
        raise AssertionError(f"seeds.json holds {literal}, which is not JSON")

    doc = json.loads((tmp_path / "seeds.json").read_text(), parse_constant=refuse)
    force = doc["scenarios"]["moving"]["summary"]["force_rmse_n"]
    assert force["diff_ci95"] == [None, None] and force["net_mean"] is None
    assert doc["scenarios"]["moving"]["summary"]["accuracy"]["diff_mean"] == pytest.approx(0.1)  # numbers stay numbers
