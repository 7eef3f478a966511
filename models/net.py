"""A small network over the OSPA-selected bins: shared trunk, location head, force head."""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["SkinNet"]


class SkinNet(nn.Module):
    """MLP ``n_in -> hidden... -> (N + 1 location logits, N forces)``.

    The location head has one class per touch location plus a last *no-touch* class; the force
    head predicts the force (N) as if the touch were at each location, and the caller reads the
    entry of the (predicted or true) location, which mirrors the paper's per-location force
    models.  Feature normalisation (mean/std from the training split) is part of the module, so
    the exported ONNX graph takes raw features.

    Parameters
    ----------
    n_in : number of input features (OSPA's gamma).
    n_locations : N.
    hidden : widths of the trunk's layers.
    dropout : dropout after each trunk layer (training only).
    input_dropout : dropout on the input bins (training only): no single bin can be relied on,
        as when motion noise corrupts a few of them.
    """

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, input_dropout: float = 0.0):
        super().__init__()
        if n_in < 1 or n_locations < 2:
            raise ValueError(f"need n_in >= 1 and n_locations >= 2, got {n_in}, {n_locations}")
        layers: list[nn.Module] = [nn.Dropout(input_dropout)] if input_dropout > 0 else []
        width = n_in
        for h in hidden:
            layers += [nn.Linear(width, h), nn.GELU(), nn.Dropout(dropout)]
            width = h
        self.trunk = nn.Sequential(*layers)
        self.location = nn.Linear(width, n_locations + 1)
        self.force = nn.Linear(width, n_locations)
        self.register_buffer("mean", torch.zeros(n_in))
        self.register_buffer("std", torch.ones(n_in))
        self.n_in, self.n_locations = n_in, n_locations

    def set_normalization(self, mean, std) -> None:
        self.mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.std.copy_(torch.as_tensor(std, dtype=torch.float32).clamp_min(1e-6))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x: (n, n_in) features -> (logits (n, N + 1), force (n, N) in newtons)."""
        z = self.trunk((x - self.mean) / self.std)
        return self.location(z), self.force(z)
