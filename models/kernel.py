"""The SVM's kernel machine as a torch layer: RBF units at its support vectors, its one-vs-one decision values and
(soft) votes.  Initialised from a fitted ``StandardScaler + SVC(kernel="rbf", decision_function_shape="ovo")`` it
reproduces the SVM's decision values exactly and its vote winner up to near-ties; then every part is a parameter
trained with the rest of the network (one session is too few chirps to learn a better decision from scratch).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["KernelVotes"]


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
        # v_k moves by 2 per pair won, so scale 2 gives 4 x the SVM's vote count (+ a constant): the sharpening the
        # SVM runtime applies before the softmax that weights the continuous-position centroid (a location one
        # pairwise vote behind the winner weighs e^-4 of it), and the two models' centroids agree.
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
