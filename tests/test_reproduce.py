"""`sonicskin reproduce --quick` end to end: every experiment, both models, every table and figure."""

import json

import pytest

from sonicskin.cli import main

# One quick reproduction per test run, shared by the tests below (`--dist loadfile`: one worker runs them all).


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce") / "rep"
    assert main(["reproduce", "--quick", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_quick_reproduction(quick_run):
    out = quick_run
    md = (out / "report.md").read_text()
    for section in ("Fig. 6b", "Fig. 11", "Fig. 12", "Two months", "Fig. 13", "Table I", "Stationary robot, one-shot",
                    "Fig. 14", "Fig. 15", "Fig. 16"):
        assert f"{section}" in md, section
    for fig in ("fig6b", "fig11", "fig12", "fig13", "fig14", "fig15", "fig16"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    res = json.loads((out / "report.json").read_text())
    # Every number is a mean over the quick run's simulator seeds, with its spread.
    assert res["seeds"] == [0, 1]
    acc = res["fig6b"]["svm"]["ospa"]
    assert len(acc["values"]) == 2 and acc["mean"] == pytest.approx(sum(acc["values"]) / 2) and acc["std"] >= 0
    assert "+-" in md.split("## Table I")[1].split("\n## ")[0]
    # Physical findings that must hold on the simulated rig, whatever the exact numbers:
    assert res["fig6b"]["svm"]["ospa"]["mean"] > res["fig6b"]["svm"]["all_bins"]["mean"] + 0.15  # OSPA matters on a moving robot
    assert all(r["svm"]["accuracy"]["mean"] >= 0.9 for k, r in res["fig16"].items() if "36" not in k)  # two points apart
    assert "net" in res["table1"]["fig14"] and "svm" in res["table1"]["fig15"] and "svm" in res["table1"]["stationary"]


@pytest.mark.slow
def test_reproduce_runs_only_the_named_experiments(tmp_path, quick_run):
    from sonicskin.cli.parser import REPRODUCE_EXPERIMENTS
    from sonicskin.reproduce import EXPERIMENTS

    assert REPRODUCE_EXPERIMENTS == EXPERIMENTS  # the CLI's choices are the experiments
    out = tmp_path / "rep"
    out.mkdir()
    (out / "data").symlink_to(quick_run / "data", target_is_directory=True)  # the quick run's datasets, not simulated again
    assert main(["reproduce", "--quick", "--only", "fig13", "--seeds", "1", "--out", str(out)]) == 0
    md = (out / "report.md").read_text()
    assert "## Fig. 13" in md and "Fig. 6b" not in md and "Table I" not in md
    res = json.loads((out / "report.json").read_text())
    assert res["experiments"] == ["fig13"] and res["seeds"] == [1] and "fig6b" not in res
    assert sorted(p.name for p in out.glob("*.png")) == ["fig13.png"]
    with pytest.raises(ValueError, match="unknown experiment"):
        from sonicskin.reproduce import reproduce
        reproduce(out, quick=True, only=["fig99"])


def test_seed_results_aggregate_to_mean_and_spread():
    import numpy as np

    from sonicskin.reproduce.aggregate import Spread
    from sonicskin.reproduce.aggregate import aggregate as _aggregate

    runs = [{"acc": 0.9, "curve": [0.8, 0.9], "confusion": np.array([[2, 0], [1, 1]]), "errors_cm": np.array([0.0, 1.2]),
             "minutes": 15.0, "model": "first"},
            {"acc": 0.7, "curve": [0.6, 0.9], "confusion": np.array([[1, 1], [0, 2]]), "errors_cm": np.array([2.4]),
             "minutes": 15.0, "model": "second"}]
    agg = _aggregate(runs)
    assert isinstance(agg["acc"], Spread) and float(agg["acc"]) == pytest.approx(0.8) and agg["acc"].std == pytest.approx(0.1)
    assert f"{agg['acc']:.1%}" == "80.0% +- 10.0%"
    assert f"{agg['minutes']:.0f}" == "15"  # no spread, no "+- 0"
    assert [float(x) for x in agg["curve"]] == pytest.approx([0.7, 0.9]) and agg["curve"][1].std == pytest.approx(0.0)
    np.testing.assert_array_equal(agg["confusion"], [[3, 1], [1, 3]])  # counts add up over seeds
    np.testing.assert_array_equal(agg["errors_cm"], [0.0, 1.2, 2.4])  # per-press errors pooled
    assert agg["model"] == "first"


@pytest.mark.parametrize("k", [2, 3, 5])
def test_blas_decision_values_equal_scikit_learns(k):
    """reproduce and the SVM kind score chirps with one BLAS product (ovo_decision); it must be libsvm's decision_function."""
    import numpy as np

    from sonicskin.kinds.svm import fit_pipeline, ovo_decision

    rng = np.random.default_rng(k)
    X = rng.normal(size=(300, 50)).astype(np.float32)
    y = rng.integers(0, k, 300)
    X[np.arange(300), y] += 2.0  # separable enough to have few support vectors, not all
    pipe = fit_pipeline(X, y, k)
    Xq = rng.normal(size=(2100, 50)).astype(np.float32)  # more than one block of 2,048
    ref = pipe.decision_function(Xq)
    got = ovo_decision(pipe, Xq)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
