"""The closed-form location layer: the artifact's shrinkage LDA (:mod:`sonicskin.kinds.lda`) inside the network.

:class:`LDASkinNet` is :class:`models.SkinNet` with the LDA's scores as its place: the trunk gives the touch
probability and the force, the LDA (each chirp normalised as it was, then one linear map; frozen) where the touch is
(``p(location k) = p(touch) softmax(scores)_k``, the kernel layer's factorisation).  Its location is therefore
exactly the LDA's: a network with this layer is never worse at placing a touch than the closed form it starts from.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .net import SkinNet

__all__ = ["LDASkinNet"]


class LDASkinNet(SkinNet):
    """:class:`SkinNet` whose location layer is a fixed linear map of the normalised inputs (``n_in -> (N + 1 logits,
    N forces)``).  ``norm``: ``"none"``, ``"level"`` (each chirp's mean removed) or ``"unit"`` (unit length), as the
    LDA was fitted.  ``n_trunk``: the trunk (touch and force) reads the first ``n_trunk`` inputs only (the best OSPA
    bins, as the SVM's input-RMS detector does); ``n_lda``: the LDA reads the first ``n_lda`` (default: all ``n_in``,
    which may be more when the head's force model reads more bins).  Call :meth:`init_from_lda` before training."""

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, input_dropout: float = 0.0, n_trunk: int | None = None, norm: str = "none",
                 n_lda: int | None = None):
        super().__init__(min(n_in, n_trunk or n_in), n_locations, hidden, dropout, input_dropout, n_centres=0)
        self.n_in, self.norm, self.n_lda = n_in, norm, int(min(n_lda or n_in, n_in))
        self.n_trunk = self.mean.numel()
        self.lda = nn.Linear(self.n_lda, n_locations).requires_grad_(False)
        self.register_buffer("centre", torch.zeros(self.n_lda))
        self.location = nn.Linear(hidden[-1] if hidden else self.n_trunk, 1)  # the touch logit
        self.force = nn.Linear((hidden[-1] if hidden else self.n_trunk) + n_locations, n_locations)

    def init_from_lda(self, W: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
        """The LDA's scores ``(normalise(x) - c) W' + b`` (:func:`sonicskin.kinds.lda.linear_scores`)."""
        with torch.no_grad():
            self.centre.copy_(torch.as_tensor(c, dtype=torch.float32))
            self.lda.weight.copy_(torch.as_tensor(W, dtype=torch.float32))
            self.lda.bias.copy_(torch.as_tensor(b, dtype=torch.float32))

    def normalized(self, x: torch.Tensor) -> torch.Tensor:
        if self.norm == "level":
            return x - x.mean(1, keepdim=True)
        if self.norm == "unit":
            return x / torch.sqrt(torch.sum(x * x, 1, keepdim=True)).clamp_min(1e-12)
        return x

    def _forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.trunk(self.standardize(x[:, :self.n_trunk]))
        t = self.location(h)
        place = torch.log_softmax(self.lda(self.normalized(x[:, :self.n_lda]) - self.centre), 1)
        loc = self._logsig(t) + place
        return torch.cat([loc, self._logsig(-t)], 1), self.force(torch.cat([h, place.exp()], 1))
