"""Stage 2: sequential convex programming (Algorithm "planning", lines
stage2_start..stage2_end; paper, section "Stage 2: Optimization-Based Motion Planning").

One convex program per robot per iteration, eq. (scp), the others fixed:

    min  sum_k ||u_k||^2 + lambda_1 ||x_T - x_f||_inf + lambda_2 delta
    s.t. p, v: eq. (planning-discreteDynamics) with a_k = u_k + kappa fa_k e_z
         fa_k = f_a-hat(x_bar_k) + A_k (x_k - x_bar_k)                 eq. (planning-xdot-approx)
         u_k in U;  x_k in X_delta (box + |fa_k| <= f_a,max less the margin, widened by delta >= 0)
         <p_bar^(ij)_k, p_k - p_bar^(j)_k> >= r^(I(i)I(j)) ||p_bar^(ij)_k||   (convexified collision,
                                                 also at the points inside the steps)
         x_0 = x_s
         |C^(j)_k (x_k - x_bar_k)| <= b_fa, |f_a^(j)(x_bar_k) + C^(j)_k (x_k - x_bar_k)| <= f_a,max^(j) + delta
         |x_k - x_bar_k| <= b_x,  |u_k - u_bar_k| <= b_u                   (trust regions)

The force bound is f_a,max less the model-error margin at the robot's relative speed
(Problem.fa_plan), taken at the previous solution's speeds in the program and at the
candidate's in the merit.  The force rows are also imposed at fa_substeps - 1 points inside every step
(the states there are affine in the variables), where a crossing's force peaks.
A_k and C^(j)_k are Jacobians of the learned force from torch autograd
(eq. planning-Fa-approx).  Solved with cvxpy and Clarabel.  A step is accepted only
when it lowers the team merit (the objective evaluated with the true nonlinear
learned forces of the whole team, plus penalties on nonlinear dynamics defects,
box and collision violations); otherwise the robot's trust region is halved and
the program solved again.  Hence the merit decreases monotonically; iterations
stop when it decreases by less than ``tol`` (relative), or at the limits.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np
from scipy import sparse

from .dynamics import Trajectory, segment_distance, step, team_substates
from .forces import ForceModel
from .problem import PlanningError, Problem, SCPParams


@dataclass
class SCPResult:
    trajs: list
    merit_history: list         # team merit: initial, then after every iteration
    iterations: int
    converged: bool
    time_s: float
    time_per_robot_s: list
    max_defect: float           # max nonlinear dynamics defect of the result (m or m/s)
    profile: dict = field(default_factory=dict)   # convex solves and where their time went (solve_cp)


def _team_arrays(trajs: list) -> tuple[np.ndarray, np.ndarray]:
    return np.stack([t.p for t in trajs], 1), np.stack([t.v for t in trajs], 1)


def merit(pb: Problem, fm: ForceModel, trajs: list, par: SCPParams) -> tuple[float, dict]:
    """Team merit with the true (nonlinear) learned forces of the whole team."""
    P, V = _team_arrays(trajs)
    types = pb.type_index()
    F = fm.team_np(types, P, V)
    kappa, r = pb.kappa(), pb.r_pair()
    bound = pb.fa_bound(fm, P, V)
    if pb.limits.fa_substeps > 1:
        Ps, Vs = team_substates(trajs, kappa, pb.limits.fa_substeps)
        F_sub, bound_sub = fm.team_np(types, Ps, Vs), pb.fa_bound(fm, Ps, Vs)
    else:
        F_sub, bound_sub = np.zeros((0, pb.n)), np.zeros((0, pb.n))
    lo, hi = pb.box()
    ax = list(pb.axes)
    goals = pb.goals()
    parts = {"effort": 0.0, "goal": 0.0, "violation": 0.0, "defect": 0.0}
    max_defect = 0.0
    for i, tr in enumerate(trajs):
        parts["effort"] += float((tr.u ** 2).sum())
        parts["goal"] += par.lambda_goal * float(np.abs(np.concatenate([tr.p[-1, ax] - goals[i, ax], tr.v[-1, ax]])).max())
        viol = max(0.0, float(np.max(tr.p[:, ax] - hi[ax])), float(np.max(lo[ax] - tr.p[:, ax])),
                   float(np.max(np.abs(tr.v) - pb.limits.v_max)), float(np.max(np.abs(F[:, i]) - bound[:, i])),
                   float(np.max(np.abs(F_sub[:, i]) - bound_sub[:, i], initial=0.0)))
        for j in range(i + 1, pb.n):
            d = segment_distance(tr.p[:-1], tr.p[1:], trajs[j].p[:-1], trajs[j].p[1:])
            viol += float(np.clip(r[i, j] - d, 0.0, None).sum())
        parts["violation"] += par.lambda_box * viol
        p1, v1 = step(tr.p[:-1], tr.v[:-1], tr.u, F[:-1, i], kappa[i], tr.dt)
        dp, dv = np.abs(tr.p[1:] - p1), np.abs(tr.v[1:] - v1)
        parts["defect"] += par.lambda_defect * float(dp.sum() + dv.sum())
        max_defect = max(max_defect, float(dp.max(initial=0.0)), float(dv.max(initial=0.0)))
    parts["max_defect"] = max_defect
    parts["forces"] = F
    return parts["effort"] + parts["goal"] + parts["violation"] + parts["defect"], parts


def solve_cp(pb: Problem, fm: ForceModel, trajs: list, i: int, par: SCPParams, rho: float,
             time_limit: float, profile: dict | None = None) -> Trajectory | None:
    """SolveCP: eq. (scp) for robot i around the current team solution.  ``profile``
    accumulates the solves and their seconds: building the program (linearization
    included), cvxpy's canonicalization and the solver's own time."""
    profile = {} if profile is None else profile
    t0 = time.perf_counter()
    prog = _Program(pb, fm, trajs, i, par, rho)
    cons = prog.own_constraints()
    for j in range(pb.n):
        if j != i:
            cons += prog.pair_constraints(j)
    ax, T = prog.ax, prog.T
    goal = cp.hstack([prog.p[T] - pb.goals()[i, ax], prog.v[T]])
    obj = cp.sum_squares(prog.u) + par.lambda_goal * cp.norm(goal, "inf") + par.lambda_box * prog.delta
    problem = cp.Problem(cp.Minimize(obj), cons)
    t1 = time.perf_counter()
    try:
        kw = {"time_limit": max(time_limit, 0.1)} if par.solver == "CLARABEL" else {}
        problem.solve(solver=par.solver, **kw)
    except cp.error.SolverError:
        return None
    finally:
        t2 = time.perf_counter()
        stats = getattr(problem, "_solver_stats", None)
        solver_s = float(stats.solve_time or 0.0) if stats is not None and stats.solve_time is not None else 0.0
        for key, val in (("solves", 1), ("build_s", t1 - t0), ("solver_s", solver_s),
                         ("canon_s", max(t2 - t1 - solver_s, 0.0))):
            profile[key] = profile.get(key, 0) + val
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or prog.p.value is None:
        return None
    out = trajs[i].copy()
    out.p[:, ax], out.v[:, ax], out.u[:, ax] = prog.p.value, prog.v.value, prog.u.value
    out.fa = np.asarray(prog.fa.value, float)
    return out


class _Program:
    """The variables of eq. (scp) for robot i (p, v, f_a,z-hat, u on the active axes,
    the box slack delta), the learned forces linearized around the team solution (at
    the knots and at the points inside the steps), and the constraints in two groups:
    robot i's own and those of each pair (i, j)."""

    def __init__(self, pb: Problem, fm: ForceModel, trajs: list, i: int, par: SCPParams, rho: float):
        tr = trajs[i]
        self.pb, self.i, self.par, self.rho = pb, i, par, rho
        self.T, self.dt = tr.T, tr.dt
        self.ax = list(pb.axes)
        self.d = len(self.ax)
        types = pb.type_index()
        self.P, V = _team_arrays(trajs)
        self.F, self.dP, self.dV = fm.jacobians(types, self.P, V, i)
        self.kappa, self.r = pb.kappa()[i], pb.r_pair()
        self.bound = pb.fa_bound(fm, self.P, V)     # [T+1, N] at the previous solution's speeds
        T, d, ax = self.T, self.d, self.ax
        self.pbar, self.vbar, self.ubar = tr.p[:, ax], tr.v[:, ax], tr.u[:, ax]
        self.p, self.v = cp.Variable((T + 1, d)), cp.Variable((T + 1, d))
        self.fa, self.u, self.delta = cp.Variable(T + 1), cp.Variable((T, d)), cp.Variable(nonneg=True)
        self.dp, self.dv = self.p - self.pbar, self.v - self.vbar
        self.subs = self._substeps(fm, trajs, types)

    def _substeps(self, fm, trajs, types) -> list:
        """The points inside every step (dynamics.substates), affine in the variables:
        (rows of the substate arrays, p - p_bar there, v - v_bar there) per point."""
        m, T, i, ax = self.pb.limits.fa_substeps, self.T, self.i, self.ax
        ez = np.zeros((1, self.d))
        ez[0, ax.index(2)] = self.kappa
        acc = self.u + cp.reshape(self.fa[:-1], (T, 1), order="F") @ ez
        subs = []
        if m > 1:
            self.Ps, Vs = team_substates(trajs, self.pb.kappa(), m)
            self.Fs, self.dPs, self.dVs = fm.jacobians(types, self.Ps, Vs, i)
            self.bounds = self.pb.fa_bound(fm, self.Ps, Vs)
            for q in range(1, m):
                sq, rows = q / m * self.dt, slice(q - 1, None, m - 1)
                pq = self.p[:-1] + sq * self.v[:-1] + 0.5 * sq * sq * acc
                vq = self.v[:-1] + sq * acc
                subs.append((rows, pq - self.Ps[rows, i][:, ax], vq - Vs[rows, i][:, ax]))
        return subs

    def rowdot(self, J, X):
        """Rows of J [R, d] dotted with the rows of the expression X [R, d]: a sparse
        matrix times vec(X) (fast to canonicalize)."""
        R, d = J.shape[0], self.d
        cols = (np.arange(d)[None, :] * R + np.arange(R)[:, None]).ravel()
        M = sparse.csr_matrix((J.ravel(), (np.repeat(np.arange(R), d), cols)), shape=(R, R * d))
        return M @ cp.vec(X, order="F")

    def lin(self, j, jp=None, jv=None, rows=slice(None), dp=None, dv=None):
        """Linearized change of robot j's force caused by robot i's (p, v) (at the knots
        unless the substep Jacobians, rows and deviations are given)."""
        jp = self.dP if jp is None else jp
        jv = self.dV if jv is None else jv
        dp = self.dp if dp is None else dp
        dv = self.dv if dv is None else dv
        return self.rowdot(jp[j][rows][:, self.ax], dp) + self.rowdot(jv[j][rows][:, self.ax], dv)

    def slack(self, shape):
        """delta spread over a shape (a broadcast scalar variable is slow to canonicalize)."""
        return np.ones(shape) * self.delta

    def own_constraints(self) -> list:
        """Start, force linearization, own force limit inside the steps, dynamics, the
        action box, the state box widened by delta, and the trust regions."""
        pb, i, T, d, ax, dt = self.pb, self.i, self.T, self.d, self.ax, self.dt
        p, v, fa, u, lim, par = self.p, self.v, self.fa, self.u, pb.limits, self.par
        lo, hi = pb.box()
        cons = [p[0] == pb.starts()[i, ax], v[0] == 0.0, fa == self.F[:, i] + self.lin(i)]
        for rows, dpq, dvq in self.subs:
            cons.append(cp.abs(self.Fs[rows, i] + self.lin(i, self.dPs, self.dVs, rows, dpq, dvq))
                        <= self.bounds[rows, i] + self.slack(T))
        zc = ax.index(2)
        for c in range(d):
            a = u[:, c] + self.kappa * fa[:-1] if c == zc else u[:, c]
            cons += [v[1:, c] == v[:-1, c] + a * dt, p[1:, c] == p[:-1, c] + v[:-1, c] * dt + 0.5 * dt * dt * a]
        return cons + [
            cp.abs(u) <= lim.u_max,
            p >= np.tile(lo[ax], (T + 1, 1)) - self.slack((T + 1, d)),
            p <= np.tile(hi[ax], (T + 1, 1)) + self.slack((T + 1, d)),
            cp.abs(v) <= lim.v_max + self.slack((T + 1, d)), cp.abs(fa) <= self.bound[:, i] + self.slack(T + 1),
            cp.abs(self.dp) <= self.rho * par.b_p, cp.abs(self.dv) <= self.rho * par.b_v,
            cp.abs(u - self.ubar) <= self.rho * par.b_u]

    def pair_constraints(self, j: int) -> list:
        """The convexified collision constraint with robot j at the knots and at the
        points inside the steps (a fast crossing cuts corners), and robot j's force
        (limit and trust region b_fa) as robot i moves."""
        i, ax, r, par, lim, T = self.i, self.ax, self.r, self.par, self.pb.limits, self.T
        cons = []
        refs = [(self.P[:, i], self.P[:, j], self.dp)]
        refs += [(self.Ps[rows, i], self.Ps[rows, j], dpq) for rows, dpq, _ in self.subs]
        for ref_i, ref_j, d_pos in refs:
            rel = ref_i - ref_j
            dist = np.linalg.norm(rel, axis=1)
            ks = np.flatnonzero(dist < r[i, j] + 2.0 * par.b_p + 0.3)
            if len(ks):     # <n, p_i - p_j> with p_i - p_j = (p_i - p_bar_i) + (p_bar_i - p_j)
                nrm = rel[ks][:, ax] / np.maximum(dist[ks], 1e-9)[:, None]
                cons.append(cp.sum(cp.multiply(nrm, d_pos[ks] + rel[ks][:, ax]), axis=1)
                            >= r[i, j] + par.collision_margin)
        if np.any(self.dP[j]) or np.any(self.dV[j]):
            cons += [cp.abs(self.lin(j)) <= lim.b_fa_g,
                     cp.abs(self.F[:, j] + self.lin(j)) <= self.bound[:, j] + self.slack(T + 1)]
        for rows, dpq, dvq in self.subs:
            if np.any(self.dPs[j][rows]) or np.any(self.dVs[j][rows]):
                cj = self.lin(j, self.dPs, self.dVs, rows, dpq, dvq)
                cons += [cp.abs(cj) <= lim.b_fa_g, cp.abs(self.Fs[rows, j] + cj) <= self.bounds[rows, j] + self.slack(T)]
        return cons


