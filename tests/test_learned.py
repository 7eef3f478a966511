"""The learned-model path: Lightning training, ONNX export with parity, torch-free runtime, compare."""

import json
import shutil
import subprocess
import sys

import pytest

pytest.importorskip("torch")
pytest.importorskip("lightning")

from sonicskin.compare import compare_artifact, format_comparison  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.runtime import ArtifactError, SkinRuntime  # noqa: E402
from sonicskin.sim.generate import simulate_dataset  # noqa: E402
from sonicskin.sim.scenario import Scenario  # noqa: E402

TINY = dict(sessions=3, layout={"kind": "grid", "nx": 3, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
            touch_s=1.5, gap_s=0.3, calibration_s=3.0, repeats=2, motion={"enabled": True}, moving_s=1.0, seed=5)


def _train(data, root, *extra):
    from sonicskin.training.cli import main

    return main(["--config", "configs/train/moving.yaml", "--data.data", str(data), "--trainer.default_root_dir", str(root),
                 "--trainer.logger.init_args.save_dir", str(root), "--trainer.enable_progress_bar", "false",
                 "--data.n_bins", "60", *extra])


@pytest.fixture(scope="module")
def artifact(tmp_path_factory, rig):
    from sonicskin.training.fit import artifact_from_checkpoint as export_artifact

    root = tmp_path_factory.mktemp("learned")
    data = root / "data"
    simulate_dataset(Scenario(**TINY), rig, data, progress=False, log=lambda *_: None)
    cli = _train(data, root / "run", "--trainer.max_epochs", "15")
    ckpt = cli.trainer.checkpoint_callback.last_model_path
    skin = export_artifact(ckpt, root / "art", log=lambda *_: None)
    return root / "art", data, skin


def data_rig_allowed(data) -> int:
    from sonicskin.dataset import Dataset

    return int(Dataset(data).rig.allowed_mask.sum())


def test_fast_dev_run(tmp_path, artifact):
    _, data, _ = artifact
    cli = _train(data, tmp_path, "--trainer.fast_dev_run", "true")
    assert cli.trainer.state.finished
    # linked from the data: every usable bin in OSPA's order (the SVM reads the first 60, --data.n_bins)
    assert cli.model.hparams.n_in == cli.datamodule.n_in == int(data_rig_allowed(data)) and cli.model.model.n_locations == 3
    assert cli.model.model.n_in <= cli.model.hparams.n_in


def test_export_parity_and_metadata(artifact):
    art, _, skin = artifact
    for k in ("net", "svm"):
        par = skin["models"][k]["parity"]
        # near ties: chirps whose top two location logits sit within rounding (hands-off chirps of an MLP mostly)
        assert par["labels_equal"] and par["near_ties"] < 26  # < 5 % of the 512 checked
        outs = [kk[8:] for kk in par if kk.startswith("max_abs_")]
        assert len(outs) == 2 and all(0 <= par[f"max_abs_{o}"] <= par[f"{o}_tol"] < 0.1 for o in outs)
    assert skin["models"]["svm"]["n_in"] == 60 and skin["rig"]["fs_hz"] == 192000
    assert skin["models"]["net"]["n_in"] <= len(skin["features"]["bins"])  # a prefix of every usable bin, OSPA order
    # an MLP on every usable bin of the jaco rig is 5014 x 128 float32 weights: 2.6 MB
    assert not list(art.glob("*.pkl")) and (art / "net.onnx").stat().st_size < 4_000_000
    # The final config is saved beside the checkpoints.
    assert list((art.parent / "run").rglob("config.yaml"))


def test_runtime_works_without_torch(artifact):
    art, data, _ = artifact
    code = f"""
import sys, importlib.abc
class NoTorch(importlib.abc.MetaPathFinder):  # this process behaves as a machine without torch
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] == 'torch':
            raise ImportError('torch is not installed on this machine')
sys.meta_path.insert(0, NoTorch())
from sonicskin.runtime import SkinRuntime
from sonicskin.dataset import Dataset
import numpy as np
t = Dataset({str(data)!r}).features(progress=False)
for k in ('net', 'svm'):
    rt = SkinRuntime({str(art)!r}, k)
    s = t['session'] == 's002'
    p = rt.replay(t.X[s], t['time_s'][s])  # the test stream as the live loop runs it
    touch = (t['location'][s] >= 0) & (t['force_n'][s] > 1)
    acc = np.mean(p.location[touch] == t['location'][s][touch])
    assert acc > 0.6, (k, acc)
    assert p.xy_cm.shape == (s.sum(), 2) and np.all(p.force_n[~p.touch] == 0)
assert 'torch' not in sys.modules
print('ok')
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "ok"


def test_artifact_mismatch_errors(artifact, tmp_path):
    art, _, _ = artifact
    with pytest.raises(ArtifactError, match=r"trained for another rig \(fs_hz: 192000(\.0)? vs 96000"):
        SkinRuntime(art, "net", rig=Rig(fs_hz=96_000, f_hi_hz=40_000))
    bad = tmp_path / "bad"
    shutil.copytree(art, bad)
    b = bytearray((bad / "net.onnx").read_bytes())
    b[len(b) // 2] ^= 0xFF
    (bad / "net.onnx").write_bytes(bytes(b))
    with pytest.raises(ArtifactError, match="does not match its checksum"):
        SkinRuntime(bad, "net")
    meta = json.loads((art / "skin.json").read_text())
    meta["features"]["bins"] = meta["features"]["bins"][:10]
    (bad / "skin.json").write_text(json.dumps(meta))
    with pytest.raises(ArtifactError, match="takes 60 features but skin.json lists 10 bins"):
        SkinRuntime(bad, "svm")
    (bad / "skin.json").write_text("{")
    with pytest.raises(ArtifactError, match="corrupt"):
        SkinRuntime(bad, "svm")
    with pytest.raises(ArtifactError, match="skin.json missing"):
        SkinRuntime(tmp_path, "svm")


def test_compare_reports_both_models(artifact):
    art, data, _ = artifact
    res = compare_artifact(art, data)
    text = format_comparison(res)
    for row in ("accuracy", "force RMSE", "false touches", "ONNX model per chirp, median", "model size"):
        assert row in text
    net, svm = res["models"]["net"], res["models"]["svm"]
    assert net["localization"]["n"] == svm["localization"]["n"] > 0
    assert net["latency"]["onnx_median_ms"] > 0 and svm["model_bytes"] > 0
