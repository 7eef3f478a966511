"""`sonicskin train` with Lightning's DDP on two CPU processes (gloo): metrics synced, one summary, the root dir honoured."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sonicskin.importers import import_wav

ROOT = Path(__file__).resolve().parents[1]
EX = ROOT / "examples" / "wav"


@pytest.mark.slow
def test_train_ddp_two_cpu_processes(tmp_path):
    pytest.importorskip("lightning")
    torch = pytest.importorskip("torch")
    if not torch.distributed.is_available() or not torch.distributed.is_gloo_available():
        pytest.skip("torch.distributed with gloo is not available")
    data = import_wav(EX / "recordings", EX / "labels.csv", tmp_path / "data", sweep_wav=EX / "sweep.wav", log=lambda *_: None)
    probe = tmp_path / "probe"
    probe.mkdir()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")]), "OMP_NUM_THREADS": "1",
           "SONICSKIN_PROBE_DIR": str(probe),
           "SONICSKIN_ALLOW_CLASSES": "ddp_probe.RankMetrics"}  # the test's own callback, opted in by name
    cmd = [sys.executable, "-m", "sonicskin", "train", "--data", str(data), "--data.n_bins", "40",
           "--trainer.max_epochs", "1", "--trainer.devices", "2", "--trainer.strategy", "ddp",
           "--trainer.default_root_dir", "my-run", "--trainer.enable_progress_bar", "false",
           "--trainer.callbacks+=ddp_probe.RankMetrics"]
    r = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    # Every rank's traceback, not just the tail (rank 0's "connection closed by peer" hides rank 1's cause).
    keep = ("Error", "error:", "rank1")
    assert r.returncode == 0, "\n".join(line for line in r.stderr.splitlines() if any(k in line for k in keep))[-6000:]
    # One summary (rank zero), naming checkpoints under --trainer.default_root_dir, not the config's logger path.
    assert r.stdout.count("checkpoints:") == 1, r.stdout
    assert "checkpoints: my-run/" in r.stdout
    assert (tmp_path / "my-run").is_dir() and not (tmp_path / "runs").exists()
    assert list((tmp_path / "my-run").rglob("metrics.csv")) and list((tmp_path / "my-run").rglob("last.ckpt"))
    # Both ranks validated on their half of the val set and saw the same, synced epoch metrics.
    ranks = {p.name: json.loads(p.read_text()) for p in probe.glob("rank*.json")}
    assert set(ranks) == {"rank0-of-2.json", "rank1-of-2.json"}
    assert ranks["rank0-of-2.json"] == ranks["rank1-of-2.json"] and "val_acc" in ranks["rank0-of-2.json"]
