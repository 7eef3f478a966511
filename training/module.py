"""One LightningModule: SkinNet trained jointly for location and force."""

from __future__ import annotations

import json
import time

import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from sonicskin.models import LDASkinNet, SkinNet

from sonicskin.kinds import BASELINE, CLOSED_FORM
from sonicskin.kinds.lda import linear_views

from .augment import make_augmenter

__all__ = ["SkinLitModule", "LAYER_KINDS"]

#: the network's location layers (``model.layer``)
LAYER_KINDS = ("lda", "kernel", "mlp", "auto")


def _plain(o):
    """numpy scalars and arrays in the metadata -> Python numbers and lists."""
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"checkpoint metadata holds a {type(o).__name__}, which is not plain data")


class SkinLitModule(L.LightningModule):
    """Model options: SkinNet trained jointly for location and force.

    The loss is ``CE(location + no-touch) + force_weight * MSE(force at the true location)``
    (the force term over touched chirps only).

    Parameters
    ----------
    n_in : int
        Inputs per chirp (OSPA bins); linked from the DataModule (``data.n_bins`` clamped to the band).
    n_locations : int
        Touch locations; linked from the DataModule (the dataset's layout).
    hidden : tuple of int
        Widths of the hidden layers of the shared trunk.
    dropout : float
        Dropout after each hidden layer.
    lr : float
        AdamW learning rate (cosine schedule over the epochs).
    weight_decay : float
        AdamW weight decay.
    force_weight : float
        Weight of the force loss (MSE in N^2, touched chirps only) against the location cross-entropy.
    noise_db : float
        Std of Gaussian noise added to the training inputs (dB), an augmentation against sensor noise;
        set by ``data.noise_db`` (linked).
    input_dropout : float
        Dropout on the input bins.
    label_smoothing : float
        Label smoothing of the location cross-entropy (training only).
    kernel : bool or "auto"
        The older name of ``layer`` (``True``: kernel, ``False``: mlp); ``layer`` wins when given.
    layer : str
        The location layer: ``"lda"`` (the artifact's shrinkage LDA, frozen), ``"kernel"`` (the artifact's SVM as a
        kernel machine), ``"mlp"`` (the trunk's own logits), or ``"auto"``: chosen before training by validation.
    n_inputs : int, optional
        The network reads the first ``n_inputs`` inputs only (OSPA's best bins); ``None``: all ``n_in``.
    n_trunk : int
        LDA layer: the trunk (touch, force) reads the first ``n_trunk`` inputs, the LDA all of them.
    views : list of [k, norm]
        LDA layer: the LDA's views (its first ``k`` inputs, normalised by ``norm``: ``none``, ``level``, ``unit``); the
        network reads ``n_inputs`` >= every ``k`` (the SVM's force model, which its head may apply, reads the first gamma).
    augment : bool
        Train on augmented touch chirps too (:class:`training.augment.Augmenter`, set by the trainer).
    aug_share : float
        Augmented copies per batch, as a share of the batch's touch chirps.
    kernel_lr : float
        Learning rate of the kernel layer; 0 keeps it the SVM's (measured best one-shot).
    tau : float
        Softness of the kernel layer's one-vs-one votes.
    n_centres : int
        RBF units, set when the SVM is fitted (a checkpoint rebuilds the same shapes); leave at 0.
    rest_mix : float
        Each training touch chirp gets a random no-touch chirp's deviation from their mean times this (0 = off).
    """

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.3, lr: float = 2e-3, weight_decay: float = 1e-2, force_weight: float = 0.1,
                 noise_db: float = 0.3, input_dropout: float = 0.0, label_smoothing: float = 0.0,
                 kernel: bool | str = True, kernel_lr: float = 0.0, tau: float = 0.1, n_centres: int = 0,
                 rest_mix: float = 0.0, layer: str | None = None, n_inputs: int | None = None, n_trunk: int = 300,
                 views: list | None = None, augment: bool = False, aug_share: float = 0.5):
        super().__init__()
        self.save_hyperparameters()
        if layer is None:
            self.hparams.layer = "auto" if kernel == "auto" else "kernel" if kernel else "mlp"
        if self.hparams.layer not in LAYER_KINDS:
            raise ValueError(f"model.layer must be one of {', '.join(LAYER_KINDS)}, got {self.hparams.layer!r}")
        self.model = self._build()
        self.meta: dict | None = None
        self.augmenter = None        # training.augment.Augmenter over the training touch chirps (set by the trainer)
        self.aug_rows: np.ndarray | None = None  # training row -> the augmenter's row (-1: not a touch chirp)
        self._aug_rng = np.random.default_rng(0)

    @property
    def n_model_in(self) -> int:
        """How many of the inputs the network reads (the first ones)."""
        h = self.hparams
        return int(min(h.n_inputs or h.n_in, h.n_in))

    def _build(self):
        h = self.hparams
        n = self.n_model_in
        if h.layer == "lda":
            return LDASkinNet(n, h.n_locations, tuple(h.hidden), h.dropout, h.input_dropout, n_trunk=h.n_trunk,
                              views=tuple(tuple(v) for v in (h.views or [[None, "none"]])))
        centres = h.n_centres if h.layer == "kernel" else 0
        return SkinNet(n, h.n_locations, tuple(h.hidden), h.dropout, h.input_dropout, n_centres=centres, tau=h.tau)

    def init_closed_form(self, fitted: dict) -> None:
        """Start a closed-form location layer as the artifact's fitted SVM (kernel layer) or LDA (LDA layer)."""
        h = self.hparams
        if h.layer == "kernel":
            pipe = fitted[BASELINE].model
            h.n_centres = int(pipe[-1].support_vectors_.shape[0])
            self.model = self._build()
            self.model.init_from_svm(pipe)
        elif h.layer == "lda":
            lda, svm = fitted[CLOSED_FORM], fitted.get(BASELINE)
            h.views = [list(v) for v in lda.model.views]
            h.n_inputs = max(int(lda.n_in), int(svm.n_in) if svm is not None else 0)
            self.model = self._build()
            self.model.init_from_lda(*linear_views(lda.model))

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None)
        if dm is not None and getattr(dm, "prepared", None) is not None:
            if stage == "fit" and self.hparams.layer == "auto":  # SkinCLI.before_fit chooses it (training.fit)
                raise ValueError("model.layer 'auto' must be resolved before training (training.fit.choose_auto_layer)")
            p = dm.prepared
            tr = p.rows("train")
            if stage == "fit":
                self.init_closed_form(dm.fitted)
            n = self.n_model_in
            if self.hparams.layer != "kernel":  # the kernel layer's normalisation is the SVM's scaler
                self.model.set_normalization(p.X[tr][:, :n].mean(0), p.X[tr][:, :n].std(0) + 1e-3)
            self.meta = dm.meta
            if stage == "fit" and self.hparams.augment and self.augmenter is None:
                self.augmenter, self.aug_rows = make_augmenter(p, tr, n_cols=n)
            if self.model.kernel is not None:  # before DDP wraps the model: a frozen layer is no unused parameter
                self.model.kernel.requires_grad_(self.hparams.kernel_lr > 0)

    def on_train_start(self) -> None:
        self._t0 = time.perf_counter()
        if self.meta is not None:
            self.meta["epochs"] = int(self.trainer.max_epochs or 1)

    def on_train_epoch_end(self) -> None:
        if self.meta is not None and hasattr(self, "_t0"):
            self.meta["train_time_s"] = time.perf_counter() - self._t0

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # What export needs (rig, layout, bins, mode, split) as plain JSON data: loadable with weights_only=True.
        checkpoint["sonicskin"] = None if self.meta is None else json.loads(json.dumps(self.meta, default=_plain))

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.meta = checkpoint.get("sonicskin")

    def forward(self, x):
        return self.model(x)

    def augmented(self, x: torch.Tensor, cls: torch.Tensor, force: torch.Tensor, rows: torch.Tensor):
        """The batch with augmented copies of ``aug_share`` of its touch chirps appended."""
        a = self.aug_rows[rows.cpu().numpy()]
        touch = np.flatnonzero(a >= 0)
        k = int(round(self.hparams.aug_share * touch.size))
        if k == 0:
            return x, cls, force
        pick = self._aug_rng.choice(touch, size=k, replace=False)
        xa = self.augmenter.draw(self._aug_rng, a[pick])[:, :x.shape[1]]
        xa = torch.from_numpy(np.ascontiguousarray(xa, np.float32)).to(x.device)
        idx = torch.from_numpy(pick).to(x.device)
        return torch.cat([x, xa]), torch.cat([cls, cls[idx]]), torch.cat([force, force[idx]])

    def loss_terms(self, x: torch.Tensor, cls: torch.Tensor, force: torch.Tensor, *, train: bool,
                   rows: torch.Tensor | None = None) -> dict:
        """The joint loss and its parts on one batch (``train``: input noise, label smoothing, augmented touch chirps)."""
        x = x[:, :self.n_model_in]
        if train and self.augmenter is not None and rows is not None:
            x, cls, force = self.augmented(x, cls, force, rows)
        if train and self.hparams.rest_mix > 0:
            # Physical noise: each touch chirp gets the deviation of a random no-touch chirp of the batch from their
            # mean (motion, drift and electrical noise as this rig records them), scaled by rest_mix.
            rest = cls == self.hparams.n_locations
            if int(rest.sum()) >= 2:
                dev = x[rest] - x[rest].mean(0)
                pick = torch.randint(dev.shape[0], (x.shape[0],), device=x.device)
                x = x + self.hparams.rest_mix * dev[pick] * (~rest)[:, None]
        if train and self.hparams.noise_db > 0:
            x = x + self.hparams.noise_db * torch.randn_like(x)
        logits, f_all = self.model(x)
        ce = F.cross_entropy(logits, cls, label_smoothing=self.hparams.label_smoothing if train else 0.0)
        touched = cls < self.hparams.n_locations
        has_f = touched & torch.isfinite(force)  # no force sensor: NaN, no force loss
        if has_f.any():
            f_hat = f_all[has_f].gather(1, cls[has_f, None])[:, 0]
            f_loss = F.mse_loss(f_hat, force[has_f])
        else:
            f_loss = torch.zeros((), device=x.device)
        pred = logits[:, : self.hparams.n_locations].argmax(1)
        acc = (pred[touched] == cls[touched]).float().mean() if touched.any() else torch.zeros(())
        det = ((logits.argmax(1) == self.hparams.n_locations) == ~touched).float().mean()
        return {"loss": ce + self.hparams.force_weight * f_loss, "acc": acc, "force_rmse": f_loss.sqrt(), "detect": det}

    def _step(self, batch, stage: str):
        x, cls, force, *rows = batch  # the training loader also gives each chirp's training row (augmentation)
        terms = self.loss_terms(x, cls, force, train=stage == "train", rows=rows[0] if rows else None)
        self.log_dict({f"{stage}_{k}": v for k, v in terms.items()}, prog_bar=stage != "train", on_epoch=True, on_step=False,
                      batch_size=x.shape[0], sync_dist=True)  # DDP: every rank logs (and checkpoints by) the same mean
        return terms["loss"]

    def training_step(self, batch, _):
        return self._step(batch, "train")

    def validation_step(self, batch, _):
        self._step(batch, "val")

    def test_step(self, batch, _):
        self._step(batch, "test")

    def make_optimizer(self, epochs: int):
        """AdamW (the kernel layer at ``kernel_lr``, frozen at 0) with a cosine schedule over ``epochs``."""
        h = self.hparams
        kernel = list(self.model.kernel.parameters()) if self.model.kernel is not None else []
        for q in kernel:
            q.requires_grad_(h.kernel_lr > 0)
        ids = {id(q) for q in kernel}
        groups = [{"params": [q for q in self.parameters() if id(q) not in ids and q.requires_grad]}]
        if kernel and h.kernel_lr > 0:
            groups.append({"params": kernel, "lr": h.kernel_lr, "weight_decay": 0.0})
        opt = torch.optim.AdamW(groups, lr=h.lr, weight_decay=h.weight_decay)
        return opt, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, epochs))

    def configure_optimizers(self):
        opt, sched = self.make_optimizer(self.trainer.max_epochs or 1)
        return {"optimizer": opt, "lr_scheduler": sched}
