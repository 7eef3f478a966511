"""Train SkinNet on arrays in-process (no CLI, no checkpoints): used by ``sonicskin reproduce`` and comparisons.

The same module, loss and optimizer as ``sonicskin train`` (:class:`training.module.SkinLitModule`), in a
plain torch loop: a Lightning ``Trainer`` costs more than the training itself on one session's
chirps (measured 20 s vs 3 s for 40 epochs of ~1,100 chirps).
"""

from __future__ import annotations

import numpy as np
import torch

from .module import SkinLitModule

__all__ = ["DEFAULTS", "fit_net"]

#: training.quick's hyperparameters (configs/train/*.yaml set the same for ``sonicskin train``).
DEFAULTS = {"hidden": (128, 128), "dropout": 0.3, "weight_decay": 1e-2, "noise_db": 0.3, "kernel": True, "kernel_lr": 0.0}


def fit_net(X: np.ndarray, cls: np.ndarray, force: np.ndarray, *, n_locations: int, epochs: int = 40, seed: int = 0,
            batch_size: int = 128, **hparams):
    """Fit on (X, cls, force) and return ``predict(X) -> (logits, force_all)`` as numpy.

    ``hparams`` override :data:`DEFAULTS` and :class:`~training.module.SkinLitModule`'s arguments.  With
    ``kernel=True`` the SVM baseline is fitted on the touch chirps of (X, cls) first and starts the
    network's location layer.  ``predict.model`` is the trained :class:`models.SkinNet`.
    """
    from sonicskin import threads

    threads.apply_torch()  # sonicskin --threads / SONICSKIN_THREADS, not torch's every-core default
    torch.manual_seed(seed)
    np.random.seed(seed)
    m = SkinLitModule(n_in=X.shape[1], n_locations=n_locations, **{**DEFAULTS, **hparams})
    X = np.ascontiguousarray(X, np.float32)
    m.model.set_normalization(X.mean(0), X.std(0) + 1e-3)
    if m.hparams.kernel:
        m.init_kernel(X, cls)
    Xt, yt, ft = torch.from_numpy(X), torch.from_numpy(cls.astype(np.int64)), torch.from_numpy(force.astype(np.float32))
    opt, sched = m.make_optimizer(epochs)
    m.train()
    for _ in range(epochs):
        perm = torch.randperm(len(Xt))
        for i in range(0, len(Xt), batch_size):
            b = perm[i:i + batch_size]
            loss = m.loss_terms(Xt[b], yt[b], ft[b], train=True)["loss"]
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    model = m.model.eval()

    def predict(Xq: np.ndarray):
        with torch.no_grad():
            lg, f = model(torch.from_numpy(np.ascontiguousarray(Xq, np.float32)))
        return lg.numpy(), f.numpy()

    predict.model = model
    return predict
