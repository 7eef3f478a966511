"""`sonicskin reproduce` end to end on tiny datasets: every experiment, both models, every table and figure, and
--only.  The quick reproduction itself (its physical findings: OSPA matters on a moving robot, two points apart are
told apart) is `benchmarks/check_reproduce.py`, run with the stored result reproduce-quick (minutes on 2 cores)."""

import json

import pytest

from sonicskin.cli import main


def _tiny(datasets):
    """Every dataset of the experiments, shorter: presses of 0.6 s (0.9 s where a force curve is fitted on few presses),
    1 s of moving, 3 drift sessions."""
    def tiny(quick):
        out = {}
        for k, (scenario, over) in datasets(quick).items():
            over = {**over, "touch_s": 0.9 if k.startswith(("two-points", "plate")) else 0.6, "gap_s": 0.2,
                    "calibration_s": 3.0, "moving_s": 1.0, **({"sessions": 3} if k.startswith("drift") else {})}
            out[k] = (scenario, over)
        return out
    return tiny


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One reproduction through the CLI (one process: the tiny datasets reach it; one simulator seed, one epoch)."""
    from sonicskin import reproduce
    from sonicskin.reproduce import context

    mp = pytest.MonkeyPatch()
    tiny = _tiny(context.datasets)
    mp.setattr(context, "datasets", tiny)
    mp.setattr(reproduce, "datasets", tiny)
    mp.setattr(context, "QUICK_SIZE", {})
    init = context.Context.__init__

    def one_epoch(self, *a, **kw):
        init(self, *a, **kw)
        self.epochs = 1

    mp.setattr(context.Context, "__init__", one_epoch)
    out = tmp_path_factory.mktemp("reproduce") / "rep"
    try:
        assert main(["reproduce", "--quick", "--seeds", "0", "--jobs", "1", "--out", str(out)]) == 0
        yield out, mp
    finally:
        mp.undo()


def test_reproduction_runs_every_experiment_and_writes_every_table_and_figure(tiny_run):
    out, _ = tiny_run
    md = (out / "report.md").read_text()
    for section in ("Fig. 6b", "Fig. 11", "Fig. 12", "Two months", "Fig. 13", "Table I", "Stationary robot, one-shot",
                    "Fig. 14", "Fig. 15", "Fig. 16"):
        assert f"{section}" in md, section
    for fig in ("fig6b", "fig11", "fig12", "fig13", "fig14", "fig15", "fig16"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    res = json.loads((out / "report.json").read_text())
    assert res["seeds"] == [0] and res["experiments"] == ["fig6b", "fig11", "fig12", "fig13", "table1", "fig16"]
    acc = res["fig6b"]["svm"]["ospa"]
    assert len(acc["values"]) == 1 and 0 <= acc["mean"] <= 1 and acc["std"] == 0
    assert "net" in res["table1"]["fig14"] and "svm" in res["table1"]["fig15"] and "svm" in res["table1"]["stationary"]
    assert all(0 <= r["svm"]["accuracy"]["mean"] <= 1 for r in res["fig16"].values())


def test_reproduce_runs_only_the_named_experiments_and_averages_seeds(tmp_path, tiny_run):
    from sonicskin.cli.parser import REPRODUCE_EXPERIMENTS
    from sonicskin.reproduce import EXPERIMENTS

    assert REPRODUCE_EXPERIMENTS == EXPERIMENTS  # the CLI's choices are the experiments
    out = tmp_path / "rep"
    out.mkdir()
    (out / "data").symlink_to(tiny_run[0] / "data", target_is_directory=True)  # seed 0's datasets, not simulated again
    assert main(["reproduce", "--quick", "--only", "fig13", "--seeds", "0", "1", "--jobs", "1", "--out", str(out)]) == 0
    md = (out / "report.md").read_text()
    assert "## Fig. 13" in md and "Fig. 6b" not in md and "Table I" not in md
    assert "+-" in md.split("## Fig. 13")[1]  # every number a mean over the seeds, with its spread
    res = json.loads((out / "report.json").read_text())
    assert res["experiments"] == ["fig13"] and res["seeds"] == [0, 1] and "fig6b" not in res
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
