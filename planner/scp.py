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

The program is built once per Stage 2 run for the whole team (_Stage2, the default
SCPParams.program "parametrized"): a DPP program whose variables are the deviations
from the current team solution and whose data (reference, forces, Jacobians, bounds,
collision normals, trust-region scale) are cvxpy Parameters, so cvxpy canonicalizes it
once and every solve only maps new parameter values into Clarabel's data.
SCPParams.program "rebuilt" builds a fresh program for every solve (_Program,
solve_cp), the same plans within the solver's tolerance; it is kept to compare the two
(tests/test_planning.py, benchmarks/bench_plan.py).
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


def _timed_solve(problem: cp.Problem, solver: str, time_limit: float, t0: float, profile: dict) -> bool:
    """Solve ``problem`` (Clarabel within ``time_limit``); add the solve and its seconds to
    ``profile``: build_s since ``t0``, the solver's own time and cvxpy's canonicalization
    (the rest).  True when it found a solution."""
    t1 = time.perf_counter()
    try:
        kw = {"time_limit": max(time_limit, 0.1)} if solver == "CLARABEL" else {}
        problem.solve(solver=solver, **kw)
    except cp.error.SolverError:
        return False
    finally:
        t2 = time.perf_counter()
        stats = getattr(problem, "_solver_stats", None)
        solver_s = float(stats.solve_time or 0.0) if stats is not None and stats.solve_time is not None else 0.0
        for key, val in (("solves", 1), ("build_s", t1 - t0), ("solver_s", solver_s),
                         ("canon_s", max(t2 - t1 - solver_s, 0.0))):
            profile[key] = profile.get(key, 0) + val
    return problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)


