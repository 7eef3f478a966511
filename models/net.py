"""A small network over the OSPA-selected bins: shared trunk, location head, force head, and
optionally the SVM's kernel machine as its location layer (:class:`models.kernel.KernelVotes`)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .kernel import KernelVotes

__all__ = ["SkinNet"]


class SkinNet(nn.Module):
    """``n_in -> (N + 1 location logits, N forces)``.

    The location head has one class per touch location plus a last *no-touch* class; the force head predicts the
    force (N) as if the touch were at each location (the caller reads the entry of the location), mirroring the
    paper's per-location force models.  Feature normalisation is part of the module, so the ONNX graph takes raw
    features.  Without a kernel layer (``n_centres=0``) it is an MLP; with one, the trunk gives the touch
    probability, the kernel layer's sharpened SVM votes (:class:`~models.kernel.KernelVotes`, softness ``tau``) say
    where, and the force head reads the trunk and the RBF activations (call :meth:`init_from_svm` before training).
    ``hidden``: the trunk's widths; ``dropout`` after each trunk layer and ``input_dropout`` on the inputs
    (training only: no single bin can be relied on).
    """

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, input_dropout: float = 0.0, n_centres: int = 0, tau: float = 0.1):
        super().__init__()
        if n_in < 1 or n_locations < 2 or n_centres < 0:
            raise ValueError(f"need n_in >= 1, n_locations >= 2 and n_centres >= 0, got {n_in}, {n_locations}, {n_centres}")
        layers: list[nn.Module] = [nn.Dropout(input_dropout)] if input_dropout > 0 else []
        width = n_in
        for h in hidden:
            layers += [nn.Linear(width, h), nn.GELU(), nn.Dropout(dropout)]
            width = h
        self.trunk = nn.Sequential(*layers)
        self.kernel = KernelVotes(n_in, n_centres, n_locations, tau) if n_centres else None
        self.location = nn.Linear(width, 1 if n_centres else n_locations + 1)
        self.force = nn.Linear(width + n_centres, n_locations)
        self.register_buffer("mean", torch.zeros(n_in))
        self.register_buffer("std", torch.ones(n_in))
        self.n_in, self.n_locations = n_in, n_locations
        # A validated pooled force model replacing the head (:meth:`set_force`); None: the trained head.
        self.force_linear: dict | None = None

    def set_force(self, pooled: dict | None) -> None:
        """Replace the force head by a pooled linear model ``F_k = x . coef + loc[k]`` (the SVM's validated
        :class:`sonicskin.force.PooledForce`, folded: ``loc[k] = loc_coef[k] + intercept``); ``None``: the head."""
        if pooled is not None and (len(pooled["coef"]) != self.n_in or len(pooled["loc"]) != self.n_locations):
            raise ValueError(f"pooled force needs {self.n_in} coefficients and {self.n_locations} location terms")
        self.force_linear = None if pooled is None else {"coef": [float(v) for v in pooled["coef"]],
                                                         "loc": [float(v) for v in pooled["loc"]]}

    @staticmethod
    def _logsig(x: torch.Tensor) -> torch.Tensor:
        # log sigmoid, written out: the exported Log(Sigmoid) loses the tails in onnxruntime (-inf below x ~ -17)
        return torch.clamp(x, max=0.0) - torch.log(1.0 + torch.exp(-x.abs()))

    def set_normalization(self, mean, std) -> None:
        """The training inputs' mean and std (of the first inputs the trunk reads)."""
        k = self.mean.numel()
        self.mean.copy_(torch.as_tensor(np.asarray(mean)[:k], dtype=torch.float32))
        self.std.copy_(torch.as_tensor(np.asarray(std)[:k], dtype=torch.float32).clamp_min(1e-6))

    def init_from_svm(self, pipe) -> None:
        """Start the kernel layer as a fitted scaler + RBF SVC pipeline (the SVM kind's, :mod:`sonicskin.kinds.svm`)
        trained on this network's inputs; the network's normalisation becomes the pipeline's scaler."""
        scaler, svc = pipe[0], pipe[-1]
        if self.kernel is None or svc.support_vectors_.shape != tuple(self.kernel.centres.shape):
            raise ValueError(f"the network has {0 if self.kernel is None else self.kernel.centres.shape[0]} RBF units, the "
                             f"SVM {svc.support_vectors_.shape[0]} support vectors; build SkinNet(n_centres=...) to match")
        self.set_normalization(scaler.mean_, scaler.scale_)
        self.kernel.load_state_dict(KernelVotes.from_svc(svc, self.n_locations, tau=float(self.kernel.tau)).state_dict())

    def standardize(self, x: torch.Tensor) -> torch.Tensor:
        """Raw features -> the standardised inputs the trunk and the kernel layer read."""
        return (x - self.mean) / self.std

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (n, n_in) features -> (logits (n, N + 1), force (n, N) in newtons)."""
        logits, force = self._forward(x)
        if self.force_linear is not None:
            w = torch.as_tensor(self.force_linear["coef"], dtype=x.dtype)
            force = (x @ w)[:, None] + torch.as_tensor(self.force_linear["loc"], dtype=x.dtype)[None, :]
        return logits, force

    def _forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.standardize(x)
        h = self.trunk(z)
        if self.kernel is None:
            return self.location(h), self.force(h)
        votes, phi = self.kernel(z)
        # Touch and place factorised: p(location k) = p(touch) softmax(votes)_k, p(no touch) = 1 - p(touch).  The
        # logits are these log-probabilities, so cross-entropy and the runtime's softmax read them as before, but the
        # trunk's touch logit no longer has to track the size of the vote scores (which vary with the input).
        t = self.location(h)
        loc = self._logsig(t) + torch.log_softmax(votes, 1)
        return torch.cat([loc, self._logsig(-t)], 1), self.force(torch.cat([h, phi], 1))
