"""Heterogeneous deep set, eq. (learningmodel-hetero), with spectral normalization, eq. (sn).

    f_a,z(i) = rho_{I(i)}( sum_k sum_{x_ij in S_k} phi_{I(j)}(x_ij) )

One phi net per neighbour type (robot types + environment), one rho net per
robot type.  Each net is a ReLU MLP g(x) = W_L s(... s(W_1 x + b_1) ...) + b_L.
"""
from __future__ import annotations

import torch
from torch import nn

from .config import Config


class MLP(nn.Module):
    """ReLU multilayer perceptron; no activation after the last layer."""

    def __init__(self, dims: list[int]):
        super().__init__()
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i + 1 < len(self.layers):
                x = torch.relu(x)
        return x

    @torch.no_grad()
    def spectral_normalize_(self, gamma: float) -> None:
        """Eq. (sn): W_i <- W_i / ||W_i||_2 * gamma^(1/L) for every layer, with the exact
        largest singular value (SVD in float64), so that ||g||_Lip <= gamma."""
        target = gamma ** (1.0 / len(self.layers))
        for layer in self.layers:
            sigma = torch.linalg.matrix_norm(layer.weight.double(), ord=2)
            layer.weight.mul_((target / sigma).to(layer.weight.dtype))


class HeteroDeepSet(nn.Module):
    def __init__(self, cfg: Config):
        super().__init__()
        self.num_robot_types = cfg.num_robot_types
        self.num_neighbor_types = len(cfg.neighbor_types)
        self.hidden = cfg.model["hidden"]
        self.gamma = float(cfg.model["gamma"])
        self.phi = nn.ModuleList(MLP(cfg.phi_dims()) for _ in cfg.neighbor_types)
        self.rho = nn.ModuleList(MLP(cfg.rho_dims()) for _ in cfg.robot_types)

    def forward(self, robot_type: torch.Tensor, sample_of: torch.Tensor,
                nbr_type: torch.Tensor, nbr_state: torch.Tensor) -> torch.Tensor:
        """Batched over samples of any neighbour mix (CSR rows, environment included):
        ``sample_of[m]`` is the sample of neighbour row m.  Returns f_a,z [B] in grams."""
        b = robot_type.shape[0]
        h = nbr_state.new_zeros((b, self.hidden))
        for k in range(self.num_neighbor_types):
            rows = torch.nonzero(nbr_type == k).squeeze(1)
            if rows.numel():
                h = h.index_add(0, sample_of[rows], self.phi[k](nbr_state[rows]))
        out = nbr_state.new_zeros(b)
        for r in range(self.num_robot_types):
            rows = torch.nonzero(robot_type == r).squeeze(1)
            if rows.numel():
                out = out.index_put((rows,), self.rho[r](h[rows]).squeeze(1))
        return out

    @torch.no_grad()
    def spectral_normalize_(self) -> None:
        for net in list(self.phi) + list(self.rho):
            net.spectral_normalize_(self.gamma)


class PairwiseSum(HeteroDeepSet):
    """Ablation: the sum of pairwise models, f = sum_j rho_I(i)(phi_I(j)(x_ij)) (the
    superposition the paper compares its deep set with, Fig. vis (g) vs (a) + 3 (b))."""

    def forward(self, robot_type, sample_of, nbr_type, nbr_state):
        z = nbr_state.new_zeros((nbr_state.shape[0], self.hidden))
        for k in range(self.num_neighbor_types):
            rows = torch.nonzero(nbr_type == k).squeeze(1)
            if rows.numel():
                z = z.index_put((rows,), self.phi[k](nbr_state[rows]))
        per, owner = nbr_state.new_zeros(nbr_state.shape[0]), robot_type[sample_of]
        for r in range(self.num_robot_types):
            rows = torch.nonzero(owner == r).squeeze(1)
            if rows.numel():
                per = per.index_put((rows,), self.rho[r](z[rows]).squeeze(1))
        return nbr_state.new_zeros(robot_type.shape[0]).index_add(0, sample_of, per)


class TypeAgnostic(HeteroDeepSet):
    """Ablation: a deep set that ignores robot types, one phi for every robot
    neighbour and one rho for every robot (the environment keeps its own phi: it is
    not a robot).  The other types' nets stay unused."""

    def forward(self, robot_type, sample_of, nbr_type, nbr_state):
        env = self.num_neighbor_types - 1
        return super().forward(torch.zeros_like(robot_type), sample_of,
                               torch.where(nbr_type == env, nbr_type, torch.zeros_like(nbr_type)), nbr_state)


VARIANTS = {"hetero": HeteroDeepSet, "pairwise": PairwiseSum, "agnostic": TypeAgnostic}


def lipschitz_bound(weights: list, margin: float = 1e-9) -> float:
    """Proven Lipschitz bound of a ReLU MLP from its (exported) weights: the product of
    exact spectral norms, computed in float64 and rounded up by a relative ``margin``."""
    bound = 1.0
    for w in weights:
        bound *= float(torch.linalg.matrix_norm(torch.as_tensor(w).double(), ord=2))
    return bound * (1.0 + margin)
