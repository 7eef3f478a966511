import json
import subprocess
import sys

import numpy as np

from sonicskin.cli import main
from sonicskin.dataset import Dataset
from sonicskin.evaluate import evaluate_svm


def test_import_sonicskin_does_not_load_torch():
    code = ("import sys, sonicskin, sonicskin.cli, sonicskin.sim, sonicskin.dataset, sonicskin.evaluate, "
            "sonicskin.skin; sys.exit(int('torch' in sys.modules))")
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
    # The pipeline on arrays predicts a location and a force for every touched chirp.
    r = evaluate_svm(Dataset(data), ablations=False, log=lambda *_: None)
    assert r["force"]["n"] == r["localization"]["n"] > 0 and np.isfinite(r["force"]["rmse_n"])


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
