"""A metric location layer for the network: class prototypes under a learned within-marker metric (issue 26).

:class:`MetricVotes` is a linear layer ``z -> z W' + b`` (one score per location) that starts as a fitted
:class:`sonicskin.nuisance.ShrinkageLDA`: LDA's discriminant is the nearest class mean under the Mahalanobis
metric of the pooled within-marker (and nuisance) covariance, which with equal covariances is exactly linear.
Training then moves it with the network's augmented chirps (:mod:`training.augment`).

:class:`MetricSkinNet` is :class:`models.SkinNet` with that layer in place of the SVM's kernel machine: the trunk
gives the touch probability and the force, the metric layer the place (the same factorisation as the kernel
layer: ``p(location k) = p(touch) softmax(scores)_k``), so detection, the force head, the validated detector and
force hooks (:meth:`SkinNet.set_detector`, :meth:`SkinNet.set_force`) and the ONNX export are unchanged.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .net import SkinNet

__all__ = ["MetricVotes", "MetricSkinNet", "SkinEnsemble"]


class MetricVotes(nn.Module):
    """Per-location scores ``scale * (z W' + b)`` of standardised inputs ``z``.

    Parameters
    ----------
    n_in : input width.
    n_locations : K.
    """

    def __init__(self, n_in: int, n_locations: int):
        super().__init__()
        if n_in < 1 or n_locations < 2:
            raise ValueError(f"need n_in >= 1 and n_locations >= 2, got {n_in}, {n_locations}")
        self.linear = nn.Linear(n_in, n_locations)
        self.log_scale = nn.Parameter(torch.zeros(()))

    @classmethod
    def from_lda(cls, lda, mean, std, *, target_margin: float | None = 8.0) -> MetricVotes:
        """The layer of a fitted LDA (``coef_`` (K, d), ``intercept_`` (K,), classes ``0..K-1``; binary LDAs with one
        row are expanded) trained on *raw* inputs, for standardised inputs ``z = (x - mean) / std``.

        ``target_margin``: the scores are scaled so that the median gap between the best and second-best score of the
        class means is this many logits (a softmax that is confident but not saturated, so training can move it);
        ``None`` keeps LDA's own scale.  The argmax is LDA's either way.
        """
        coef, icpt = np.asarray(lda.coef_, np.float64), np.asarray(lda.intercept_, np.float64)
        if coef.shape[0] == 1:  # scikit-learn's binary convention: row for classes_[1]; scores (-s/2, s/2)
            coef, icpt = np.vstack([-coef / 2, coef / 2]), np.r_[-icpt / 2, icpt / 2]
        K, d = coef.shape
        mean, std = np.asarray(mean, np.float64), np.asarray(std, np.float64)
        W = coef * std[None, :]
        b = icpt + coef @ mean
        layer = cls(d, K)
        scale = 1.0
        if target_margin is not None and getattr(lda, "means_", None) is not None:
            S = np.asarray(lda.means_, np.float64) @ coef.T + icpt
            top2 = np.sort(S, axis=1)[:, -2:]
            gap = float(np.median(top2[:, 1] - top2[:, 0]))
            scale = target_margin / gap if gap > 0 else 1.0
        with torch.no_grad():
            layer.linear.weight.copy_(torch.from_numpy(W))
            layer.linear.bias.copy_(torch.from_numpy(b))
            layer.log_scale.fill_(float(np.log(scale)))
        return layer

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.log_scale.exp() * self.linear(z)


class MetricSkinNet(SkinNet):
    """:class:`SkinNet` whose location layer is :class:`MetricVotes` (``n_in -> (N + 1 logits, N forces)``).

    The force head reads the trunk and the (softmaxed) location scores, as the kernel layer's reads its RBF units.
    Call :meth:`init_from_lda` before training so the place starts as the LDA's.

    ``n_trunk``: the trunk (touch and force) reads only the first ``n_trunk`` inputs (the best OSPA bins, as the
    SVM's input-RMS detector does, :data:`sonicskin.head.DETECTOR_BINS`) while the metric layer reads all of
    them; ``None``: every input.

    ``unit_norm``: the metric layer reads each chirp's relative spectrum scaled to unit length (the *shape* of the
    touch; scikit-learn's ``Normalizer`` before the LDA), the trunk the raw inputs (touch and force need the
    *strength*).  Initialise it from an LDA fitted on unit-length inputs.
    """

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, input_dropout: float = 0.0, n_trunk: int | None = None, unit_norm: bool = False):
        super().__init__(n_in, n_locations, hidden, dropout, input_dropout, n_centres=0)
        self.unit_norm = bool(unit_norm)
        self.n_trunk = n_in if n_trunk is None else int(min(max(n_trunk, 1), n_in))
        if self.n_trunk != n_in:  # the trunk again, over the first n_trunk inputs
            layers: list[nn.Module] = [nn.Dropout(input_dropout)] if input_dropout > 0 else []
            width = self.n_trunk
            for h in hidden:
                layers += [nn.Linear(width, h), nn.GELU(), nn.Dropout(dropout)]
                width = h
            self.trunk = nn.Sequential(*layers)
        width = hidden[-1] if hidden else self.n_trunk
        self.metric = MetricVotes(n_in, n_locations)
        self.location = nn.Linear(width, 1)              # the touch logit
        self.force = nn.Linear(width + n_locations, n_locations)

    def init_from_lda(self, lda, mean, std, **kw) -> None:
        """Set the normalisation to ``mean``/``std`` and the metric layer to ``lda`` (fitted on the raw inputs, or on
        unit-length inputs with ``unit_norm``)."""
        self.set_normalization(mean, std)
        if self.unit_norm:  # the layer reads unit-length chirps directly (no standardisation)
            layer = MetricVotes.from_lda(lda, np.zeros(self.n_in), np.ones(self.n_in), **kw)
        else:
            layer = MetricVotes.from_lda(lda, self.mean.numpy(), self.std.numpy(), **kw)
        self.metric.load_state_dict(layer.state_dict())

    def shape(self, x: torch.Tensor) -> torch.Tensor:
        """Each chirp scaled to unit length (its touch's shape), as scikit-learn's ``Normalizer``."""
        return x / torch.sqrt(torch.sum(x * x, 1, keepdim=True)).clamp_min(1e-12)

    def _forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.standardize(x)
        h = self.trunk(z[:, :self.n_trunk])
        scores = self.metric(self.shape(x) if self.unit_norm else z)
        t = self.location(h)
        soft = torch.log(1.0 + torch.exp(-t.abs()))
        place = torch.log_softmax(scores, 1)
        loc = (torch.clamp(t, max=0.0) - soft) + place
        return torch.cat([loc, torch.clamp(-t, max=0.0) - soft], 1), self.force(torch.cat([h, place.exp()], 1))


class SkinEnsemble(SkinNet):
    """Several trained networks as one: the mean of their class probabilities (logits = its log) and of their
    forces.  A :class:`SkinNet` itself, so the validated detector and pooled force hooks (:meth:`SkinNet.set_detector`,
    :meth:`SkinNet.set_force`) and the ONNX export apply to the whole; the members' own hooks are not used.

    One-shot training leaves a network's location layer sensitive to its random start (measured: the same rig and
    data give 90.8 % or 97.7 % with training seeds 0 and 1); averaging a few removes most of that spread.
    """

    def __init__(self, members):
        members = list(members)
        if not members:
            raise ValueError("an ensemble needs at least one trained network")
        n_in, n_loc = members[0].n_in, members[0].n_locations
        if any(m.n_in != n_in or m.n_locations != n_loc for m in members):
            raise ValueError("every member of an ensemble must read the same inputs and name the same locations")
        super().__init__(n_in, n_loc, hidden=(), dropout=0.0, n_centres=0)
        self.members = nn.ModuleList(members)

    def _forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        logp, forces = [], []
        for m in self.members:
            lg, f = m._forward(x)
            logp.append(torch.log_softmax(lg, 1))
            forces.append(f)
        lp = torch.stack(logp)  # (M, n, N + 1): the mean probability, as a log
        return torch.logsumexp(lp, 0) - float(np.log(len(self.members))), torch.stack(forces).mean(0)