def scp(pb: Problem, fm: ForceModel, trajs: list, par: SCPParams = SCPParams()) -> SCPResult:
    """Refine uniform-length trajectories (Stage 1 after post-processing)."""
    if len({t.T for t in trajs}) != 1:
        raise PlanningError("Stage 2 needs trajectories of uniform length (post-process Stage 1 first)")
    rng = np.random.default_rng(par.seed)
    t0 = time.perf_counter()
    deadline = t0 + par.time_limit_s
    trajs = [t.copy() for t in trajs]
    J, parts = merit(pb, fm, trajs, par)
    history = [J]
    rho = np.ones(pb.n)
    per_robot = [0.0] * pb.n
    profile: dict = {}
    converged = False
    it = 0
    while it < par.max_iterations and time.perf_counter() < deadline:
        for i in rng.permutation(pb.n):          # RandomShuffle
            ts = time.perf_counter()
            for _ in range(par.max_shrinks + 1):
                if time.perf_counter() >= deadline:
                    break
                cand = solve_cp(pb, fm, trajs, int(i), par, rho[i], deadline - time.perf_counter(), profile)
                if cand is not None:
                    trial = list(trajs)
                    trial[i] = cand
                    J_new, parts_new = merit(pb, fm, trial, par)
                    if J_new < J:
                        trajs, J, parts = trial, J_new, parts_new
                        rho[i] = min(1.0, 2.0 * rho[i])
                        break
                rho[i] *= 0.5
            per_robot[i] += time.perf_counter() - ts
        it += 1
        history.append(J)
        if history[-2] - J <= par.tol * abs(history[-2]):
            converged = True
            break
    F = parts["forces"]
    for i, tr in enumerate(trajs):
        tr.fa = F[:, i].copy()
    return SCPResult(trajs, history, it, converged, time.perf_counter() - t0, per_robot, parts["max_defect"], profile)
