"""Train SkinNet on arrays in-process (no CLI, no checkpoints): used by ``sonicskin reproduce``."""

from __future__ import annotations

import logging
import warnings

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from .module import SkinLitModule

__all__ = ["fit_net"]


def fit_net(X: np.ndarray, cls: np.ndarray, force: np.ndarray, *, n_locations: int, epochs: int = 40, seed: int = 0,
            batch_size: int = 128, **hparams):
    """Fit on (X, cls, force) and return ``predict(X) -> (logits, force_all)`` as numpy."""
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", module="lightning")
    L.seed_everything(seed, verbose=False)
    defaults = {"hidden": (128, 128), "dropout": 0.3, "weight_decay": 1e-2, "noise_db": 1.0}
    m = SkinLitModule(n_in=X.shape[1], n_locations=n_locations, **{**defaults, **hparams})
    m.model.set_normalization(X.mean(0), X.std(0) + 1e-3)
    data = TensorDataset(torch.from_numpy(np.ascontiguousarray(X, np.float32)), torch.from_numpy(cls.astype(np.int64)),
                         torch.from_numpy(force.astype(np.float32)))
    trainer = L.Trainer(max_epochs=epochs, enable_progress_bar=False, logger=False, enable_checkpointing=False,
                        enable_model_summary=False, accelerator="cpu", devices=1, deterministic=True)
    trainer.fit(m, DataLoader(data, batch_size=batch_size, shuffle=True))
    model = m.model.eval()

    def predict(Xq: np.ndarray):
        with torch.no_grad():
            lg, f = model(torch.from_numpy(np.ascontiguousarray(Xq, np.float32)))
        return lg.numpy(), f.numpy()

    return predict
