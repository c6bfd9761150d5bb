"""Planning problem and parameters as plain data.

A problem is a team of robots (type, start and goal position, velocities zero at
both ends) in a state box, planned either in the yz plane (``axes = (1, 2)``, x
and v_x held at zero, as in the paper's 2-D experiments) or in 3-D.  All arrays
are 3-D world vectors; only the active ``axes`` are sampled and optimized.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ns2codegen.config import Config
from ns2codegen.errors import Ns2Error
from ns2codegen.vehicle import G

GRAMS_TO_N = G / 1000.0


class PlanningError(Ns2Error, RuntimeError):
    """Bad planning input (collision at the start, goal outside the box, infeasible
    limits) or no solution within the time limits."""


@dataclass(frozen=True)
class Robot:
    type: str                 # robot type name of the config ("small", "large")
    start: tuple              # p_s (m), v_s = 0
    goal: tuple               # p_f (m), v_f = 0


def speed_bin(speeds_mps, speed):
    """The bin of a speed table (Limits.margin): k for speeds in (speeds_mps[k-1],
    speeds_mps[k]], 0 at or below speeds_mps[0], len(speeds_mps) above the last."""
    return np.searchsorted(np.asarray(speeds_mps, float), speed, side="left")


def check_margin(name: str, m) -> None:
    """A margin (g): a finite number >= 0, or a speed table {"speeds_mps": s, "margins_g":
    m} with s strictly increasing and > 0 and len(m) = len(s) + 1 (Limits.margin)."""
    def number(x):
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    if isinstance(m, dict):
        s, g = m.get("speeds_mps"), m.get("margins_g")
        if set(m) != {"speeds_mps", "margins_g"} or not isinstance(s, (list, tuple)) \
                or not isinstance(g, (list, tuple)) or len(g) != len(s) + 1:
            raise PlanningError(f"limit parameter {name} must be a number or a table {{speeds_mps: [s_1..s_n], "
                                f"margins_g: [m_0..m_n]}}, got {m!r}")
        if not all(number(x) and x > 0 for x in s) or any(b <= a for a, b in zip(s, s[1:])):
            raise PlanningError(f"limit parameter {name}.speeds_mps must be finite, > 0 and increasing, got {s!r}")
        if not all(number(x) and x >= 0 for x in g):
            raise PlanningError(f"limit parameter {name}.margins_g must be finite numbers >= 0, got {g!r}")
    elif not (number(m) and m >= 0):
        raise PlanningError(f"limit parameter {name} must be a finite number >= 0, got {m!r}")


def _require(owner: str, obj, ints=(), counts=(), positive=(), nonneg=()) -> None:
    """Refuse bad parameters where they are constructed (PlanningError naming the field):
    ``ints`` positive integers, ``counts`` integers >= 0, ``positive`` finite numbers > 0,
    ``nonneg`` finite numbers >= 0."""
    def bad(name, what):
        raise PlanningError(f"{owner} parameter {name} must be {what}, got {getattr(obj, name)!r}")

    for name in ints + counts:
        v = getattr(obj, name)
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= (1 if name in ints else 0)):
            bad(name, "a positive integer" if name in ints else "an integer >= 0")
    for name in positive + nonneg:
        v = getattr(obj, name)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and (v > 0 if name in positive else v >= 0)):
            bad(name, "a finite number > 0" if name in positive else "a finite number >= 0")


@dataclass(frozen=True)
class Limits:
    """The sets X^{I(i)} and U^{I(i)} of eq. (motion-planning), per robot type."""
    pos_lo: tuple = (-1.0, -1.0, 0.3)        # m, state box (active axes)
    pos_hi: tuple = (1.0, 1.0, 2.0)
    v_max: float = 1.0                       # m/s per axis
    u_max: float = 2.5                       # m/s^2 per axis (action box U)
    fa_max_g: dict = field(default_factory=lambda: {"small": 5.0, "large": 10.0})  # f_a,max per type
    b_fa_g: float = 3.0                      # trust region on a neighbour's force change
    fa_substeps: int = 4                     # force limits also checked at dt/4, dt/2, 3dt/4 of every step
    clearance_m: float = 0.0                 # added to the tight collision distance of every pair (see r_pair)
    fa_margin_g: float | dict = 0.0          # g of f_a,max kept free for model error: one value, or per type a
    #                                          value or a speed table {"speeds_mps": [...], "margins_g": [...]} (margin)

    def __post_init__(self):
        if not all(isinstance(x, (int, float)) and x > 0 for x in (self.v_max, self.u_max, self.b_fa_g)):
            raise PlanningError(f"infeasible limits: v_max, u_max and b_fa_g must be positive, got "
                                f"{self.v_max!r}, {self.u_max!r}, {self.b_fa_g!r}")
        _require("limit", self, ints=("fa_substeps",), nonneg=("clearance_m",))
        margins = self.fa_margin_g.items() if isinstance(self.fa_margin_g, dict) else [(None, self.fa_margin_g)]
        for t, m in margins:
            check_margin(f"fa_margin_g{'' if t is None else f'[{t}]'}", m)
        if not (len(self.pos_lo) == 3 and len(self.pos_hi) == 3):
            raise PlanningError(f"the state box needs 3-D pos_lo and pos_hi, got {self.pos_lo} .. {self.pos_hi}")
        bad = {t: f for t, f in self.fa_max_g.items() if not (isinstance(f, (int, float)) and f > 0)}
        if bad:
            raise PlanningError(f"infeasible limits: f_a,max must be positive, got {bad}")
        tight = {t: f - self.margin(t) for t, f in self.fa_max_g.items() if f - self.margin(t) <= 0}
        if tight:
            raise PlanningError(f"infeasible limits: f_a,max - fa_margin_g must be positive, got {tight}")


    def margin(self, robot_type: str, speed=0.0):
        """fa_margin_g of a robot type (0 for a type a per-type table leaves out) at the
        robot's relative speed to the neighbours the model sees (m/s, a number or an
        array: ForceModel.rel_speed_np).  A speed table gives margins_g[k] for speeds in
        (speeds_mps[k-1], speeds_mps[k]], the first at or below speeds_mps[0], the last
        above speeds_mps[-1]; a number holds at every speed."""
        m = self.fa_margin_g
        m = m.get(robot_type, 0.0) if isinstance(m, dict) else m
        if isinstance(m, dict):
            out = np.asarray(m["margins_g"], float)[speed_bin(m["speeds_mps"], speed)]
            return float(out) if np.ndim(out) == 0 else out
        return float(m) if np.ndim(speed) == 0 else np.full(np.shape(speed), float(m))


MAX_SAMPLES = 40000


@dataclass(frozen=True)
class SearchParams:
    """One RRT search: a robot's tree in AORRT.rrt, the team's in joint.py.  Every
    loop stops on a count (samples, nodes), so the same seed gives the same plan on
    any machine; ``time_s`` is a safety net only (see aorrt.py)."""
    dt: float = 0.1                 # s, fixed propagation step (also Stage 2's step)
    max_steps: int = 100            # horizon H: no plan longer than H dt
    goal_bias_every: int = 10       # every k-th sample is the goal (goal biasing)
    eps_p: float = 0.1              # m, goal region
    eps_v: float = 0.3              # m/s
    batch: int = 32                 # candidates propagated per batched model call
    max_nodes: int = 6000           # per tree
    max_samples: int = MAX_SAMPLES  # per RRT run (one robot, one cost bound): the primary stopping rule
    w_v: float = 0.4                # s: velocity weight of the nearest-neighbour metric
    w_fa: float = 0.01              # m/g: force weight of the metric
    w_c: float = 0.1                # cost weight of the metric (AO-RRT state-cost space)
    time_s: float = 60.0            # safety net per RRT run (wall clock)

    def __post_init__(self):
        _require("RRT", self, ints=("max_steps", "goal_bias_every", "batch", "max_nodes", "max_samples"),
                 positive=("dt", "eps_p", "eps_v", "time_s"), nonneg=("w_v", "w_fa", "w_c"))


@dataclass(frozen=True)
class RelaxParams:
    """Relax-and-repair (AORRT._relax): the slacks tried in turn and the refinement."""
    levels_g: tuple = (2.0, 4.0, 8.0, 16.0, 32.0)   # relaxed force bounds (g), tried in turn
    samples: int = MAX_SAMPLES // 4  # per relaxed RRT run (at most the search's max_samples)
    refine: int = 3                  # searches for a less violating relaxed path (slack cut each time)
    shrink: float = 0.6              # the next slack is this times the best relaxed path's force excess

    def __post_init__(self):
        _require("relax", self, ints=("samples",), counts=("refine",), positive=("shrink",))
        if not all(isinstance(s, (int, float)) and s > 0 for s in self.levels_g):
            raise PlanningError(f"relax parameter levels_g must be positive slacks, got {self.levels_g!r}")


@dataclass(frozen=True)
class JointParams:
    """The composite-state RRT of joint.py, tried at the first conflict."""
    tries: int = 4                  # fresh trees (0: off)
    samples: int = 100000           # per composite-state tree
    nodes: int = 20000

    def __post_init__(self):
        _require("joint", self, ints=("samples", "nodes"), counts=("tries",))


@dataclass(frozen=True)
class RRTParams:
    """Stage 1 (AO-RRT) parameters: the outer loop's here, each part's in its group.
    Every loop stops on a count (samples, nodes, rounds, iterations), so the same seed
    gives the same plan on any machine; the two time limits are a safety net only."""
    search: SearchParams = SearchParams()
    relax: RelaxParams = RelaxParams()
    joint: JointParams = JointParams()
    max_rounds: int = 20            # Stage 1 fails after this many rounds with a robot still without a path
    ao_iterations: int = 3          # AO-RRT outer iterations (cost bound decreases)
    ao_patience: int = 1            # stop after this many iterations without improvement
    total_time_s: float = 300.0     # safety net for Stage 1 of the whole team (wall clock)
    seed: int = 0

    def __post_init__(self):
        _require("RRT", self, ints=("max_rounds", "ao_iterations", "ao_patience"), positive=("total_time_s",))


PROGRAMS = ("parametrized", "rebuilt")


@dataclass(frozen=True)
class SCPParams:
    """Stage 2 parameters, eq. (scp)."""
    lambda_goal: float = 1000.0     # lambda_1, soft goal (infinity norm)
    lambda_box: float = 1000.0      # lambda_2, soft state box (delta)
    lambda_defect: float = 1000.0   # merit weight of the nonlinear dynamics defects
    b_p: float = 0.15               # m, trust region on positions
    b_v: float = 0.3                # m/s, on velocities
    b_u: float = 1.0                # m/s^2, on actions
    collision_margin: float = 0.01  # m added to r^(I(i) I(j)) in the convexified constraint
    max_iterations: int = 12
    tol: float = 1e-3               # relative decrease of the merit that counts as converged
    max_shrinks: int = 3            # trust-region halvings when a step is rejected
    time_limit_s: float = 60.0
    solver: str = "CLARABEL"
    seed: int = 0
    program: str = "parametrized"   # one DPP program per robot, its data changed per solve (scp.py);
    #                                 "rebuilt": the program built anew for every solve (to compare)

    def __post_init__(self):
        _require("SCP", self, ints=("max_iterations",), counts=("max_shrinks",),
                 positive=("lambda_goal", "lambda_box", "lambda_defect", "b_p", "b_v", "b_u", "tol", "time_limit_s"),
                 nonneg=("collision_margin",))
        if self.program not in PROGRAMS:
            raise PlanningError(f"SCP parameter program must be one of {PROGRAMS}, got {self.program!r}")


@dataclass
class Problem:
    cfg: Config
    robots: list
    limits: Limits = field(default_factory=Limits)
    axes: tuple = (1, 2)            # (1, 2): yz plane; (0, 1, 2): 3-D

    @property
    def n(self) -> int:
        return len(self.robots)

    def type_index(self) -> np.ndarray:
        return np.array([self.cfg.robot_types.index(r.type) for r in self.robots])

    def mass(self) -> np.ndarray:
        """kg per robot."""
        return np.array([self.cfg.vehicle(r.type)["mass_g"] / 1000.0 for r in self.robots])

    def kappa(self) -> np.ndarray:
        """m/s^2 per gram of f_a,z: the learned force enters v_dot as kappa f_a."""
        return GRAMS_TO_N / self.mass()

    def radius(self) -> np.ndarray:
        return np.array([float(self.cfg.vehicle(r.type).get("diameter_m", 0.12)) / 2.0 for r in self.robots])

    def r_pair(self) -> np.ndarray:
        """Sphere collision distance r^(I(i) I(j)) = (D_i + D_j) / 2 + clearance: the
        tight spheres of the paper with clearance 0; a clearance keeps plans out of
        the near field, where a learned model is least reliable (see experiments.py)."""
        r = self.radius()
        return r[:, None] + r[None, :] + self.limits.clearance_m

    def fa_max(self) -> np.ndarray:
        try:
            return np.array([float(self.limits.fa_max_g[r.type]) for r in self.robots])
        except KeyError as e:
            raise PlanningError(f"no interaction force limit f_a,max for robot type {e}") from e

    def fa_plan(self, speeds=None) -> np.ndarray:
        """The force bound the planner enforces: f_a,max - fa_margin_g (per type), so that
        a model that reads low by up to that margin still keeps the flight within f_a,max
        (the limit every result is reported against; ns2exp.margin measures it).
        ``speeds`` [..., N] (m/s, ForceModel.rel_speed_np): the bound [..., N] at those
        relative speeds; None: [N] at rest."""
        if speeds is None:
            speeds = np.zeros(self.n)
        speeds = np.asarray(speeds, float)
        margin = np.stack([self.limits.margin(r.type, speeds[..., i]) for i, r in enumerate(self.robots)], -1)
        return self.fa_max() - margin

    def fa_bound(self, fm, P, V, present=None) -> np.ndarray:
        """fa_plan at team states P, V [..., N, 3] (``present`` [..., N]): every robot's
        bound [..., N] at its relative speed to the neighbours ``fm`` (a ForceModel) sees."""
        return self.fa_plan(fm.rel_speed_np(self.type_index(), P, V, present))

    def starts(self) -> np.ndarray:
        return np.array([r.start for r in self.robots], float)

    def goals(self) -> np.ndarray:
        return np.array([r.goal for r in self.robots], float)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.limits.pos_lo, float), np.array(self.limits.pos_hi, float)

    def validate(self) -> None:
        """Bad input gives a clear message (PlanningError), never a hang: what depends on
        the robots and the config (the parameters check themselves when constructed)."""
        if self.n < 1:
            raise PlanningError("no robots to plan for")
        unknown = [r.type for r in self.robots if r.type not in self.cfg.robot_types]
        if unknown:
            raise PlanningError(f"unknown robot types {unknown}; the config has {self.cfg.robot_types}")
        self.fa_max()               # every type has a limit (the values are checked by Limits)
        lo, hi = self.box()
        if not np.all(lo[list(self.axes)] < hi[list(self.axes)]):
            raise PlanningError(f"empty state box {lo.tolist()} .. {hi.tolist()}")
        inactive = [a for a in range(3) if a not in self.axes]
        for what, pts in (("start", self.starts()), ("goal", self.goals())):
            if not np.all(np.isfinite(pts)):
                raise PlanningError(f"{what} positions must be finite")
            for i, p in enumerate(pts):
                a = list(self.axes)
                if np.any(p[a] < lo[a]) or np.any(p[a] > hi[a]):
                    raise PlanningError(f"robot {i} ({self.robots[i].type}): {what} {p.tolist()} is outside the "
                                        f"state box {lo.tolist()} .. {hi.tolist()} (unreachable)")
                if inactive and np.any(np.abs(p[inactive]) > 1e-12):
                    raise PlanningError(f"robot {i}: {what} must have 0 on the axes not planned ({inactive})")
            d = np.linalg.norm(pts[:, None] - pts[None, :], axis=2) + np.eye(self.n) * 1e9
            bad = np.argwhere(d < self.r_pair())
            if len(bad):
                i, j = bad[0]
                raise PlanningError(f"robots {i} and {j} are in collision at the {what} "
                                    f"({d[i, j]:.3f} m < r = {self.r_pair()[i, j]:.3f} m)")
