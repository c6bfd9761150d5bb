"""Independent check of a team solution with the joint learned forces: what the
planner promised, measured on the result (used by the experiments and the tests)."""
from __future__ import annotations

import numpy as np

from .dynamics import Trajectory, segment_distance, step, team_substates
from .forces import ForceModel
from .problem import Problem


def check_solution(pb: Problem, fm: ForceModel, trajs: list) -> dict:
    """Per robot: box and speed violation (m, m/s), worst |f_a,z-hat| with the whole
    team (g, at the knots and at least 3 points inside every step) against f_a,max and how
    far it comes over the planning bound (f_a,max less the margin at the robot's relative
    speed: <= 0 when the plan keeps it), closest approach to every other robot (continuous over
    each step, m) against r, goal error, and the nonlinear dynamics defect."""
    H = max(t.T for t in trajs)
    P = np.stack([np.concatenate([t.p, np.repeat(t.p[-1:], H - t.T, 0)]) for t in trajs], 1)
    V = np.stack([np.concatenate([t.v, np.zeros((H - t.T, 3))]) for t in trajs], 1)
    F = fm.team_np(pb.type_index(), P, V)
    held = [Trajectory(P[:, i], V[:, i], F[:, i], np.concatenate([t.u, np.zeros((H - t.T, 3))]), t.dt)
            for i, t in enumerate(trajs)]
    Ps, Vs = team_substates(held, pb.kappa(), max(pb.limits.fa_substeps, 4))
    F_sub = fm.team_np(pb.type_index(), Ps, Vs)
    over = np.concatenate([np.abs(F) - pb.fa_bound(fm, P, V),
                           np.abs(F_sub) - pb.fa_bound(fm, Ps, Vs)])
    lo, hi = pb.box()
    ax = list(pb.axes)
    r, fa_max, kappa, goals = pb.r_pair(), pb.fa_max(), pb.kappa(), pb.goals()
    out = []
    for i, tr in enumerate(trajs):
        clear = [float(segment_distance(P[:-1, i], P[1:, i], P[:-1, j], P[1:, j]).min() - r[i, j])
                 for j in range(pb.n) if j != i]
        p1, v1 = step(tr.p[:-1], tr.v[:-1], tr.u, F[:tr.T, i], kappa[i], tr.dt)
        out.append({
            "box_violation_m": float(max(0.0, np.max(tr.p[:, ax] - hi[ax]), np.max(lo[ax] - tr.p[:, ax]))),
            "speed_violation_mps": float(max(0.0, np.max(np.abs(tr.v) - pb.limits.v_max))),
            "action_violation": float(max(0.0, np.max(np.abs(tr.u) - pb.limits.u_max))),
            "worst_fa_g": float(max(np.abs(F[:, i]).max(), np.abs(F_sub[:, i]).max(initial=0.0))),
            "fa_max_g": float(fa_max[i]),
            "fa_over_bound_g": float(over[:, i].max()),
            "min_clearance_m": min(clear) if clear else float("inf"),
            "goal_error_m": float(np.linalg.norm(tr.p[-1] - goals[i])),
            "goal_speed_mps": float(np.linalg.norm(tr.v[-1])),
            "max_defect": float(max(np.abs(tr.p[1:] - p1).max(initial=0.0), np.abs(tr.v[1:] - v1).max(initial=0.0))),
        })
    return {"robots": out, "forces": F}


def is_valid(report: dict, tol: float = 1e-6) -> bool:
    return all(r["box_violation_m"] <= tol and r["speed_violation_mps"] <= tol and r["action_violation"] <= tol
               and r["worst_fa_g"] <= r["fa_max_g"] + tol and r["min_clearance_m"] >= -tol
               for r in report["robots"])
