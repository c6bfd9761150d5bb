"""Stage 1: sequential interaction-aware AO-RRT (Algorithm "planning", lines
init..PostProcess; paper, section "Stage 1: Sampling-Based Planning").

Robots are planned one after the other in a random permutation, the others being
dynamic obstacles with known trajectories (a finished robot rests at its last
position).  The tree lives in the state-cost space: x = [p; v; f_a,z-hat] plus
the time step k and the cost c = sum ||u|| dt.  An extension samples x_rand
uniformly in the state box (with f_a in [-f_a,max, f_a,max]) and c_rand in
[0, c^(i)], picks the nearest node with a kd-tree (scipy cKDTree), samples u
uniformly in the action box and propagates eq. (planning-discreteDynamics) for
one fixed dt with the learned force.  Every ``search.goal_bias_every``-th sample is the
goal (goal biasing).  StateValid: the state box including |f_a,z-hat| <=
f_a,max, the tight sphere collision r^(I(i) I(j)) against every planned robot
(continuous over the step), and for every neighbour j its force with robot i at
the new state: |f_a^(j)| <= f_a,max^(j) and |f_a^(j) - previous f_a^(j)| <= b_fa
(trust region).  AO-RRT repeats the search with the decreasing cost bound c^(i)
until the termination condition (iterations, patience).

At the first robot that finds no path, the whole team is planned at once by the
composite-state search of joint.py (``_joint``); its paths then go through the AO
iterations like any others.  If that fails too, relax-and-repair (``_relax``,
``_promoted``): a robot without a valid path that finds none takes a relaxed,
least-violating path (force limits widened by the smallest slack that works, then
cut while a path is found) as a placeholder; the others re-plan first and make
room for it, then it is promoted (same states, actions re-derived for the new
forces) or re-planned.  Both solve crossings in which several robots must deviate,
which one-at-a-time planning cannot (each plan is made with the others' fixed).

Stopping rules are counts, so a seed gives the same plan on every machine: an
RRT run ends after ``search.max_samples`` samples or ``search.max_nodes`` nodes, Stage 1 after
``ao_iterations`` AO iterations (or ``ao_patience`` without improvement) once
every robot has a path, and fails after ``max_rounds`` rounds in which some robot
found none.  The wall-clock limits ``search.time_s`` and ``total_time_s`` are only a
safety net against bad input that makes the counted work unexpectedly slow (a
huge ``search.max_samples``, a pathological model); with the defaults they are not
reached (a run that hits one says so in ``Stage1Result.hit_time_limit``, and its
outcome then depends on the machine).

For speed, ``search.batch`` candidate extensions share one nearest-neighbour query and
one batched call of the learned model (the tree is at most one batch stale).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from .dynamics import Trajectory, accel, hold_arrays, segment_distance, step, substates
from .forces import ForceModel
from .joint import joint_rrt
from .nearest import Nearest
from .problem import PlanningError, Problem, RRTParams


@dataclass
class Team:
    """The current solution of the whole team over the horizon H (rest after the end):
    states and joint forces at the knots and at the points inside every step."""
    P: np.ndarray           # [H+1, N, 3]
    V: np.ndarray           # [H+1, N, 3]
    FA: np.ndarray          # [H+1, N] grams, joint forces of the planned robots
    PS: np.ndarray          # [H, m-1, N, 3] inside step k (k -> k+1)
    VS: np.ndarray
    FAS: np.ndarray         # [H, m-1, N]
    planned: np.ndarray     # [N] bool
    trajs: list
    relaxed: np.ndarray     # [N] bool: the robot's path is a relaxed (limit-violating) placeholder
    BOUND: np.ndarray       # [H+1, N] grams, every robot's force bound at the knots (Problem.fa_plan)
    BOUNDS: np.ndarray      # [H, m-1, N] inside the steps

    @staticmethod
    def empty(problem: Problem, H: int) -> "Team":
        n, m = problem.n, problem.limits.fa_substeps
        P = np.repeat(problem.starts()[None], H + 1, 0)
        PS = np.repeat(P[:H, None], m - 1, 1)
        rest = problem.fa_plan()
        return Team(P, np.zeros_like(P), np.zeros((H + 1, n)), PS, np.zeros_like(PS), np.zeros((H, m - 1, n)),
                    np.zeros(n, bool), [None] * n, np.zeros(n, bool), np.tile(rest, (H + 1, 1)),
                    np.tile(rest, (H, m - 1, 1)))

    def needs_path(self, i: int) -> bool:
        """Robot i has no valid path yet (none, or a relaxed placeholder)."""
        return self.trajs[i] is None or bool(self.relaxed[i])

    def over_limit(self, i: int) -> bool:
        """Robot i's path is over its force bound in the current team (a relaxed
        neighbour pushed it there), at a knot or inside a step."""
        return bool(self.planned[i]) and bool(np.any(np.abs(self.FA[:, i]) > self.BOUND[:, i])
                                              or np.any(np.abs(self.FAS[:, :, i]) > self.BOUNDS[:, :, i]))

    def set(self, i: int, traj: Trajectory, fm: ForceModel, pb: Problem, relaxed: bool = False) -> None:
        """Robot i's path (``relaxed``: a placeholder, see AORRT._relax)."""
        types, kappa = pb.type_index(), float(pb.kappa()[i])
        H, m = len(self.P) - 1, self.PS.shape[1] + 1
        self.relaxed[i] = relaxed
        self.P[:, i], self.V[:, i] = hold_arrays(traj, H)
        ps, vs = substates(traj.p[:-1], traj.v[:-1], traj.accel(kappa), traj.dt, m)
        self.PS[:, :, i] = self.P[:H, None, i]
        self.VS[:, :, i] = 0.0
        self.PS[:traj.T, :, i], self.VS[:traj.T, :, i] = ps, vs
        self.trajs[i] = traj
        self.planned[i] = True
        present = np.repeat(self.planned[None], H + 1, 0)
        self.FA = fm.team_np(types, self.P, self.V, present)
        self.BOUND = pb.fa_bound(fm, self.P, self.V, present)
        n = len(self.planned)
        PS, VS = self.PS.reshape(-1, n, 3), self.VS.reshape(-1, n, 3)
        present = np.repeat(self.planned[None], H * (m - 1), 0)
        self.FAS = fm.team_np(types, PS, VS, present).reshape(H, m - 1, n)
        self.BOUNDS = pb.fa_bound(fm, PS, VS, present).reshape(H, m - 1, n)


