"""Planning problem and parameters as plain data.

A problem is a team of robots (type, start and goal position, velocities zero at
both ends) in a state box, planned either in the yz plane (``axes = (1, 2)``, x
and v_x held at zero, as in the paper's 2-D experiments) or in 3-D.  All arrays
are 3-D world vectors; only the active ``axes`` are sampled and optimized.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ns2codegen.config import Config
from ns2codegen.errors import Ns2Error

G = 9.81
GRAMS_TO_N = G / 1000.0


class PlanningError(Ns2Error, RuntimeError):
    """Bad planning input (collision at the start, goal outside the box, infeasible
    limits) or no solution within the time limits."""


@dataclass(frozen=True)
class Robot:
    type: str                 # robot type name of the config ("small", "large")
    start: tuple              # p_s (m), v_s = 0
    goal: tuple               # p_f (m), v_f = 0


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
    fa_margin_g: float = 0.0                 # g of f_a,max the planner keeps free for model error (see fa_plan)


MAX_SAMPLES = 40000


@dataclass(frozen=True)
class RRTParams:
    """Stage 1 (AO-RRT) parameters.  Every loop stops on a count (samples, nodes,
    rounds, iterations), so the same seed gives the same plan on any machine; the
    two time limits are a safety net only (see aorrt.py)."""
    dt: float = 0.1                 # s, fixed propagation step (also Stage 2's step)
    max_steps: int = 100            # horizon H: no plan longer than H dt
    goal_bias_every: int = 10       # every k-th sample is the goal (goal biasing)
    eps_p: float = 0.1              # m, goal region
    eps_v: float = 0.3              # m/s
    batch: int = 32                 # candidates propagated per batched model call
    max_nodes: int = 6000           # per tree
    max_samples: int = MAX_SAMPLES  # per RRT run (one robot, one cost bound): the primary stopping rule
    max_rounds: int = 20            # Stage 1 fails after this many rounds with a robot still without a path
    relax_levels_g: tuple = (2.0, 4.0, 8.0, 16.0, 32.0)   # relax-and-repair slacks (g), tried in turn
    relax_samples: int = MAX_SAMPLES // 4   # per relaxed RRT run
    relax_refine: int = 3           # searches for a less violating relaxed path (slack cut each time)
    relax_shrink: float = 0.6       # the next slack is this times the best relaxed path's force excess
    joint_tries: int = 4            # composite-state RRT (joint.py) at the first conflict: fresh trees, 0: off
    joint_samples: int = 100000     # per composite-state tree
    joint_nodes: int = 20000
    ao_iterations: int = 3          # AO-RRT outer iterations (cost bound decreases)
    ao_patience: int = 1            # stop after this many iterations without improvement
    rrt_time_s: float = 60.0        # safety net per RRT run (wall clock)
    total_time_s: float = 300.0     # safety net for Stage 1 of the whole team (wall clock)
    w_v: float = 0.4                # s: velocity weight of the nearest-neighbour metric
    w_fa: float = 0.01              # m/g: force weight of the metric
    w_c: float = 0.1                # cost weight of the metric (AO-RRT state-cost space)
    seed: int = 0


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

    def fa_plan(self) -> np.ndarray:
        """The force bound the planner enforces: f_a,max - fa_margin_g, so that a model
        that reads low by up to that margin still keeps the flight within f_a,max (the
        limit every result is reported against)."""
        return self.fa_max() - self.limits.fa_margin_g

    def starts(self) -> np.ndarray:
        return np.array([r.start for r in self.robots], float)

    def goals(self) -> np.ndarray:
        return np.array([r.goal for r in self.robots], float)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.limits.pos_lo, float), np.array(self.limits.pos_hi, float)

    def validate(self) -> None:
        """Bad input gives a clear message (PlanningError), never a hang."""
        lim = self.limits
        if self.n < 1:
            raise PlanningError("no robots to plan for")
        unknown = [r.type for r in self.robots if r.type not in self.cfg.robot_types]
        if unknown:
            raise PlanningError(f"unknown robot types {unknown}; the config has {self.cfg.robot_types}")
        if not (lim.v_max > 0 and lim.u_max > 0 and lim.b_fa_g > 0):
            raise PlanningError("infeasible limits: v_max, u_max and b_fa must be positive")
        if not (np.isfinite(lim.fa_margin_g) and lim.fa_margin_g >= 0):
            raise PlanningError(f"fa_margin_g must be >= 0, got {lim.fa_margin_g}")
        if not np.all(self.fa_plan() > 0):
            raise PlanningError(f"infeasible limits: f_a,max - fa_margin_g must be positive, got "
                                f"{self.fa_plan().tolist()}")
        if not (np.isfinite(lim.clearance_m) and lim.clearance_m >= 0):
            raise PlanningError(f"clearance_m must be >= 0, got {lim.clearance_m}")
        if not (isinstance(lim.fa_substeps, int) and lim.fa_substeps >= 1):
            raise PlanningError("fa_substeps must be a positive integer")
        fa_max = self.fa_max()
        if not np.all(fa_max > 0):
            raise PlanningError(f"infeasible limits: f_a,max must be positive, got {fa_max.tolist()}")
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