def solve_cp(pb: Problem, fm: ForceModel, trajs: list, i: int, par: SCPParams, rho: float,
             time_limit: float, profile: dict | None = None) -> Trajectory | None:
    """SolveCP: eq. (scp) for robot i around the current team solution, with a program
    built for this solve (SCPParams.program "rebuilt"; the default is _Stage2).  ``profile``
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
    profile["linearizations"] = profile.get("linearizations", 0) + 1
    if not _timed_solve(problem, par.solver, time_limit, t0, profile) or prog.p.value is None:
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


def _q_major(a: np.ndarray, T: int) -> np.ndarray:
    """Rows of a substate array (team_substates: time-major, step k's points are rows
    k (m-1) .. (k+1)(m-1) - 1) reordered point-major: rows (q-1) T .. q T - 1 are the
    q-th points inside every step."""
    return a.reshape(T, -1, *a.shape[1:]).swapaxes(0, 1).reshape(a.shape)


def _within(x, b) -> list:
    """|x| <= b as two rows of inequalities (cp.abs adds a variable and a third row)."""
    return [x <= b, x >= -b]


def _rowdot(J, X):
    """Rows of the parameter J [R, d] dotted with the rows of the expression X [R, d]."""
    return cp.sum(cp.multiply(J, X), axis=1)


class _Stage2:
    """The program of eq. (scp), built once per Stage 2 run (T fixed) for every robot of
    the team and solved again with new data: a DPP program (cvxpy's Disciplined
    Parametrized Programming), which cvxpy canonicalizes at its first solve and then
    only maps the parameter values into the solver's data.

    The variables are the deviations from the reference (the current team solution)
    of the robot being optimized: dp, dv, dfa on x_0..x_T, du on u_0..u_{T-1} (active
    axes), and the box slack delta; p = p_bar + dp etc.  Parameters: the robot's
    reference, start, goal and kappa, the learned forces, their Jacobians (A_k and,
    per neighbour slot, C^(j)_k), the force bounds, the collision normals and the
    trust-region scale rho.  So one program serves every robot of the team (its
    neighbours in slots 0..N-2).  The rows that the rebuilt program (_Program) adds or
    leaves out with the data have a fixed size here and are switched off by their
    data: a collision row away from the neighbour has the normal 0 and the right-hand
    side -1 (0 >= -1), a neighbour's force rows whose Jacobian is zero have the force 0
    and the bound 1 (|0| <= 1 + delta).  With f_a = 0 (``linear_forces`` False) the
    program has no Jacobians and no neighbour force rows (the rebuilt program has none
    either then).  A robot's linearization is recomputed only when the team solution
    changed since its last solve (not after a rejected step, where only rho changes)."""

    def __init__(self, pb: Problem, T: int, dt: float, par: SCPParams, linear_forces: bool = True):
        self.pb, self.par, self.T, self.dt, self.linear = pb, par, T, dt, linear_forces
        self.ax = list(pb.axes)
        self.d, self.slots, self.m = len(self.ax), pb.n - 1, pb.limits.fa_substeps
        self.S = T * (self.m - 1)
        self._parameters()
        d = self.d
        self.dp, self.dv = cp.Variable((T + 1, d)), cp.Variable((T + 1, d))
        self.dfa, self.du, self.delta = cp.Variable(T + 1), cp.Variable((T, d)), cp.Variable(nonneg=True)
        self.daz = cp.Variable(T)       # kappa dfa: the change of the held acceleration along z
        cons = self._own_rows()
        if self.m > 1:
            cons += self._inside_rows()
        for k in range(self.slots):
            cons += self._pair_rows(k)
        # sum ||u||^2 = sum ||du||^2 + 2 <u_bar, du> + a constant
        goal = cp.hstack([self.pbar[T] + self.dp[T] - self.goal, self.vbar[T] + self.dv[T]])
        obj = (cp.sum_squares(self.du) + 2.0 * cp.sum(cp.multiply(self.ubar, self.du))
               + par.lambda_goal * cp.norm(goal, "inf") + par.lambda_box * self.delta)
        self.problem = cp.Problem(cp.Minimize(obj), cons)
        self.data: dict = {}            # robot -> (the team solution, its parameter values)
        self.current = None             # the robot whose values the parameters hold

    def _parameters(self) -> None:
        T, d, S, slots, Par = self.T, self.d, self.S, self.slots, cp.Parameter

        def per_slot(shape):
            return [Par(shape) for _ in range(slots)]

        self.pbar, self.vbar, self.fabar, self.ubar = Par((T + 1, d)), Par((T + 1, d)), Par(T + 1), Par((T, d))
        self.kappa, self.kfabar = Par(nonneg=True), Par(T + 1)    # kappa, kappa fa_bar
        self.start, self.goal = Par(d), Par(d)
        self.rho = Par(nonneg=True)
        self.f_own, self.bound = Par(T + 1), Par(T + 1)           # F_i - fa_bar, bound_i at the knots
        self.nk, self.ck = per_slot((T + 1, d)), per_slot(T + 1)  # collision normals and right-hand sides
        if self.linear:
            self.jp, self.jv = Par((T + 1, d)), Par((T + 1, d))   # A_k: dF_i/dp_i, dF_i/dv_i
            self.cp_, self.cv = per_slot((T + 1, d)), per_slot((T + 1, d))   # C^(j)_k: dF_j/dp_i, dF_j/dv_i
            self.fj, self.bj = per_slot(T + 1), per_slot(T + 1)   # neighbour j's force and bound (masked)
        if self.m > 1:                                            # the same at the points inside the steps
            self.fs_own, self.bounds = Par(S), Par(S)
            self.ns, self.cs = per_slot((S, d)), per_slot(S)
            if self.linear:
                self.jps, self.jvs = Par((S, d)), Par((S, d))
                self.cps, self.cvs = per_slot((S, d)), per_slot((S, d))
                self.fsj, self.bsj = per_slot(S), per_slot(S)

    def _slack(self, shape):
        """delta spread over a shape (as _Program.slack)."""
        return np.ones(shape) * self.delta

    def _own_rows(self) -> list:
        """Start, force linearization, dynamics, the action box, the state box widened
        by delta, and the trust regions (_Program.own_constraints but the rows inside
        the steps)."""
        pb, par, lim, T, d, ax, dt = self.pb, self.par, self.pb.limits, self.T, self.d, self.ax, self.dt
        dp, dv, dfa, du, slack = self.dp, self.dv, self.dfa, self.du, self._slack
        p, v, fa, u = self.pbar + dp, self.vbar + dv, self.fabar + dfa, self.ubar + du
        lo, hi = pb.box()
        own = self.f_own + (_rowdot(self.jp, dp) + _rowdot(self.jv, dv) if self.linear else 0.0)
        cons = [p[0] == self.start, v[0] == 0.0, dfa == own, self.daz == self.kappa * dfa[:-1]]
        zc = ax.index(2)
        for c in range(d):
            a = u[:, c] + self.kfabar[:-1] + self.daz if c == zc else u[:, c]
            cons += [v[1:, c] == v[:-1, c] + a * dt, p[1:, c] == p[:-1, c] + v[:-1, c] * dt + 0.5 * dt * dt * a]
        return cons + [
            *_within(u, lim.u_max),
            p >= np.tile(lo[ax], (T + 1, 1)) - slack((T + 1, d)), p <= np.tile(hi[ax], (T + 1, 1)) + slack((T + 1, d)),
            *_within(v, lim.v_max + slack((T + 1, d))), *_within(fa, self.bound + slack(T + 1)),
            *_within(dp, self.rho * par.b_p), *_within(dv, self.rho * par.b_v), *_within(du, self.rho * par.b_u)]

    def _inside_rows(self) -> list:
        """The deviations at the points inside the steps (point-major, _q_major; affine
        in the variables) and the robot's own force limit there."""
        T, m, dt, dp, dv = self.T, self.m, self.dt, self.dp, self.dv
        ez = np.zeros((1, self.d))
        ez[0, self.ax.index(2)] = 1.0
        dacc = self.du + cp.reshape(self.daz, (T, 1), order="F") @ ez
        sq = [q / m * dt for q in range(1, m)]
        self.dpq = cp.vstack([dp[:-1] + s * dv[:-1] + 0.5 * s * s * dacc for s in sq])
        self.dvq = cp.vstack([dv[:-1] + s * dacc for s in sq])
        own = self.fs_own
        if self.linear:
            own = own + _rowdot(self.jps, self.dpq) + _rowdot(self.jvs, self.dvq)
        return _within(own, self.bounds + self._slack(self.S))

    def _pair_rows(self, k: int) -> list:
        """Neighbour slot k: the collision rows and, with a model, the neighbour's force
        (trust region b_fa and limit), at the knots and inside the steps
        (_Program.pair_constraints)."""
        b_fa, slack, dp, dv = self.pb.limits.b_fa_g, self._slack, self.dp, self.dv
        cons = [_rowdot(self.nk[k], dp) >= self.ck[k]]
        if self.m > 1:
            cons.append(_rowdot(self.ns[k], self.dpq) >= self.cs[k])
        if self.linear:
            lin = _rowdot(self.cp_[k], dp) + _rowdot(self.cv[k], dv)
            cons += [*_within(lin, b_fa), *_within(self.fj[k] + lin, self.bj[k] + slack(self.T + 1))]
            if self.m > 1:
                lin = _rowdot(self.cps[k], self.dpq) + _rowdot(self.cvs[k], self.dvq)
                cons += [*_within(lin, b_fa), *_within(self.fsj[k] + lin, self.bsj[k] + slack(self.S))]
        return cons

    def _collision(self, ref_i, ref_j, r) -> tuple[np.ndarray, np.ndarray]:
        """Morgan's convexified collision rows (see _Program.pair_constraints) as data:
        the normal and the right-hand side on the rows near the neighbour, 0 >= -1 on
        the others."""
        par, ax = self.par, self.ax
        rel = ref_i - ref_j
        dist = np.linalg.norm(rel, axis=1)
        near = dist < r + 2.0 * par.b_p + 0.3
        nrm = np.where(near[:, None], rel[:, ax] / np.maximum(dist, 1e-9)[:, None], 0.0)
        return nrm, np.where(near, r + par.collision_margin - (nrm * rel[:, ax]).sum(1), -1.0)

    def linearize(self, fm: ForceModel, trajs: list, i: int) -> list:
        """The parameter values (pairs of parameter and value) of robot i's program
        around the team solution ``trajs``: what _Program computes, as data."""
        pb, ax, T, m, lin = self.pb, self.ax, self.T, self.m, self.linear
        tr = trajs[i]
        types = pb.type_index()
        P, V = _team_arrays(trajs)
        F, dP, dV = fm.jacobians(types, P, V, i)
        bound = pb.fa_bound(fm, P, V)
        r, kappa = pb.r_pair(), float(pb.kappa()[i])
        vals = [(self.pbar, tr.p[:, ax]), (self.vbar, tr.v[:, ax]), (self.ubar, tr.u[:, ax]), (self.fabar, tr.fa),
                (self.kappa, kappa), (self.kfabar, kappa * tr.fa), (self.start, pb.starts()[i, ax]),
                (self.goal, pb.goals()[i, ax]), (self.f_own, F[:, i] - tr.fa), (self.bound, bound[:, i])]
        if lin:
            vals += [(self.jp, dP[i][:, ax]), (self.jv, dV[i][:, ax])]
        if m > 1:
            Ps, Vs = team_substates(trajs, pb.kappa(), m)
            Fs, dPs, dVs = fm.jacobians(types, Ps, Vs, i)
            bounds = pb.fa_bound(fm, Ps, Vs)
            Ps, Fs, bounds = _q_major(Ps, T), _q_major(Fs, T), _q_major(bounds, T)
            dPs, dVs = _q_major(dPs.swapaxes(0, 1), T), _q_major(dVs.swapaxes(0, 1), T)     # [S, N, 3]
            vals += [(self.fs_own, Fs[:, i]), (self.bounds, bounds[:, i])]
            if lin:
                vals += [(self.jps, dPs[:, i][:, ax]), (self.jvs, dVs[:, i][:, ax])]
        for k, j in enumerate(j for j in range(pb.n) if j != i):
            vals += zip((self.nk[k], self.ck[k]), self._collision(P[:, i], P[:, j], r[i, j]))
            if m > 1:
                vals += zip((self.ns[k], self.cs[k]), self._collision(Ps[:, i], Ps[:, j], r[i, j]))
            if not lin:
                continue
            on = bool(np.any(dP[j]) or np.any(dV[j]))       # the rebuilt program's rows of j's force
            vals += [(self.cp_[k], dP[j][:, ax]), (self.cv[k], dV[j][:, ax]),
                     (self.fj[k], F[:, j] if on else np.zeros(T + 1)),
                     (self.bj[k], bound[:, j] if on else np.ones(T + 1))]
            if m > 1:
                on = (np.any(dPs[:, j].reshape(m - 1, T, 3), axis=(1, 2))
                      | np.any(dVs[:, j].reshape(m - 1, T, 3), axis=(1, 2))).repeat(T)   # per point q
                vals += [(self.cps[k], dPs[:, j][:, ax]), (self.cvs[k], dVs[:, j][:, ax]),
                         (self.fsj[k], np.where(on, Fs[:, j], 0.0)), (self.bsj[k], np.where(on, bounds[:, j], 1.0))]
        return vals

    def solve(self, fm: ForceModel, trajs: list, i: int, rho: float, time_limit: float,
              profile: dict) -> Trajectory | None:
        """SolveCP for robot i with this program: the same result as solve_cp (the
        rebuilt program) within the solver's tolerance.  ``profile`` as in solve_cp,
        plus the linearizations (build_s is theirs and the parameters' setting;
        canon_s includes this program's one canonicalization, at its first solve)."""
        t0 = time.perf_counter()
        ref, vals = self.data.get(i, (None, None))
        if ref is None or any(a is not b for a, b in zip(ref, trajs)):
            vals = self.linearize(fm, trajs, i)
            self.data[i] = (list(trajs), vals)
            self.current = None
            profile["linearizations"] = profile.get("linearizations", 0) + 1
        if self.current != i:
            for prm, val in vals:
                prm.value = val
            self.current = i
        self.rho.value = rho
        if not _timed_solve(self.problem, self.par.solver, time_limit, t0, profile) or self.dp.value is None:
            return None
        out = trajs[i].copy()
        ax = self.ax
        out.p[:, ax] = self.pbar.value + self.dp.value
        out.v[:, ax] = self.vbar.value + self.dv.value
        out.u[:, ax] = self.ubar.value + self.du.value
        out.fa = np.asarray(self.fabar.value + self.dfa.value, float)
        return out


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
    program = None          # the team's _Stage2 (par.program "parametrized")
    converged = False
    it = 0
    while it < par.max_iterations and time.perf_counter() < deadline:
        for i in rng.permutation(pb.n):          # RandomShuffle
            ts = time.perf_counter()
            for _ in range(par.max_shrinks + 1):
                if time.perf_counter() >= deadline:
                    break
                left = deadline - time.perf_counter()
                if par.program == "rebuilt":
                    cand = solve_cp(pb, fm, trajs, int(i), par, rho[i], left, profile)
                else:
                    if program is None:
                        program = _Stage2(pb, trajs[0].T, trajs[0].dt, par, not fm.is_zero)
                    cand = program.solve(fm, trajs, int(i), rho[i], left, profile)
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