@dataclass
class Tree:
    """Nodes of one RRT (for extraction and for the figures)."""
    p: np.ndarray
    v: np.ndarray
    fa: np.ndarray
    k: np.ndarray
    c: np.ndarray
    parent: np.ndarray
    u: np.ndarray
    excess: np.ndarray      # g: the largest force excess on the path from the root (<= 0: valid)
    n: int = 0
    rejected: list = field(default_factory=list)   # edges rejected by a neighbour's force check

    @staticmethod
    def alloc(size: int) -> "Tree":
        return Tree(np.zeros((size, 3)), np.zeros((size, 3)), np.zeros(size), np.zeros(size, int),
                    np.zeros(size), np.full(size, -1), np.zeros((size, 3)), np.full(size, -np.inf))

    def add(self, p, v, fa, k, c, parent, u, excess) -> np.ndarray:
        idx = np.arange(self.n, self.n + len(p))
        self.p[idx], self.v[idx], self.fa[idx], self.k[idx] = p, v, fa, k
        self.c[idx], self.parent[idx], self.u[idx], self.excess[idx] = c, parent, u, excess
        self.n += len(p)
        return idx

    def path(self, leaf: int) -> Trajectory:
        idx = [leaf]
        while self.parent[idx[-1]] >= 0:
            idx.append(self.parent[idx[-1]])
        idx = np.array(idx[::-1])
        return Trajectory(self.p[idx].copy(), self.v[idx].copy(), self.fa[idx].copy(), self.u[idx[1:]].copy(), 0.0)

    def trimmed(self) -> "Tree":
        s = slice(0, self.n)
        return Tree(self.p[s], self.v[s], self.fa[s], self.k[s], self.c[s], self.parent[s], self.u[s],
                    self.excess[s], self.n, self.rejected)


