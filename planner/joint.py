"""Stage 1 fallback: one RRT in the composite state of the whole team.

Sequential planning (aorrt.py) plans one robot against the others' fixed paths; a
conflict in which every robot has to give way at the right time (the 2-D SLL
exchange: the large robot that crosses both others must pass under them while
they climb out of its way, one after the other) has no solution for any single
robot, and relax-and-repair does not always untangle it.  Here all robots are
planned at once: a node is the state of every robot at one time step, x = [p_i;
v_i; f_a,z-hat_i] for i = 1..N, plus the step k and the team cost c = sum_i sum_k
||u_i,k|| dt.  An extension samples a composite state (every ``goal_bias_every``-th
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
from scipy.spatial import cKDTree

from .dynamics import Trajectory, accel, segment_distance, step, substates

KP, KD = 4.0, 3.0      # 1/s^2, 1/s: PD step toward the sampled positions (well damped at dt = 0.1 s)
STEER = 0.5            # share of extensions that steer (PD + noise) instead of a uniform action
NOISE = 0.3            # the steering noise, as a share of a uniform action


def joint_rrt(s, deadline: float, max_samples: int, max_nodes: int):
    """Composite-state RRT for the whole team of the sequential planner ``s``
    (an ``aorrt.AORRT``: problem, force model, parameters, random stream).  Returns
    (list of Trajectory, one per robot, all of the same length; or None) and the
    number of samples drawn."""
    pb, par, lim = s.pb, s.par, s.pb.limits
    n, ax, na, m = pb.n, s.ax, len(s.ax), lim.fa_substeps
    H, b, rng = par.max_steps, par.batch, s.rng
    kappa, fa_max, lo, hi = s.kappa, s.fa_max, s.lo, s.hi
    start, goal = pb.starts(), pb.goals()
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    size = max_nodes + b
    P, V, FA = np.zeros((size, n, 3)), np.zeros((size, n, 3)), np.zeros((size, n))
    K, C, parent, U = np.zeros(size, int), np.zeros(size), np.full(size, -1), np.zeros((size, n, 3))
    P[0] = start
    FA[0] = s.fm.team_np(s.types, start[None], np.zeros((1, n, 3)))[0]

    def key(p, v, fa):
        per_robot = np.concatenate([p[..., ax], par.w_v * v[..., ax], par.w_fa * fa[..., None]], -1)
        return per_robot.reshape(len(p), -1)

    keys = np.zeros((size, n * (2 * na + 1)))
    keys[:1] = key(P[:1], V[:1], FA[:1])
    nodes, kd, built, drawn = 1, None, 0, 0
    while nodes < max_nodes and drawn < max_samples:
        if time.perf_counter() >= deadline:
            s.hit_time_limit = True
            break
        # UniformSample of the composite state, with goal biasing
        pr, vr = np.zeros((b, n, 3)), np.zeros((b, n, 3))
        pr[..., ax] = rng.uniform(lo[ax], hi[ax], (b, n, na))
        vr[..., ax] = rng.uniform(-lim.v_max, lim.v_max, (b, n, na))
        far = rng.uniform(-fa_max, fa_max, (b, n))
        gb = (drawn + np.arange(b)) % par.goal_bias_every == 0
        pr[gb], vr[gb], far[gb] = goal, 0.0, 0.0
        drawn += b
        q = key(pr, vr, far)
        if kd is None or nodes - built > max(64, built // 4):
            kd, built = cKDTree(keys[:nodes]), nodes
        d_kd, near = kd.query(q)
        if nodes > built:
            d_new = np.linalg.norm(q[:, None, :] - keys[None, built:nodes], axis=2)
            j = d_new.argmin(1)
            near = np.where(d_new[np.arange(b), j] < d_kd, built + j, near)
        p0, v0, f0 = P[near], V[near], FA[near]
        # one action per robot: uniform, or (a share STEER) a PD step toward the sample plus noise
        u = np.zeros((b, n, 3))
        u[..., ax] = rng.uniform(-lim.u_max, lim.u_max, (b, n, na))
        pd = KP * (pr - p0) - KD * v0 - accel(np.zeros_like(v0), f0, kappa)
        steer = rng.uniform(size=b) < STEER
        u[steer] = np.clip(pd[steer] + NOISE * u[steer], -lim.u_max, lim.u_max) * np.isin(np.arange(3), ax)
        p1, v1 = step(p0, v0, u, f0, kappa, par.dt)
        k1 = K[near] + 1
        c1 = C[near] + np.linalg.norm(u, axis=2).sum(1) * par.dt
        ok = (k1 <= H) & np.all((p1[..., ax] >= lo[ax]) & (p1[..., ax] <= hi[ax]), (1, 2))
        ok &= np.all(np.abs(v1) <= lim.v_max + 1e-12, (1, 2))
        for i, j in pairs:
            ok &= segment_distance(p0[:, i], p1[:, i], p0[:, j], p1[:, j]) >= s.r[i, j]
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        ps, vs = substates(p0[idx], v0[idx], accel(u[idx], f0[idx], kappa), par.dt, m)    # [c, n, m-1, 3]
        Ps = np.concatenate([p1[idx][:, None], ps.transpose(0, 2, 1, 3)], 1)              # [c, m, n, 3]
        Vs = np.concatenate([v1[idx][:, None], vs.transpose(0, 2, 1, 3)], 1)
        F = s.fm.team_np(s.types, Ps.reshape(-1, n, 3), Vs.reshape(-1, n, 3)).reshape(len(idx), m, n)
        good = np.all(np.abs(F) <= fa_max, (1, 2))
        idx, F = idx[good], F[good]
        if len(idx) == 0:
            continue
        new = np.arange(nodes, nodes + len(idx))
        P[new], V[new], FA[new], K[new], C[new] = p1[idx], v1[idx], F[:, 0], k1[idx], c1[idx]
        parent[new], U[new] = near[idx], u[idx]
        keys[new] = key(P[new], V[new], FA[new])
        nodes += len(idx)
        at_goal = np.all((np.linalg.norm(P[new] - goal, axis=2) <= par.eps_p)
                         & (np.linalg.norm(V[new], axis=2) <= par.eps_v), 1)
        for leaf in new[at_goal][np.argsort(C[new][at_goal])]:
            rest = s.fm.team_np(s.types, P[leaf][None], np.zeros((1, n, 3)))[0]
            if np.all(np.abs(rest) <= fa_max):      # the team then rests at the goals
                return _paths(P, V, FA, U, parent, int(leaf), par.dt), drawn
    return None, drawn


def _paths(P, V, FA, U, parent, leaf: int, dt: float) -> list:
    idx = [leaf]
    while parent[idx[-1]] >= 0:
        idx.append(parent[idx[-1]])
    idx = np.array(idx[::-1])
    return [Trajectory(P[idx, i].copy(), V[idx, i].copy(), FA[idx, i].copy(), U[idx[1:], i].copy(), dt)
            for i in range(P.shape[1])]
