"""DataModule over the sonicskin dataset format."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, TensorDataset

from sonicskin.dataset import Dataset
from sonicskin.feature_cache import load_features_cached
from sonicskin.features import FeatureSpec
from sonicskin.fit import fit_models, prepare
from sonicskin.kinds import CLOSED_FORM
from sonicskin.rig import Rig

__all__ = ["SkinDataModule"]


def session_fingerprints(root: str | Path, sessions) -> dict[str, str]:
    """sha256 of each session's ``session.json``, so ``export --data`` can tell the recordings trained on from others."""
    return {str(s): hashlib.sha256((Path(root) / str(s) / "session.json").read_bytes()).hexdigest() for s in sessions}


class SkinDataModule(L.LightningDataModule):
    """Data options: the chirps of a dataset as (features, class, force) tensors (class N = no touch).

    Parameters
    ----------
    data : str
        Dataset folder (``sonicskin simulate`` / ``record`` / ``import-*``); ``sonicskin train --data`` sets it.
    n_bins : int, optional
        OSPA's gamma, the bins the SVM reads (selected on the training split).  ``None``: chosen by validation, the
        paper's 300 when nothing can validate.
    mode : str
        Model inputs: ``relative`` (minus the running no-touch reference, Alg. 2 on features) or ``absolute``.
    train_sessions : list of str, optional
        Training sessions (default: the first).
    val_sessions : list of str, optional
        Validation sessions (default: the second when there are three or more, else none).
    test_subjects : list of int, optional
        Leave-subjects-out instead: sessions of these people are the test set.
    min_force_n : float
        Labelled chirps pressed lighter than this (N) are neither a clear touch nor no touch: left out of training.
    batch_size : int
        Chirps per optimisation step.
    noise_db : float
        Std of Gaussian noise added to training features (augmentation), in dB; passed to ``model.noise_db``.
    alpha_s : float
        Alg. 2's refresh interval: the no-touch reference of relative inputs is renewed every ``alpha_s`` seconds.
    beta_s : float
        Alg. 2's reference length in seconds (shorter when some session has less rest).
    refit : bool
        ``export`` refits on the training and validation sessions (``--no-refit``: false); with a validation session
        the network's layer is then the closed form (:func:`sonicskin.training.fit.choose_network_layer`).
    """

    def __init__(self, data: str, n_bins: int | None = None, mode: str = "relative", train_sessions: list[str] | None = None,
                 val_sessions: list[str] | None = None, test_subjects: list[int] | None = None,
                 min_force_n: float = 0.5, batch_size: int = 128, noise_db: float = 0.3,
                 alpha_s: float = FeatureSpec.alpha_s, beta_s: float = FeatureSpec.beta_s, refit: bool = True):
        super().__init__()
        self.save_hyperparameters()
        meta = json.loads((Path(data) / "dataset.json").read_text()) if (Path(data) / "dataset.json").is_file() else None
        if meta is None:
            raise FileNotFoundError(f"{data} is not a sonicskin dataset (dataset.json missing); run `sonicskin simulate` first")
        self._n_locations = len(meta["layout"]["ids"])
        # The network's inputs are every usable bin in OSPA's order (its layer reads a validated prefix); the SVM reads
        # the first n_bins (OSPA's gamma, validated by prepare() when None).
        self._n_in = int(Rig.from_dict(meta["rig"]).allowed_mask.sum())
        self.prepared = None  # sonicskin.fit.TrainingData, after setup
        self.fitted: dict = {}  # the closed-form models on its training chirps (the network's closed-form layers)

    @property
    def selection(self) -> dict | None:
        """What model selection chose on the training/validation sessions (gamma, the closed forms' options)."""
        return None if self.prepared is None else self.prepared.selection

    @property
    def n_locations(self) -> int:
        return self._n_locations

    @property
    def n_in(self) -> int:
        """Model inputs: every usable bin of the rig's band, in OSPA's order (the SVM reads the first ``n_bins``)."""
        return self._n_in

    def prepare_data(self) -> None:
        # Lightning calls this once per machine before `setup` on every rank: the feature cache is built here,
        # so DDP ranks read it instead of all computing (and writing) it at once.
        load_features_cached(Dataset(self.hparams.data), progress=False)

    def setup(self, stage: str | None = None) -> None:
        if self.prepared is not None:
            return
        h = self.hparams
        p = prepare(h.data, n_bins=h.n_bins, wide=True, mode=h.mode, train_sessions=h.train_sessions, val_sessions=h.val_sessions,
                    test_subjects=h.test_subjects, min_force_n=h.min_force_n, alpha_s=h.alpha_s, beta_s=h.beta_s,
                    log=lambda m: print(f"sonicskin: {m}"))
        p.refit_follows = h.refit and bool(p.split.val)
        self.prepared = p
        _, self.fitted = fit_models(p, (CLOSED_FORM,), refit=False, log=lambda m: None)
        p.selection = {k: v for f in self.fitted.values() for k, v in f.selection.items()} | p.selection
        tr = p.rows("train")
        self.mean = p.X[tr].mean(axis=0)
        self.std = p.X[tr].std(axis=0) + 1e-3
        ds, split = p.dataset, p.split
        self.meta = {"data": str(Path(h.data).resolve()), "rig": ds.rig.to_dict(), "layout": ds.layout.to_dict(),
                     "spec": p.spec.to_dict(), "n_svm": int(p.n_svm), "split": split.to_dict(), "min_force_n": h.min_force_n,
                     "sessions_sha256": session_fingerprints(ds.root, [*split.train, *split.val, *split.test])}
        self.meta["selection"] = dict(p.selection)

    def _loader(self, part: str, shuffle: bool) -> DataLoader:
        p = self.prepared
        m = p.rows(part)
        tensors = [torch.from_numpy(np.ascontiguousarray(getattr(p, k)[m])) for k in ("X", "cls", "force")]
        if part == "train":  # each chirp's training row: the augmenter draws from the training touch chirps by row
            tensors.append(torch.arange(int(m.sum())))
        return DataLoader(TensorDataset(*tensors), batch_size=self.hparams.batch_size, shuffle=shuffle)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val" if self.prepared.split.val else "train", False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", False)
