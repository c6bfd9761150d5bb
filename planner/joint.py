"""Stage 1 fallback: one RRT in the composite state of the whole team.

Sequential planning (aorrt.py) plans one robot against the others' fixed paths; a
conflict in which every robot has to give way at the right time (the 2-D SLL
exchange: the large robot that crosses both others must pass under them while
they climb out of its way, one after the other) has no solution for any single
robot, and relax-and-repair does not always untangle it.  Here all robots are
planned at once: a node is the state of every robot at one time step, x = [p_i;
v_i; f_a,z-hat_i] for i = 1..N, plus the step k and the team cost c = sum_i sum_k
||u_i,k|| dt.  An extension samples a composite state (every ``search.goal_bias_every``-th
sample: every robot at its goal), takes the nearest node (scipy cKDTree) and applies
one action per robot (uniform in the action box, or for half of the extensions a PD
step toward the sampled positions plus noise: steering deepens the tree, which a
purely random action hardly does in the composite space), propagated with the joint learned forces, eq. (planning-discreteDynamics).
Valid: state box and speed of every robot, every robot's |f_a,z-hat| <= f_a,max at
the new knot and inside the step, the tight sphere collision of every pair over the
step.  Forces are joint, so no trust region is needed (it only guards the others'
plans in sequential planning).  The nearest-neighbour metric has no cost term (the
team cost of a deep node is large; with it, the nearest node is nearly always a
shallow one and the tree never gets far).  A search ends on counts (samples, nodes);
the deadline is a safety net only.  The first solution is returned; the AO
iterations of aorrt.py then lower every robot's cost with the others fixed.
"""
from __future__ import annotations

import time

import numpy as np

from .dynamics import Trajectory, accel, segment_distance, step, substates
from .nearest import Nearest

KP, KD = 4.0, 3.0      # 1/s^2, 1/s: PD step toward the sampled positions (well damped at dt = 0.1 s)
STEER = 0.5            # share of extensions that steer (PD + noise) instead of a uniform action
NOISE = 0.3            # the steering noise, as a share of a uniform action


def joint_rrt(s, deadline: float, max_samples: int, max_nodes: int):
    """Composite-state RRT for the whole team of the sequential planner ``s``
    (an ``aorrt.AORRT``: problem, force model, parameters, random stream).  Returns
    (list of Trajectory, one per robot, all of the same length; or None) and the
    number of samples drawn."""
    sp, pb = s.par.search, s.pb
    n = pb.n
    tree = _CompositeTree(max_nodes + sp.batch, n, pb.starts(),
                          s.fm.team_np(s.types, pb.starts()[None], np.zeros((1, n, 3)))[0])
    keys = np.zeros((len(tree.K), n * (2 * len(s.ax) + 1)))
    keys[:1] = _key(s, tree.P[:1], tree.V[:1], tree.FA[:1])
    nearest, drawn = Nearest(keys), 0
    while tree.n < max_nodes and drawn < max_samples:
        if time.perf_counter() >= deadline:
            s.hit_time_limit = True
            break
        pr, q = _sample(s, drawn)
        drawn += sp.batch
        near = nearest.query(q, tree.n)
        u, p1, v1 = _actions(s, pr, tree.P[near], tree.V[near], tree.FA[near])
        idx, F = _valid(s, tree, near, u, p1, v1)
        if len(idx) == 0:
            continue
        new = tree.add(p1[idx], v1[idx], F[:, 0], tree.K[near[idx]] + 1,
                       tree.C[near[idx]] + np.linalg.norm(u[idx], axis=2).sum(1) * sp.dt, near[idx], u[idx])
        keys[new] = _key(s, tree.P[new], tree.V[new], tree.FA[new])
        leaf = _at_rest_at_goals(s, tree, new)
        if leaf is not None:
            return _paths(tree.P, tree.V, tree.FA, tree.U, tree.parent, leaf, sp.dt), drawn
    return None, drawn


class _CompositeTree:
    """Nodes of the composite-state tree: every robot's p, v, f_a,z-hat at step K,
    the team cost C, the parent and the actions that led there."""

    def __init__(self, size: int, n: int, start: np.ndarray, fa0: np.ndarray):
        self.P, self.V, self.FA = np.zeros((size, n, 3)), np.zeros((size, n, 3)), np.zeros((size, n))
        self.K, self.C, self.parent = np.zeros(size, int), np.zeros(size), np.full(size, -1)
        self.U = np.zeros((size, n, 3))
        self.P[0], self.FA[0], self.n = start, fa0, 1

    def add(self, p, v, fa, k, c, parent, u) -> np.ndarray:
        new = np.arange(self.n, self.n + len(p))
        self.P[new], self.V[new], self.FA[new], self.K[new], self.C[new] = p, v, fa, k, c
        self.parent[new], self.U[new] = parent, u
        self.n += len(p)
        return new


def _key(s, p, v, fa) -> np.ndarray:
    """Nearest-neighbour key of composite states: every robot's p, w_v v, w_fa f_a (no cost term)."""
    sp, ax = s.par.search, s.ax
    per_robot = np.concatenate([p[..., ax], sp.w_v * v[..., ax], sp.w_fa * fa[..., None]], -1)
    return per_robot.reshape(len(p), -1)


