"""A callback for tests/test_ddp.py: each DDP rank writes the epoch metrics it sees (to $SONICSKIN_PROBE_DIR)."""

import json
import os
from pathlib import Path

import lightning as L


class RankMetrics(L.Callback):
    def on_validation_end(self, trainer, pl_module) -> None:
        out = Path(os.environ["SONICSKIN_PROBE_DIR"])
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("val_")}
        (out / f"rank{trainer.global_rank}-of-{trainer.world_size}.json").write_text(json.dumps(metrics))
