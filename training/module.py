"""One LightningModule: SkinNet trained jointly for location and force."""

from __future__ import annotations

import json

import lightning as L
import torch
import torch.nn.functional as F

from models import SkinNet

__all__ = ["SkinLitModule"]


def _plain(o):
    """numpy scalars and arrays in the metadata -> Python numbers and lists."""
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"checkpoint metadata holds a {type(o).__name__}, which is not plain data")


class SkinLitModule(L.LightningModule):
    """Joint loss ``CE(location + no-touch) + force_weight * MSE(force at the true location)``
    (the force term over touched chirps only).

    Parameters
    ----------
    n_in, n_locations : linked from the DataModule by the CLI.
    hidden, dropout : network size.
    lr, weight_decay : AdamW.
    force_weight : weight of the force loss (N^2) against the cross-entropy.
    noise_db : Gaussian noise on training inputs (dB), a cheap augmentation against sensor noise.
    input_dropout : dropout on the input bins.  label_smoothing : for the cross-entropy.
    """

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, lr: float = 2e-3, weight_decay: float = 1e-4, force_weight: float = 0.1,
                 noise_db: float = 0.3, input_dropout: float = 0.0, label_smoothing: float = 0.0):
        super().__init__()
        self.save_hyperparameters()
        self.model = SkinNet(n_in, n_locations, tuple(hidden), dropout, input_dropout)
        self.meta: dict | None = None

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None)
        if dm is not None and getattr(dm, "prepared", None) is not None:
            self.model.set_normalization(dm.mean, dm.std)
            self.meta = dm.meta

    def on_train_start(self) -> None:
        import time
        self._t0 = time.perf_counter()

    def on_train_epoch_end(self) -> None:
        import time
        if self.meta is not None and hasattr(self, "_t0"):
            self.meta["train_time_s"] = time.perf_counter() - self._t0

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # What export needs (rig, layout, bins, mode, split) as plain JSON data: loadable with weights_only=True.
        checkpoint["sonicskin"] = None if self.meta is None else json.loads(json.dumps(self.meta, default=_plain))

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.meta = checkpoint.get("sonicskin")

    def forward(self, x):
        return self.model(x)

    def _step(self, batch, stage: str):
        x, cls, force = batch
        if stage == "train" and self.hparams.noise_db > 0:
            x = x + self.hparams.noise_db * torch.randn_like(x)
        logits, f_all = self.model(x)
        ce = F.cross_entropy(logits, cls, label_smoothing=self.hparams.label_smoothing if stage == "train" else 0.0)
        touched = cls < self.hparams.n_locations
        has_f = touched & torch.isfinite(force)  # no force sensor: NaN, no force loss
        if has_f.any():
            f_hat = f_all[has_f].gather(1, cls[has_f, None])[:, 0]
            f_loss = F.mse_loss(f_hat, force[has_f])
        else:
            f_loss = torch.zeros((), device=x.device)
        loss = ce + self.hparams.force_weight * f_loss
        pred = logits[:, : self.hparams.n_locations].argmax(1)
        acc = (pred[touched] == cls[touched]).float().mean() if touched.any() else torch.zeros(())
        det = ((logits.argmax(1) == self.hparams.n_locations) == ~touched).float().mean()
        self.log_dict({f"{stage}_loss": loss, f"{stage}_acc": acc, f"{stage}_force_rmse": f_loss.sqrt(),
                       f"{stage}_detect": det}, prog_bar=stage != "train", on_epoch=True, on_step=False,
                      batch_size=x.shape[0], sync_dist=True)  # DDP: every rank logs (and checkpoints by) the same mean
        return loss

    def training_step(self, batch, _):
        return self._step(batch, "train")

    def validation_step(self, batch, _):
        self._step(batch, "val")

    def test_step(self, batch, _):
        self._step(batch, "test")

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, self.trainer.max_epochs or 1))
        return {"optimizer": opt, "lr_scheduler": sched}