def _sample(s, drawn: int):
    """UniformSample of one batch of composite states (positions, keys), with goal
    biasing: every ``goal_bias_every``-th sample is every robot at its goal at rest."""
    sp, lim, ax, rng = s.par.search, s.pb.limits, s.ax, s.rng
    b, n, na = sp.batch, s.pb.n, len(ax)
    pr, vr = np.zeros((b, n, 3)), np.zeros((b, n, 3))
    pr[..., ax] = rng.uniform(s.lo[ax], s.hi[ax], (b, n, na))
    vr[..., ax] = rng.uniform(-lim.v_max, lim.v_max, (b, n, na))
    far = rng.uniform(-s.fa_max, s.fa_max, (b, n))
    gb = (drawn + np.arange(b)) % sp.goal_bias_every == 0
    pr[gb], vr[gb], far[gb] = s.pb.goals(), 0.0, 0.0
    return pr, _key(s, pr, vr, far)


def _actions(s, pr, p0, v0, f0):
    """One action per robot: uniform in the action box, or (a share STEER of the
    extensions) a PD step toward the sampled positions plus noise; propagated for dt."""
    lim, ax, rng = s.pb.limits, s.ax, s.rng
    b, n = p0.shape[:2]
    u = np.zeros((b, n, 3))
    u[..., ax] = rng.uniform(-lim.u_max, lim.u_max, (b, n, len(ax)))
    pd = KP * (pr - p0) - KD * v0 - accel(np.zeros_like(v0), f0, s.kappa)
    steer = rng.uniform(size=b) < STEER
    u[steer] = np.clip(pd[steer] + NOISE * u[steer], -lim.u_max, lim.u_max) * np.isin(np.arange(3), ax)
    p1, v1 = step(p0, v0, u, f0, s.kappa, s.par.search.dt)
    return u, p1, v1


def _valid(s, tree: _CompositeTree, near, u, p1, v1):
    """The valid extensions (indices) and their joint forces [c, m, n] at the new knot
    and inside the step: horizon, box, speed, pairwise collision over the step, every
    robot's |f_a,z-hat| within its bound at its relative speed (Problem.fa_plan)."""
    sp, lim, ax, n = s.par.search, s.pb.limits, s.ax, s.pb.n
    p0, v0, f0 = tree.P[near], tree.V[near], tree.FA[near]
    ok = (tree.K[near] + 1 <= sp.max_steps) & np.all((p1[..., ax] >= s.lo[ax]) & (p1[..., ax] <= s.hi[ax]), (1, 2))
    ok &= np.all(np.abs(v1) <= lim.v_max + 1e-12, (1, 2))
    for i in range(n):
        for j in range(i + 1, n):
            ok &= segment_distance(p0[:, i], p1[:, i], p0[:, j], p1[:, j]) >= s.r[i, j]
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return idx, None
    m = lim.fa_substeps
    ps, vs = substates(p0[idx], v0[idx], accel(u[idx], f0[idx], s.kappa), sp.dt, m)    # [c, n, m-1, 3]
    Ps = np.concatenate([p1[idx][:, None], ps.transpose(0, 2, 1, 3)], 1)              # [c, m, n, 3]
    Vs = np.concatenate([v1[idx][:, None], vs.transpose(0, 2, 1, 3)], 1)
    Ps, Vs = Ps.reshape(-1, n, 3), Vs.reshape(-1, n, 3)
    F = s.fm.team_np(s.types, Ps, Vs).reshape(len(idx), m, n)
    bound = s.pb.fa_bound(s.fm, Ps, Vs).reshape(len(idx), m, n)
    good = np.all(np.abs(F) <= bound, (1, 2))
    return idx[good], F[good]


def _at_rest_at_goals(s, tree: _CompositeTree, new: np.ndarray) -> int | None:
    """The cheapest new node with every robot in its goal region whose rest there
    keeps every force within its limit (the team then rests at the goals), or None."""
    sp, n, goal = s.par.search, s.pb.n, s.pb.goals()
    at_goal = np.all((np.linalg.norm(tree.P[new] - goal, axis=2) <= sp.eps_p)
                     & (np.linalg.norm(tree.V[new], axis=2) <= sp.eps_v), 1)
    for leaf in new[at_goal][np.argsort(tree.C[new][at_goal])]:
        rest = s.fm.team_np(s.types, tree.P[leaf][None], np.zeros((1, n, 3)))[0]
        if np.all(np.abs(rest) <= s.fa_max):
            return int(leaf)
    return None


def _paths(P, V, FA, U, parent, leaf: int, dt: float) -> list:
    idx = [leaf]
    while parent[idx[-1]] >= 0:
        idx.append(parent[idx[-1]])
    idx = np.array(idx[::-1])
    return [Trajectory(P[idx, i].copy(), V[idx, i].copy(), FA[idx, i].copy(), U[idx[1:], i].copy(), dt)
            for i in range(P.shape[1])]
