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


# -- provenance: what made a cached dataset or a stored run is checked before either is re-used


def test_code_digest_follows_every_source_byte_and_name(tmp_path, monkeypatch):
    from sonicskin.feature_cache import code_digest
    from sonicskin.seeds import run_code

    pkg = tmp_path / "fakepkg_provenance"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("x = 1\n")
    (pkg / "sub" / "a.py").write_text("y = 2\n")
    (tmp_path / "fakemod_provenance.py").write_text("z = 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    d0 = code_digest("fakepkg_provenance")
    assert d0 == code_digest("fakepkg_provenance") and len(d0) == 16  # stable
    (pkg / "notes.txt").write_text("not source")
    assert code_digest("fakepkg_provenance") == d0
    (pkg / "sub" / "a.py").write_text("y = 3\n")  # one byte of a nested module
    assert code_digest("fakepkg_provenance") != d0
    (pkg / "sub" / "a.py").write_text("y = 2\n")
    assert code_digest("fakepkg_provenance") == d0
    (pkg / "sub" / "a.py").rename(pkg / "sub" / "b.py")  # same bytes, another name
    assert code_digest("fakepkg_provenance") != d0
    m0 = code_digest("fakemod_provenance")  # a plain module: its one file
    (tmp_path / "fakemod_provenance.py").write_text("z = 4\n")
    assert code_digest("fakemod_provenance") != m0
    assert code_digest("fakepkg_provenance", "fakemod_provenance") != code_digest("fakepkg_provenance")
    with pytest.raises(ModuleNotFoundError):
        code_digest("no_such_module_provenance")
    assert len(run_code()) == 16  # the package and the folders pyproject.toml maps into it are all found


def test_a_cached_scenario_is_reused_only_with_its_made_by_stamp(tmp_path, monkeypatch):
    from cli_helpers import SMALL_RIG, TINY_SCENARIO

    import sonicskin.seeds as seeds
    from sonicskin.rig import Rig

    (tmp_path / "small.yaml").write_text(SMALL_RIG)
    (tmp_path / "tiny.yaml").write_text(TINY_SCENARIO)
    monkeypatch.chdir(tmp_path)  # the scenario by a relative path: the cache folder is named after it
    made, lines = [], []
    real = seeds.simulate_dataset
    monkeypatch.setattr(seeds, "simulate_dataset", lambda *a, **k: made.append(1) or real(*a, **k))

    def get():
        return seeds.scenario_dataset("tiny.yaml", 4, tmp_path / "cache", rig=Rig.load(tmp_path / "small.yaml"),
                                      log=lines.append, sessions=1)

    ds = get()
    stamp = ds.root / ".cache" / "made-by.json"
    doc = json.loads(stamp.read_text())
    assert doc["code"] == seeds.code_digest(*seeds.SIM_CODE) and doc["scenario"]["sessions"] == 1 and doc["rig"]["name"] == "small"
    assert len(made) == 1 and ds.sessions == ["s000"]
    get()
    assert len(made) == 1 and not any("simulated again" in m for m in lines)  # the matching stamp: reused
    stamp.write_text(json.dumps({**doc, "code": "0" * 16}))  # made by other code
    get()
    assert len(made) == 2 and any("simulated again, it was made with other code (0000000000000000" in m for m in lines)
    assert json.loads(stamp.read_text()) == doc
    stamp.unlink()  # made before stamps (or interrupted)
    get()
    assert len(made) == 3 and "no readable .cache/made-by.json" in lines[-2] and stamp.is_file()
    assert seeds._stamp_differs(ds.root, {**doc, "scenario": {**doc["scenario"], "sessions": 2}}) == "it was made with another scenario"
    assert seeds._stamp_differs(ds.root, {**doc, "rig": {**doc["rig"], "n_chirp": 2048}}) == "it was made with another rig"


def test_a_stored_run_of_other_code_is_not_resumed(tmp_path, monkeypatch):
    import importlib.util
    from pathlib import Path

    import sonicskin.seeds as seeds

    lines = []
    key = {"code": seeds.run_code(), "epochs": None}
    done = tmp_path / "run.json"
    assert seeds.stored_run(done, key, lines.append) is None and not lines  # nothing stored: nothing to say
    done.write_text(json.dumps({"key": key, "rows": [1]}))
    assert seeds.stored_run(done, key, lines.append) == {"key": key, "rows": [1]} and not lines
    done.write_text(json.dumps({"key": {**key, "code": "0" * 16}, "rows": [1]}))
    assert seeds.stored_run(done, key, lines.append) is None and "made by other code (0000000000000000" in lines[-1]
    done.write_text(json.dumps({"key": {"epochs": None}, "rows": [1]}))  # stored before runs named their code
    assert seeds.stored_run(done, key, lines.append) is None and "names no code" in lines[-1]

    # sweep_probe: a configuration stored by other code is run again; its key names the code, epochs and overrides
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "sweep_probe.py"
    spec = importlib.util.spec_from_file_location("sweep_probe", path)
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    assert probe.run_key(3) == {"code": seeds.run_code(), "epochs": 3, "overrides": probe.OVERRIDES}
    done.write_text(json.dumps({"scenario": "moving", "key": {**probe.run_key(3), "code": "0" * 16}}))
    assert seeds.stored_run(done, probe.run_key(3), lines.append) is None
    done.write_text(json.dumps({"scenario": "moving", "key": probe.run_key(3)}))
    assert seeds.stored_run(done, probe.run_key(3), lines.append)["scenario"] == "moving"

    # compare --sim-seeds: seed 0 stored by other code is run again, seed 1 stored by this code is resumed
    ran = []
    monkeypatch.setattr(seeds, "scenario_dataset", lambda name, s, *a, **k: s)
    monkeypatch.setattr(seeds, "_one_seed", lambda name, s, *a, **k: ran.append(s) or [_row(0.5, 0.5)])
    monkeypatch.setattr(seeds, "save_seeds", lambda res, out: [])
    from sonicskin.rig import Rig

    rig = Rig.load("jaco")
    want = {"code": seeds.run_code(), "train_seeds": [0], "epochs": 1, "select": True, "rig": rig.to_dict(), "val": False}
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "moving-seed0.json").write_text(json.dumps({"key": {**want, "code": "0" * 16}, "rows": [_row(0.9, 0.9)]}))
    (tmp_path / "runs" / "moving-seed1.json").write_text(json.dumps({"key": want, "rows": [_row(0.8, 0.8)]}))
    res = seeds.compare_seeds(["moving"], sim_seeds=[0, 1], train_seeds=[0], epochs=1, out=tmp_path, cache=tmp_path,
                              log=lines.append)
    assert ran == [0] and "moving-seed0.json: not resumed, it was made by other code" in lines[-1]
    runs = res["scenarios"]["moving"]["runs"]
    assert runs["0"][0]["net"]["accuracy"] == 0.5 and runs["1"][0]["net"]["accuracy"] == 0.8
    assert json.loads((tmp_path / "runs" / "moving-seed0.json").read_text())["key"] == want  # stored with this code now