@dataclass
class Stage1Result:
    trajs: list                 # Trajectory per robot (own length)
    costs: list                 # c^(i)
    trees: list                 # last successful Tree per robot (figures)
    order_history: list         # permutation of every AO iteration
    accept_history: list        # (round, robot, cost, team P, V, FA, relaxed mask before acceptance, trajectory)
    iterations: int
    time_s: float
    time_per_robot_s: list
    samples_per_robot: list     # samples drawn by the RRT runs of every robot
    hit_time_limit: bool        # the wall-clock safety net stopped a run (outcome machine-dependent)
    relaxations: list = field(default_factory=list)   # (round, robot, force excess g) of every relaxed path
    promotions: list = field(default_factory=list)    # (round, robot): relaxed paths that became valid
    joint_round: int | None = None  # the round in which the composite-state search (joint.py) planned the team
    joint_samples: int = 0          # samples drawn by the composite-state search
    joint_time_s: float = 0.0       # seconds in the composite-state search (part of time_s)
    joint_trajs: list | None = None  # its paths, as it found them (AO iterations may improve them after)


class AORRT:
    def __init__(self, problem: Problem, fm: ForceModel, params: RRTParams = RRTParams()):
        self.pb, self.fm, self.par = problem, fm, params
        self.types = problem.type_index()
        self.kappa = problem.kappa()
        self.r = problem.r_pair()
        self.fa_max = problem.fa_plan()      # f_a,max less the model-error margin at rest (the sampled range)
        self.lo, self.hi = problem.box()
        self.ax = list(problem.axes)
        self.rng = np.random.default_rng(params.seed)
        self.hit_time_limit = False

    # ------------------------------------------------------------------ checks
    def _forces(self, team: Team, i: int, k: np.ndarray, q: np.ndarray, p: np.ndarray, v: np.ndarray):
        """Joint forces [B, N] of the planned robots and robot i (at p, v) at knot k
        (q = 0) or at point q of step k -> k+1 (q >= 1), the planned robots'
        previous forces [B, N] there, and every robot's force bound [B, N] there (g:
        f_a,max less the margin at its relative speed, Problem.fa_plan)."""
        kc, qc = np.minimum(k, len(team.PS) - 1), np.maximum(q, 1) - 1
        knot = (q == 0)[:, None]
        P = np.where(knot[..., None], team.P[k], team.PS[kc, qc])
        V = np.where(knot[..., None], team.V[k], team.VS[kc, qc])
        FA = np.where(knot, team.FA[k], team.FAS[kc, qc])
        P[:, i], V[:, i] = p, v
        present = np.repeat(team.planned[None], len(k), 0)
        present[:, i] = True
        bound = self.pb.fa_bound(self.fm, P, V, present)
        return self.fm.team_np(self.types, P, V, present), FA, bound

    def _excess(self, team: Team, i: int, k_prev, p_prev, v_prev, a, k, p, v):
        """StateValid (line state_valid) for candidates of robot i that move from
        (p_prev, v_prev) at step k_prev with acceleration a to (p, v) at step k, as
        margins: returns (hard [B]: box, speed and collision hold; own force at k [B];
        own excess [B]; neighbours' excess [B]).  An excess (g) is how far a force is
        over its bound: robot i's |f_a| over f_a,max^(i), and for every neighbour j
        its |f_a^(j)| over f_a,max^(j) and its change over the trust region b_fa (a
        neighbour whose path is relaxed has no trust region: its forces are no
        reference, it is re-planned).  Forces are checked at k and at fa_substeps - 1
        points inside the step; the state is valid when both excesses are <= 0."""
        lim = self.pb.limits
        ax = self.ax
        B = len(p)
        hard = (k <= len(team.P) - 1)
        hard &= np.all((p[:, ax] >= self.lo[ax]) & (p[:, ax] <= self.hi[ax]), 1)
        hard &= np.all(np.abs(v) <= lim.v_max + 1e-12, 1)
        fa_i, own, nbr = np.zeros(B), np.full(B, np.inf), np.full(B, np.inf)
        idx = np.flatnonzero(hard)
        if len(idx) == 0:
            return hard, fa_i, own, nbr
        kk, b, m = k[idx], len(idx), lim.fa_substeps
        ps, vs = substates(p_prev[idx], v_prev[idx], a[idx], self.par.search.dt, m)     # [b, m-1, 3]
        P = np.concatenate([p[idx][:, None], ps], 1).reshape(-1, 3)
        V = np.concatenate([v[idx][:, None], vs], 1).reshape(-1, 3)
        q = np.tile(np.arange(m), b)
        F, FA, bound = self._forces(team, i, np.repeat(kk, m) - (q > 0), q, P, V)
        F, FA, over = F.reshape(b, m, -1), FA.reshape(b, m, -1), (np.abs(F) - bound).reshape(b, m, -1)
        fa_i[idx] = F[:, 0, i]
        own[idx] = over[:, :, i].max(1)
        good = np.ones(b, bool)
        ex = np.full(b, -np.inf)
        for j in np.flatnonzero(team.planned):
            if j == i:
                continue
            d = segment_distance(p_prev[idx], p[idx], team.P[k_prev[idx], j], team.P[kk, j])
            good &= d >= self.r[i, j]
            ex = np.maximum(ex, over[:, :, j].max(1))
            if not team.relaxed[j]:
                ex = np.maximum(ex, np.abs(F[:, :, j] - FA[:, :, j]).max(1) - lim.b_fa_g)
        hard[idx] = good
        nbr[idx] = ex
        return hard, fa_i, own, nbr

    def _tail_excess(self, team: Team, i: int, k_end: int, p_end: np.ndarray) -> float:
        """A robot that reached its goal rests there; the largest force excess over the
        rest of the horizon, for it and its neighbours (inf if the rest is not
        collision-free).  The solution is accepted only if it fits the slack."""
        H = len(team.P) - 1
        if k_end >= H:
            return -np.inf
        k = np.arange(k_end + 1, H + 1)
        p = np.repeat(p_end[None], len(k), 0)
        z = np.zeros_like(p)
        hard, _, own, nbr = self._excess(team, i, k - 1, p, z, z, k, p, z)
        return float(np.maximum(own, nbr).max()) if hard.all() else np.inf

    # ------------------------------------------------------------------ one RRT
    def _key(self, p, v, fa, c):
        sp = self.par.search
        return np.column_stack([p[:, self.ax], sp.w_v * v[:, self.ax], sp.w_fa * fa[:, None], sp.w_c * c[:, None]])

    def rrt(self, team: Team, i: int, c_bound: float, deadline: float, slack: float = 0.0,
            max_samples: int | None = None):
        """Lines rrt_start..rrt_end for robot i with cost bound c_bound: at most
        ``max_samples`` samples and ``max_nodes`` nodes (``deadline``, wall clock,
        only as a safety net); returns (Trajectory or None, Tree, samples drawn, the
        path's largest force excess in g).  A node is valid when the largest excess on
        its path from the root (``_excess``) is at most ``slack``: 0 for a true
        search, > 0 for the relaxed search of ``_relax``."""
        sp = self.par.search
        max_samples = sp.max_samples if max_samples is None else max_samples
        tree, keys = self._root(team, i)
        nearest = Nearest(keys)
        n_samples = 0
        while tree.n < sp.max_nodes and n_samples < max_samples:
            if time.perf_counter() >= deadline:
                self.hit_time_limit = True
                break
            q = self._sample(i, n_samples, c_bound, slack)
            n_samples += sp.batch
            idx = self._extend(team, i, tree, keys, nearest.query(q, tree.n), c_bound, slack)
            found = self._reached(team, i, tree, idx, slack)
            if found is not None:
                return found[0], tree, n_samples, found[1]
        return None, tree, n_samples, np.inf

    def _root(self, team: Team, i: int) -> tuple[Tree, np.ndarray]:
        """A tree holding robot i's start (at rest, with its force among the planned
        robots) and the array of its nodes' keys in the state-cost space."""
        sp = self.par.search
        start = self.pb.starts()[i]
        tree = Tree.alloc(sp.max_nodes + sp.batch)
        fa0 = self._forces(team, i, np.array([0]), np.array([0]), start[None], np.zeros((1, 3)))[0][0, i]
        tree.add(start[None], np.zeros((1, 3)), np.array([fa0]), np.array([0]), np.array([0.0]), np.array([-1]),
                 np.zeros((1, 3)), np.array([-np.inf]))
        keys = np.zeros((sp.max_nodes + sp.batch, len(self.ax) * 2 + 2))
        keys[:1] = self._key(tree.p[:1], tree.v[:1], tree.fa[:1], tree.c[:1])
        return tree, keys

    def _sample(self, i: int, drawn: int, c_bound: float, slack: float) -> np.ndarray:
        """UniformSample(X) of one batch in the state-cost space (keys), with goal
        biasing: every ``goal_bias_every``-th sample is the goal at rest."""
        sp, lim, ax, rng = self.par.search, self.pb.limits, self.ax, self.rng
        b, na = sp.batch, len(ax)
        xr = np.zeros((b, 3))
        xr[:, ax] = rng.uniform(self.lo[ax], self.hi[ax], (b, na))
        vr = np.zeros((b, 3))
        vr[:, ax] = rng.uniform(-lim.v_max, lim.v_max, (b, na))
        far = rng.uniform(-self.fa_max[i] - slack, self.fa_max[i] + slack, b)
        cr = rng.uniform(0.0, c_bound, b) if np.isfinite(c_bound) else np.zeros(b)
        gb = (drawn + np.arange(b)) % sp.goal_bias_every == 0
        xr[gb], vr[gb], far[gb], cr[gb] = self.pb.goals()[i], 0.0, 0.0, 0.0
        return self._key(xr, vr, far, cr)

    def _extend(self, team: Team, i: int, tree: Tree, keys: np.ndarray, near: np.ndarray, c_bound: float,
                slack: float) -> np.ndarray:
        """UniformSample(U) and Propagate for dt with the learned force from the nodes
        ``near``; the new states that are valid (StateValid within ``slack``, cost
        below ``c_bound``) join the tree.  Returns their node indices."""
        sp, lim, ax = self.par.search, self.pb.limits, self.ax
        u = np.zeros((len(near), 3))
        u[:, ax] = self.rng.uniform(-lim.u_max, lim.u_max, (len(near), len(ax)))
        p_new, v_new = step(tree.p[near], tree.v[near], u, tree.fa[near], self.kappa[i], sp.dt)
        k_new = tree.k[near] + 1
        c_new = tree.c[near] + np.linalg.norm(u, axis=1) * sp.dt
        a = accel(u, tree.fa[near], self.kappa[i])
        hard, fa_new, own, nbr = self._excess(team, i, tree.k[near], tree.p[near], tree.v[near], a, k_new,
                                              p_new, v_new)
        ex_new = np.maximum(tree.excess[near], np.maximum(own, nbr))
        ok = hard & (ex_new <= slack) & (c_new < c_bound)
        nbr_bad = hard & (own <= slack) & (nbr > slack)
        for e in np.flatnonzero(nbr_bad)[:max(0, 3000 - len(tree.rejected))]:
            tree.rejected.append((tree.p[near[e]].copy(), p_new[e].copy()))
        sel = np.flatnonzero(ok)
        if len(sel) == 0:
            return sel
        idx = tree.add(p_new[sel], v_new[sel], fa_new[sel], k_new[sel], c_new[sel], near[sel], u[sel], ex_new[sel])
        keys[idx] = self._key(p_new[sel], v_new[sel], fa_new[sel], c_new[sel])
        return idx

    def _reached(self, team: Team, i: int, tree: Tree, idx: np.ndarray, slack: float):
        """The cheapest of the new nodes ``idx`` in the goal region whose rest at the
        goal (``_tail_excess``) fits the slack: (its path, the path's excess), or None."""
        sp = self.par.search
        goal = self.pb.goals()[i]
        at_goal = (np.linalg.norm(tree.p[idx] - goal, axis=1) <= sp.eps_p) & \
                  (np.linalg.norm(tree.v[idx], axis=1) <= sp.eps_v)
        for leaf in idx[at_goal][np.argsort(tree.c[idx][at_goal])]:
            tail = self._tail_excess(team, i, int(tree.k[leaf]), tree.p[leaf])
            if tail <= slack:
                traj = tree.path(int(leaf))
                traj.dt = sp.dt
                return traj, max(float(tree.excess[leaf]), tail)
        return None

    # ------------------------------------------------------------------ AO-RRT
    def check_endpoints(self) -> None:
        """Infeasible limits at the start or goal configuration: clear error."""
        for what, pts in (("start", self.pb.starts()), ("goal", self.pb.goals())):
            F = self.fm.team_np(self.types, pts[None], np.zeros_like(pts)[None])[0]
            bad = np.flatnonzero(np.abs(F) > self.fa_max)
            if len(bad):
                i = bad[0]
                raise PlanningError(f"infeasible limits: at the {what} robot {i} ({self.pb.robots[i].type}) feels "
                                    f"|f_a| = {abs(F[i]):.2f} g > f_a,max = {self.fa_max[i]:.2f} g")

    def _relax(self, team: Team, i: int, deadline: float, samples: list) -> float | None:
        """Relax-and-repair for robot i, which has no valid path against the team: a
        path that exceeds the force bounds and trust regions as little as it can find
        (box, speed and collision stay hard).  The smallest slack s of
        ``relax.levels_g`` with which RRT finds a path, then ``relax.refine`` searches
        with the slack cut to ``relax.shrink`` times the best path's excess (a
        decreasing bound, as AO-RRT does for the cost): a least-violating path keeps
        clear of the others as far as it can, so it leaves them room.  The path enters
        the team marked relaxed: the others then re-plan first (cost bounds reset) and
        must keep its force within its true limit (no trust region), i.e. they make
        room for it; then it is promoted (``_promoted``) or re-planned with the true
        limits (and relaxed again if there is not yet room).  Sequential planning alone
        cannot solve a crossing in which both robots must deviate (two large robots in
        the yz plane need more than a metre of vertical gap: neither can open it alone).
        Returns the excess (g) of the path taken, or None."""
        rp = self.par.relax
        n_max = min(rp.samples, self.par.search.max_samples)
        best, excess = None, np.inf
        for s in rp.levels_g:
            best, _, drawn, excess = self.rrt(team, i, np.inf, deadline, slack=float(s), max_samples=n_max)
            samples[i] += drawn
            if best is not None:
                break
        if best is None:
            return None
        for _ in range(rp.refine):
            if excess <= 0.0:
                break
            traj, _, drawn, ex = self.rrt(team, i, np.inf, deadline, slack=rp.shrink * excess, max_samples=n_max)
            samples[i] += drawn
            if traj is None:
                break
            best, excess = traj, ex
        team.set(i, best, self.fm, self.pb, relaxed=True)
        return float(excess)

    def _joint(self, st: "_Stage1State", deadline: float) -> bool:
        """The composite-state RRT of joint.py: up to ``joint.tries`` fresh trees (a
        tree that filled up without reaching the goals is stuck in the composite space;
        a new one usually is not).  Its paths replace the team's (costs updated, the
        time shared among the robots; copies of them as found kept in ``st``).
        Returns whether it found them."""
        jp, t0 = self.par.joint, time.perf_counter()
        trajs = None
        for _ in range(jp.tries):
            trajs, drawn = joint_rrt(self, deadline, jp.samples, jp.nodes)
            st.joint_samples += drawn
            if trajs is not None:
                break
        for j, tr in enumerate(trajs or []):
            st.team.set(j, tr, self.fm, self.pb)
            st.costs[j] = tr.effort()
        for j in range(self.pb.n):
            st.per_robot[j] += (time.perf_counter() - t0) / self.pb.n
        st.joint_time_s += time.perf_counter() - t0
        st.joint_trajs = None if trajs is None else [tr.copy() for tr in trajs]
        if trajs is not None:
            st.joint_round = st.rounds
        return trajs is not None

    def _promoted(self, team: Team, i: int) -> Trajectory | None:
        """A relaxed path of robot i that the others have made room for: the same
        states, the actions re-derived for the forces of the current team (u = a -
        kappa f_a,z-hat e_z, so the dynamics hold exactly), accepted when the action box
        and every robot's force limit hold over the whole horizon (knots and points
        inside the steps).  Box, speed and collision were hard when it was planned and
        for everyone who re-planned around it.  None when it does not qualify."""
        tr = team.trajs[i]
        T = tr.T
        fa = team.FA[:T + 1, i].copy()
        u = tr.accel(self.kappa[i]) - accel(np.zeros_like(tr.u), fa[:-1], self.kappa[i])
        if np.abs(u).max(initial=0.0) > self.pb.limits.u_max:
            return None
        if any(team.over_limit(j) for j in range(self.pb.n)):
            return None
        return Trajectory(tr.p.copy(), tr.v.copy(), fa, u, tr.dt)

    def run(self) -> Stage1Result:
        """Rounds until TerminationCondition1 (see the module docstring)."""
        self.pb.validate()
        self.check_endpoints()
        t0 = time.perf_counter()
        deadline = t0 + self.par.total_time_s
        st = _Stage1State.start(self.pb, self.par.search.max_steps)
        while not self._finished(st, self._round(st, deadline), deadline):
            pass
        # refresh every robot's forces jointly with the final team (they were stored
        # as they were at acceptance time)
        for i, tr in enumerate(st.team.trajs):
            tr.fa = st.team.FA[:tr.T + 1, i].copy()
        return Stage1Result(
            trajs=list(st.team.trajs), costs=st.costs, trees=st.trees, order_history=st.orders,
            accept_history=st.accepts, iterations=st.rounds, time_s=time.perf_counter() - t0,
            time_per_robot_s=st.per_robot, samples_per_robot=st.samples, hit_time_limit=self.hit_time_limit,
            relaxations=st.relaxations, promotions=st.promotions, joint_round=st.joint_round,
            joint_samples=st.joint_samples, joint_trajs=st.joint_trajs, joint_time_s=st.joint_time_s)

    def _round(self, st: "_Stage1State", deadline: float) -> bool:
        """One round: every robot in a random permutation (RandomShuffle), those
        without a valid path last (the others first make room for them).  Returns
        whether some robot's path improved."""
        team = st.team
        order = self.rng.permutation(self.pb.n)
        order = [int(i) for i in order if not team.needs_path(i)] + [int(i) for i in order if team.needs_path(i)]
        st.orders.append(order)
        improved = False
        for i in order:
            outcome = self._turn(st, i, deadline)
            improved |= outcome is not None
            if outcome == "joint":
                break
        st.rounds += 1
        return improved

    def _turn(self, st: "_Stage1State", i: int, deadline_total: float) -> str | None:
        """Robot i's turn: its relaxed path promoted, or a cheaper path searched (lines
        rrt..cost_update).  Without one, and without a valid path or over its limit
        because a relaxed neighbour pushed it there: the composite-state search (once,
        at the first conflict), else relax-and-repair (it gives way as little as it
        can, too).  Returns "improved", "joint" (the whole team was planned at once:
        the round ends) or None."""
        ts = time.perf_counter()
        deadline = min(ts + self.par.search.time_s, deadline_total)
        outcome = "improved" if self._new_path(st, i, deadline) else None
        if outcome is None and (st.team.needs_path(i) or st.team.over_limit(i)):
            if not st.joint_tried and self.par.joint.tries > 0:
                st.joint_tried = True
                st.per_robot[i] += time.perf_counter() - ts
                if self._joint(st, deadline_total):
                    return "joint"
                ts = time.perf_counter()
            excess = self._relax(st.team, i, deadline, st.samples)
            if excess is not None:
                st.relaxations.append((st.rounds, i, excess))
                st.costs[:] = [np.inf] * self.pb.n     # the others may change homotopy class to make room
        st.per_robot[i] += time.perf_counter() - ts
        return outcome

    def _new_path(self, st: "_Stage1State", i: int, deadline: float) -> bool:
        """Robot i's relaxed path promoted or a path below its cost bound c^(i) found:
        it joins the team and c^(i) <- its cost (line cost_update)."""
        team = st.team
        traj, tree = (self._promoted(team, i) if team.relaxed[i] else None), None
        if traj is not None:
            st.promotions.append((st.rounds, i))
        else:
            traj, tree, drawn, _ = self.rrt(team, i, st.costs[i], deadline)
            st.samples[i] += drawn
        if traj is None:
            return False
        st.accepts.append((st.rounds, i, traj.effort(), team.P.copy(), team.V.copy(), team.FA.copy(),
                           team.relaxed.copy(), traj.copy()))
        st.costs[i] = traj.effort()
        if tree is not None:
            st.trees[i] = tree.trimmed()
        team.set(i, traj, self.fm, self.pb)
        return True

    def _finished(self, st: "_Stage1State", improved: bool, deadline: float) -> bool:
        """TerminationCondition1 after a round: every robot has a valid path and the AO
        iterations or the patience are used up (or the safety time is).  A robot still
        without a path restarts the AO count and fails Stage 1 after ``max_rounds``
        rounds or at the safety time limit."""
        par = self.par
        missing = [i for i in range(self.pb.n) if st.team.needs_path(i)]
        st.since_improved = 0 if improved else st.since_improved + 1
        out_of_time = time.perf_counter() >= deadline
        self.hit_time_limit |= out_of_time
        if missing:
            st.ao_iterations = st.since_improved = 0
            if out_of_time:
                raise PlanningError(
                    f"no path found for robot(s) {missing} within the {par.total_time_s:.0f} s safety time limit "
                    f"of Stage 1 (goal unreachable under the limits, or the machine far too slow)")
            if st.rounds >= par.max_rounds:
                raise PlanningError(
                    f"no path found for robot(s) {missing} in {par.max_rounds} rounds of at most "
                    f"{par.search.max_samples} samples per robot (goal unreachable under the limits, or too few "
                    f"samples)")
            return False
        st.ao_iterations += 1
        return st.ao_iterations >= par.ao_iterations or st.since_improved >= par.ao_patience or out_of_time


@dataclass
class _Stage1State:
    """Stage 1's bookkeeping across rounds: the team, every robot's cost bound, and
    what Stage1Result reports."""
    team: Team
    costs: list
    trees: list
    per_robot: list
    samples: list
    orders: list = field(default_factory=list)
    accepts: list = field(default_factory=list)
    relaxations: list = field(default_factory=list)
    promotions: list = field(default_factory=list)
    joint_tried: bool = False
    joint_round: int | None = None
    joint_samples: int = 0
    joint_time_s: float = 0.0
    joint_trajs: list | None = None
    rounds: int = 0
    ao_iterations: int = 0          # AO iterations since every robot has a valid path
    since_improved: int = 0

    @staticmethod
    def start(problem: Problem, H: int) -> "_Stage1State":
        n = problem.n
        return _Stage1State(Team.empty(problem, H), [np.inf] * n, [None] * n, [0.0] * n, [0] * n)


def post_process(trajs: list, kappa: np.ndarray) -> list:
    """Uniform length (line postprocess): every trajectory held to the longest."""
    T = max(tr.T for tr in trajs)
    return [tr.held(T, float(k)) for tr, k in zip(trajs, kappa)]
