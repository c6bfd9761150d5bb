"""The learned interaction force f_a,z-hat of every robot from its neighbour set,
eq. (learningmodel-hetero), batched for the planner.

A query is one robot (type, p, v) with S neighbour slots (type, p_j, v_j, mask).
As on the drone, robot j is a neighbour of i only when p_j - p_i lies in the
interaction volume V(type_i, type_j), the environment row x_env = [-p_i; -v_i] is
always present, and every phi input is clamped to the declared input box (so the
planner sees what the firmware computes; with at most a handful of robots the
C's neighbour-count truncation never applies).  ``net`` is anything with the deep
set's call interface ``net(robot_type, sample_of, nbr_type, nbr_state) -> [B]`` in
grams (``ns2codegen.model.HeteroDeepSet`` or an analytic torch module);
``net=None`` is the baseline f_a = 0 (BL).  Everything is differentiable in the
robot's and the neighbours' states (torch autograd gives the Jacobians of Stage 2).
"""
from __future__ import annotations

import contextlib
import time

import numpy as np
import torch

from ns2codegen.config import Config


@contextlib.contextmanager
def single_thread():
    """Small batched calls: one intra-op thread is many times faster than several on
    a loaded machine (thread hand-off dominates)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


class ForceModel:
    def __init__(self, cfg: Config, net=None):
        self.cfg = cfg
        self.net = net.eval() if net is not None and hasattr(net, "eval") else net
        k = cfg.num_robot_types
        self.vol = torch.tensor([[cfg.volume(r, t) for t in range(k)] for r in range(k)],
                                dtype=torch.float32)                          # [K, K, 2, 3]
        self.nbr_box = torch.tensor(cfg.input_box(0), dtype=torch.float32)   # [6, 2]
        self.env_box = torch.tensor(cfg.input_box(cfg.env_index), dtype=torch.float32)
        self.env = cfg.env_index
        self.reset_counts()

    def reset_counts(self) -> None:
        """Force evaluations since the last reset (``plan`` reports them per plan):
        model calls, robot queries in them, seconds in the forward passes and in the
        Jacobians' backward passes."""
        self.counts = {"calls": 0, "queries": 0, "forward_s": 0.0, "jacobians": 0, "backward_s": 0.0}

    @property
    def is_zero(self) -> bool:
        return self.net is None

    def query(self, rtype, p, v, ntype, np_, nv, nmask) -> torch.Tensor:
        """f_a,z-hat [B] (g).  rtype [B] long, p, v [B, 3]; ntype [B, S] long,
        np_, nv [B, S, 3], nmask [B, S] bool (slot holds a robot)."""
        b = p.shape[0]
        if self.net is None:
            return p.new_zeros(b) + 0.0 * (p.sum(1) + v.sum(1))   # keeps the graph for autograd
        t0 = time.perf_counter()
        out = self._query(rtype, p, v, ntype, np_, nv, nmask)
        self.counts["calls"] += 1
        self.counts["queries"] += b
        self.counts["forward_s"] += time.perf_counter() - t0
        return out

    def _query(self, rtype, p, v, ntype, np_, nv, nmask) -> torch.Tensor:
        b = p.shape[0]
        rel = torch.cat([np_ - p[:, None, :], nv - v[:, None, :]], dim=2)    # x_ij [B, S, 6]
        if ntype.shape[1]:
            vol = self.vol[rtype[:, None].expand_as(ntype), ntype]          # [B, S, 2, 3]
            inside = ((rel[..., :3] >= vol[..., 0, :]) & (rel[..., :3] <= vol[..., 1, :])).all(2)
            use = nmask & inside
        else:
            use = nmask
        rows_b, rows_s = torch.nonzero(use, as_tuple=True)
        x_nbr = torch.clamp(rel[rows_b, rows_s], self.nbr_box[:, 0], self.nbr_box[:, 1])
        x_env = torch.clamp(torch.cat([-p, -v], 1), self.env_box[:, 0], self.env_box[:, 1])
        sample_of = torch.cat([rows_b, torch.arange(b)])
        nbr_type = torch.cat([ntype[rows_b, rows_s], torch.full((b,), self.env, dtype=torch.long)])
        nbr_state = torch.cat([x_nbr, x_env]).to(torch.float32)
        return self.net(rtype, sample_of, nbr_type, nbr_state)

    def team(self, types, P, V, present=None) -> torch.Tensor:
        """Every robot's force in every snapshot: types [N], P, V [M, N, 3] (torch),
        present [M, N] bool (robots not present neither feel nor exert forces).
        Returns [M, N] grams (zero where not present)."""
        m, n = P.shape[0], P.shape[1]
        types = torch.as_tensor(np.asarray(types), dtype=torch.long)
        if present is None:
            present = torch.ones((m, n), dtype=torch.bool)
        others = torch.tensor([[j for j in range(n) if j != i] for i in range(n)], dtype=torch.long).reshape(n, n - 1)
        rtype = types.repeat(m)
        p, v = P.reshape(m * n, 3), V.reshape(m * n, 3)
        np_ = P[:, others].reshape(m * n, n - 1, 3)
        nv = V[:, others].reshape(m * n, n - 1, 3)
        ntype = types[others].repeat(m, 1)
        nmask = present[:, others].reshape(m * n, n - 1)
        f = self.query(rtype, p, v, ntype, np_, nv, nmask).reshape(m, n)
        return torch.where(present, f, torch.zeros_like(f))

    def team_np(self, types, P, V, present=None) -> np.ndarray:
        """``team`` on numpy arrays, no gradients; [M, N] grams (float64)."""
        with torch.no_grad():
            pr = None if present is None else torch.as_tensor(np.asarray(present, bool))
            f = self.team(types, torch.as_tensor(np.ascontiguousarray(P), dtype=torch.float32),
                          torch.as_tensor(np.ascontiguousarray(V), dtype=torch.float32), pr)
        return f.double().numpy()

    def rel_speed_np(self, types, P, V, present=None) -> np.ndarray:
        """Every robot's relative speed to the neighbours the model sees: types [N],
        P, V [..., N, 3] (numpy), present [..., N] bool.  Returns [..., N] m/s, the
        largest ||v_j - v_i|| over the present robots j != i with p_j - p_i inside
        the interaction volume V(type_i, type_j) (0 with none): the speed the
        planning margin is conditioned on (Limits.fa_margin_g, ns2exp.margin)."""
        P, V = np.asarray(P, float), np.asarray(V, float)
        n = P.shape[-2]
        types = np.asarray(types, int)
        vol = self.vol.double().numpy()[types[:, None], types[None, :]]          # [N, N, 2, 3]
        rel = P[..., None, :, :] - P[..., :, None, :]                            # [..., i, j, 3]: p_j - p_i
        inside = ((rel >= vol[..., 0, :]) & (rel <= vol[..., 1, :])).all(-1) & ~np.eye(n, dtype=bool)
        if present is not None:
            pr = np.asarray(present, bool)
            inside &= pr[..., None, :] & pr[..., :, None]
        speed = np.linalg.norm(V[..., None, :, :] - V[..., :, None, :], axis=-1)
        return np.where(inside, speed, 0.0).max(-1)

    def jacobians(self, types, P, V, i: int):
        """Linearization around a team trajectory, for robot i (Stage 2):
        F [T, N] (g), dF_j/dp_i and dF_j/dv_i as [N, T, 3] for every robot j
        (j = i: the A_k rows of f_a,z-hat, eq. planning-xdot-approx; j != i: the
        C^(j)_k of eq. planning-Fa-approx)."""
        P = torch.as_tensor(P, dtype=torch.float32)
        V = torch.as_tensor(V, dtype=torch.float32)
        pi = P[:, i].clone().requires_grad_(True)
        vi = V[:, i].clone().requires_grad_(True)
        Pn = torch.cat([P[:, :i], pi[:, None], P[:, i + 1:]], 1)
        Vn = torch.cat([V[:, :i], vi[:, None], V[:, i + 1:]], 1)
        F = self.team(types, Pn, Vn)
        n = P.shape[1]
        dP = np.zeros((n, P.shape[0], 3))
        dV = np.zeros((n, P.shape[0], 3))
        if not self.is_zero:
            t0 = time.perf_counter()
            self.counts["jacobians"] += 1
            for j in range(n):
                gp, gv = torch.autograd.grad(F[:, j].sum(), (pi, vi), retain_graph=j + 1 < n, allow_unused=True)
                dP[j] = 0.0 if gp is None else gp.double().numpy()
                dV[j] = 0.0 if gv is None else gv.double().numpy()
            self.counts["backward_s"] += time.perf_counter() - t0
        return F.detach().double().numpy(), dP, dV


def load_force_model(cfg: Config, checkpoint=None) -> ForceModel:
    """The deep set of a checkpoint (NN) or, with ``checkpoint=None``, f_a = 0 (BL)."""
    if checkpoint is None:
        return ForceModel(cfg, None)
    from ns2codegen.checkpoint import load_checkpoint

    ck = load_checkpoint(checkpoint)
    if ck.cfg.robot_types != cfg.robot_types:
        from ns2codegen.checkpoint import CheckpointError

        raise CheckpointError(f"{checkpoint}: robot types {ck.cfg.robot_types} differ from the config's "
                              f"{cfg.robot_types}")
    return ForceModel(ck.cfg, ck.model())
