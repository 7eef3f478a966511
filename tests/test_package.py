import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.evaluate import evaluate_svm


def test_import_sonicskin_does_not_load_torch():
    code = ("import sys, sonicskin, sonicskin.cli, sonicskin.sim, sonicskin.dataset, sonicskin.evaluate, "
            "sonicskin.head, sonicskin.fit, sonicskin.reproduce; sys.exit(int('torch' in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_cli_help_and_errors(capsys):
    assert main([]) == 2
    assert "simulate" in capsys.readouterr().out
    assert main(["simulate", "--scenario", "no-such-scenario"]) == 2
    assert "no scenarios config named 'no-such-scenario'" in capsys.readouterr().err
    assert main(["evaluate", "--data", "/nonexistent"]) == 2
    assert "dataset.json is missing" in capsys.readouterr().err


def test_simulate_then_evaluate_end_to_end(tmp_path, capsys):
    data, rep = tmp_path / "d", tmp_path / "r"
    layout = "{kind: grid, nx: 3, ny: 1, spacing_cm: 1.2, x0_cm: 8, y0_cm: 12}"
    assert main(["simulate", "--scenario", "moving", "--out", str(data), "--sessions", "2", "--quiet",
                 "--set", f"layout={layout}", "--set", "touch_s=1.0", "--set", "moving_s=1.0", "--set", "repeats=2"]) == 0
    assert main(["evaluate", "--data", str(data), "--out", str(rep)]) == 0
    out = capsys.readouterr().out
    assert "localization  accuracy" in out and "OSPA (Fig. 6b)" in out
    res = json.loads((rep / "report.json").read_text())
    assert res["localization"]["accuracy"] > 0.6  # 3 markers 1.2 cm apart, chance is 1/3
    assert (rep / "localization.png").stat().st_size > 10_000
    # The deployed pipeline predicts a location for every touched chirp and a force for every touch it detects.
    r = evaluate_svm(Dataset(data), ablations=False, log=lambda *_: None)
    n, missed = r["localization"]["n"], r["detection"]["missed_touch_rate"]
    assert n > 0 and r["force"]["n"] == round(n * (1 - missed)) > 0 and np.isfinite(r["force"]["rmse_n"])


def test_fit_svm_artifact_without_torch(tmp_path):
    """The paper's system as an artifact on a machine without torch: fit-svm, then the runtime."""
    data = tmp_path / "d"
    layout = "{kind: grid, nx: 3, ny: 1, spacing_cm: 1.2, x0_cm: 8, y0_cm: 12}"
    assert main(["simulate", "--scenario", "stationary", "--out", str(data), "--sessions", "2", "--quiet",
                 "--set", f"layout={layout}", "--set", "touch_s=1.0", "--set", "repeats=2"]) == 0
    code = f"""
import sys, importlib.abc
class NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] == 'torch':
            raise ImportError('torch is not installed on this machine')
sys.meta_path.insert(0, NoTorch())
from sonicskin.cli import main
assert main(['fit-svm', '--data', {str(data)!r}, '--out', {str(tmp_path / 'art')!r}, '--train', 's000', '--n-bins', '50']) == 0
from sonicskin.runtime import SkinRuntime
from sonicskin.dataset import Dataset
import numpy as np
rt = SkinRuntime({str(tmp_path / 'art')!r}, 'svm')
t = Dataset({str(data)!r}).features(progress=False)
s = t['session'] == 's001'
p = rt.replay(t.X[s], t['time_s'][s])
touch = (t['location'][s] >= 0) & (t['force_n'][s] > 1)
assert np.mean(p.location[touch] == t['location'][s][touch]) > 0.6
assert 'torch' not in sys.modules
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    meta = json.loads((tmp_path / "art" / "skin.json").read_text())
    assert set(meta["models"]) == {"svm"} and len(meta["features"]["bins"]) == 50


# -- configs: one lookup, shipped as package data -------------------------------------------------

REPO = Path(__file__).resolve().parent.parent


def test_config_names_resolve_from_the_package_and_paths_from_the_filesystem(tmp_path, monkeypatch):
    from sonicskin.rig import config_dir, config_names, resolve_config

    assert "jaco" in config_names("rigs") and "moving" in config_names("scenarios") and "moving" in config_names("train")
    assert resolve_config("jaco", "rigs") == config_dir() / "rigs" / "jaco.yaml"
    monkeypatch.chdir(tmp_path)  # a bare name does not depend on the working directory ...
    assert resolve_config("moving", "train").is_file()
    (tmp_path / "mine.yaml").write_text("fs_hz: 96000\nf_hi_hz: 40000\n")
    assert resolve_config("mine.yaml", "rigs") == Path("mine.yaml")  # ... a path is read where it is
    assert resolve_config(tmp_path / "mine.yaml", "rigs") == tmp_path / "mine.yaml"
    with pytest.raises(FileNotFoundError, match=r"no rigs config named 'mine'; known: fast, jaco; or give a path"):
        resolve_config("mine", "rigs")
    with pytest.raises(FileNotFoundError, match=r"rigs config file sub/jaco.yaml does not exist"):
        resolve_config("sub/jaco.yaml", "rigs")
    with pytest.raises(ValueError, match="unknown config kind 'rig'; valid kinds: rigs, scenarios, links, arms, train"):
        config_names("rig")


def _installed_copy(site: Path, *, with_configs: bool) -> None:
    """The sonicskin package laid out as a wheel installs it: no repository around it."""
    shutil.copytree(REPO / "sonicskin", site / "sonicskin", ignore=shutil.ignore_patterns("__pycache__"))
    if with_configs:
        shutil.copytree(REPO / "configs", site / "sonicskin" / "configs")


def test_an_installed_package_reads_its_own_configs(tmp_path):
    """What `pip install .` gives (.ci/deploy-check proves it with a real wheel): configs inside the package."""
    site, elsewhere = tmp_path / "site", tmp_path / "cwd"
    _installed_copy(site, with_configs=True)
    elsewhere.mkdir()
    code = ("from sonicskin.rig import Rig, config_dir; from sonicskin.sim.scenario import Scenario; "
            "from sonicskin.cli import main; print(config_dir()); print(float(Rig.load('jaco').fs_hz)); "
            "print(Scenario.load('moving').name); main(['info'])")
    env = {**os.environ, "PYTHONPATH": str(site)}
    r = subprocess.run([sys.executable, "-c", code], cwd=elsewhere, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines[:3] == [str(site / "sonicskin" / "configs"), "192000.0", "moving"]
    assert any(x.startswith("scenarios: ") and "moving" in x for x in lines[3:]), r.stdout  # sonicskin info


def test_a_package_installed_without_configs_says_so(tmp_path):
    site = tmp_path / "site"
    _installed_copy(site, with_configs=False)
    env = {**os.environ, "PYTHONPATH": str(site)}
    r = subprocess.run([sys.executable, "-m", "sonicskin", "info"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "no rigs config named 'jaco'; known: none" in r.stderr and "installed without its configs" in r.stderr


MAPPED = ("models", "training", "export")  # repository folders installed as sonicskin.<name>


def test_pyproject_ships_every_package_and_config_folder():
    """The wheel's package list is explicit (configs/ is mapped in): a new package folder must be listed."""
    tomllib = pytest.importorskip("tomllib")
    from sonicskin.rig import CONFIG_KINDS

    st = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    code = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "sonicskin").rglob("__init__.py")}
    code |= {f"sonicskin.{'.'.join(p.parent.relative_to(REPO).parts)}" for root in MAPPED
             for p in (REPO / root).rglob("__init__.py")}
    kinds = sorted(p.name for p in (REPO / "configs").iterdir() if p.is_dir())
    want = code | {"sonicskin.configs"} | {f"sonicskin.configs.{k}" for k in kinds}
    listed = set(st["packages"])
    assert not want - listed, f"add {sorted(want - listed)} to [tool.setuptools] packages in pyproject.toml"
    assert not listed - want, f"[tool.setuptools] packages lists {sorted(listed - want)}, which has no folder"
    assert st["package-dir"] == {"sonicskin.configs": "configs", **{f"sonicskin.{m}": m for m in MAPPED}}
    assert sorted(CONFIG_KINDS) == kinds


@pytest.mark.slow
def test_built_wheel_holds_one_top_level_package(tmp_path):
    """`pip install sonicskin` adds exactly one importable name to site-packages: sonicskin."""
    import zipfile

    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path),
                        str(REPO)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    (whl,) = tmp_path.glob("sonicskin-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith((".dist-info", ".data"))}
    assert top == {"sonicskin"}, f"the wheel installs top-level {sorted(top)}"
    for mod in ("sonicskin/models/__init__.py", "sonicskin/training/module.py", "sonicskin/export/onnx.py",
                "sonicskin/configs/rigs/jaco.yaml", "sonicskin/view.html", "sonicskin/msg/ros2.msg",
                "sonicskin/msg/sonicskin_msgs/package.xml", "sonicskin/msg/sonicskin_msgs/CMakeLists.txt",
                "sonicskin/msg/sonicskin_msgs/msg/Contact.msg", "sonicskin/configs/arms/arm6.foxglove.json"):
        assert mod in names, f"the wheel lacks {mod}"
