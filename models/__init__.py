"""Torch networks over the OSPA-selected bins: :class:`SkinNet` (trunk, location and force heads), the SVM's kernel
machine as a layer (:class:`KernelVotes`) and the artifact's shrinkage LDA as one (:class:`LDASkinNet`)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["KernelVotes", "LDASkinNet", "SkinNet"]


# -- The SVM's kernel machine as a torch layer: RBF units at its support vectors, its one-vs-one decision values and
# (soft) votes. Initialised from a fitted ``StandardScaler + SVC(kernel="rbf", decision_function_shape="ovo")`` it
# reproduces the SVM's decision values exactly and its vote winner up to near-ties; then every part is a parameter
# trained with the rest of the network (one session is too few chirps to learn a better decision from scratch).
def _pairs(n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """libsvm's pair order: (0, 1), (0, 2), ..., (1, 2), ..."""
    return np.triu_indices(n_classes, 1)


class KernelVotes(nn.Module):
    """``z -> phi = exp(-gamma |z - c_s|^2) -> d = W phi + b (one value per pair of locations) -> scores``.

    ``scores_k = scale * (v_k + 2 c_k / (3 (|c_k| + 1)))``: libsvm's vote count ``v_k`` plus the summed confidences
    ``c_k`` that break ties (``2 * ovr - (K - 1)`` for scikit-learn's one-vs-rest scores), so the winner is the
    SVM's.  The votes pass gradients as ``tanh(d / tau)`` would (straight-through), so the layer can be trained;
    ``n_centres`` RBF units (the SVM's support vectors) on ``n_in`` standardised inputs, ``n_locations`` = K.
    """

    def __init__(self, n_in: int, n_centres: int, n_locations: int, tau: float = 0.1):
        super().__init__()
        if n_centres < 1 or n_locations < 2:
            raise ValueError(f"need n_centres >= 1 and n_locations >= 2, got {n_centres}, {n_locations}")
        i, j = _pairs(n_locations)
        P = np.zeros((i.size, n_locations), np.float32)
        P[np.arange(i.size), i] = 1.0
        P[np.arange(i.size), j] = -1.0
        self.centres = nn.Parameter(torch.zeros(n_centres, n_in))
        self.log_gamma = nn.Parameter(torch.tensor(float(np.log(1.0 / n_in))))
        self.pairwise = nn.Linear(n_centres, i.size)
        self.register_buffer("P", torch.from_numpy(P))
        self.register_buffer("tau", torch.tensor(float(tau)))
        # v_k moves by 2 per pair won, so scale 2 gives 4 x the SVM's vote count: the sharpening the SVM runtime applies
        # before its centroid's softmax, so the two models' centroids agree.
        self.scale = nn.Parameter(torch.tensor(2.0))

    @classmethod
    def from_svc(cls, svc, n_locations: int, *, tau: float = 0.1) -> KernelVotes:
        """Copy a fitted RBF ``SVC`` (classes ``0..K-1``, inputs already standardised) into the layer."""
        if getattr(svc, "kernel", None) != "rbf":
            raise ValueError(f"KernelVotes needs an RBF SVC, got kernel={getattr(svc, 'kernel', None)!r}")
        if not np.array_equal(svc.classes_, np.arange(n_locations)):
            raise ValueError(f"the SVM was trained on classes {list(svc.classes_)}; need every location 0..{n_locations - 1}")
        sv = np.asarray(svc.support_vectors_, np.float64)
        layer = cls(sv.shape[1], sv.shape[0], n_locations, tau=tau)
        # scikit-learn negates a binary SVC's public dual_coef_ and intercept_ (its d > 0 means classes_[1]); libsvm's sign
        dual, intercept = (-svc.dual_coef_, -svc.intercept_) if n_locations == 2 else (svc.dual_coef_, svc.intercept_)
        start = np.concatenate([[0], np.cumsum(svc.n_support_)])
        i_, j_ = _pairs(n_locations)
        W = np.zeros((i_.size, sv.shape[0]))
        for p, (i, j) in enumerate(zip(i_, j_)):
            # libsvm: d_ij = sum_{s in i} alpha_s^(j) k_s + sum_{s in j} alpha_s^(i) k_s + b_ij, > 0 votes for i
            W[p, start[i]:start[i + 1]] = dual[j - 1, start[i]:start[i + 1]]
            W[p, start[j]:start[j + 1]] = dual[i, start[j]:start[j + 1]]
        with torch.no_grad():
            layer.centres.copy_(torch.from_numpy(sv))
            layer.log_gamma.fill_(float(np.log(svc._gamma)))
            layer.pairwise.weight.copy_(torch.from_numpy(W))
            layer.pairwise.bias.copy_(torch.from_numpy(np.asarray(intercept, np.float64)))
        return layer

    def rbf(self, z: torch.Tensor) -> torch.Tensor:
        """RBF unit activations (n, n_centres) of standardised inputs ``z``."""
        d2 = (z * z).sum(1, keepdim=True) - 2.0 * z @ self.centres.T + (self.centres * self.centres).sum(1)[None]
        return torch.exp(-self.log_gamma.exp() * d2.clamp_min(0.0))

    def decision(self, phi: torch.Tensor) -> torch.Tensor:
        """Pairwise decision values (n, K (K-1) / 2) in libsvm's order and sign."""
        return self.pairwise(phi)

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Standardised inputs (n, n_in) -> (per-location scores (n, K), RBF activations (n, n_centres))."""
        phi = self.rbf(z)
        d = self.decision(phi)
        conf = d @ self.P
        soft = torch.tanh(d / self.tau)
        votes = soft + (torch.sign(d) - soft).detach()
        return self.scale * (votes @ self.P + 2.0 * conf / (3.0 * (conf.abs() + 1.0))), phi


# -- A small network over the OSPA-selected bins: shared trunk, location head, force head, and optionally the SVM's
# kernel machine as its location layer (:class:`KernelVotes`).
class SkinNet(nn.Module):
    """``n_in -> (N + 1 location logits, N forces)``: one class per location plus *no-touch*; the force as if the touch
    were at each location (the paper's per-location force models).  Normalisation is part of the module, so the ONNX
    graph takes raw features.  With a kernel layer (``n_centres``) call :meth:`init_from_svm` before training."""

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
        """Start the kernel layer as a fitted scaler + RBF SVC pipeline on this network's inputs (its scaler: the normalisation)."""
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
        return self._forward(x)

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


# -- The closed-form location layer: the artifact's shrinkage LDA (:mod:`sonicskin.kinds.lda`), frozen, inside the
# network: the trunk gives the touch probability and the force, the LDA where (``p(location k) = p(touch)
# softmax(scores)_k``), so its location is exactly the LDA's.
class LDASkinNet(SkinNet):
    """:class:`SkinNet` whose location layer is a fixed linear map of views of the inputs (``n_in -> (N + 1 logits,
    N forces)``): per view ``(k, norm)`` the first ``k`` inputs, normalised (``"none"``, ``"level"``: each chirp's mean
    removed, ``"unit"``: unit length), as the LDA was fitted (:class:`sonicskin.kinds.lda.LDAViews`); the views' scores
    summed.  ``n_trunk``: the trunk (touch and force) reads the first ``n_trunk`` inputs only (the best OSPA bins, as the
    SVM's input-RMS detector does).  Call :meth:`init_from_lda` before training."""

    def __init__(self, n_in: int = 300, n_locations: int = 31, hidden: tuple[int, ...] = (128, 128),
                 dropout: float = 0.1, input_dropout: float = 0.0, n_trunk: int | None = None,
                 views: tuple = ((None, "none"),)):
        super().__init__(min(n_in, n_trunk or n_in), n_locations, hidden, dropout, input_dropout, n_centres=0)
        self.n_in = n_in
        self.views = [(int(min(k or n_in, n_in)), str(norm)) for k, norm in views]
        self.n_trunk = self.mean.numel()
        self.lda = nn.ModuleList(nn.Linear(k, n_locations, bias=False).requires_grad_(False) for k, _ in self.views)
        for i, (k, _) in enumerate(self.views):
            self.register_buffer(f"centre{i}", torch.zeros(k))
        self.register_buffer("lda_bias", torch.zeros(n_locations))
        self.location = nn.Linear(hidden[-1] if hidden else self.n_trunk, 1)  # the touch logit
        self.force = nn.Linear((hidden[-1] if hidden else self.n_trunk) + n_locations, n_locations)

    def init_from_lda(self, parts, b) -> None:
        """The LDA's scores ``sum over views of (normalise(x[:k]) - c) W' + b`` (:func:`sonicskin.kinds.lda.linear_views`)."""
        if [(k, norm) for k, norm, _, _ in parts] != self.views:
            raise ValueError(f"the LDA's views {[(k, n) for k, n, _, _ in parts]} are not the layer's {self.views}")
        with torch.no_grad():
            for i, (_, _, W, c) in enumerate(parts):
                getattr(self, f"centre{i}").copy_(torch.as_tensor(c, dtype=torch.float32))
                self.lda[i].weight.copy_(torch.as_tensor(W, dtype=torch.float32))
            self.lda_bias.copy_(torch.as_tensor(b, dtype=torch.float32))

    @staticmethod
    def normalized(x: torch.Tensor, norm: str) -> torch.Tensor:
        if norm == "level":
            return x - x.mean(1, keepdim=True)
        if norm == "unit":
            return x / torch.sqrt(torch.sum(x * x, 1, keepdim=True)).clamp_min(1e-12)
        return x

    def _forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.trunk(self.standardize(x[:, :self.n_trunk]))
        t = self.location(h)
        s = self.lda_bias
        for i, (k, norm) in enumerate(self.views):
            s = s + self.lda[i](self.normalized(x[:, :k], norm) - getattr(self, f"centre{i}"))
        place = torch.log_softmax(s, 1)
        loc = self._logsig(t) + place
        return torch.cat([loc, self._logsig(-t)], 1), self.force(torch.cat([h, place.exp()], 1))
