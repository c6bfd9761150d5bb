"""Flying a plan in the simulator (host/sim) with the firmware tracking controller
in the loop and the simulator's ground-truth interactions (host/sim/aero.py, not
the network), as in the paper's planning experiments: "a nonlinear controller,
which uses the planned controls as feed-forward term".  The setpoint is the
planned p(t), v(t) (exact piecewise quadratic) with the planned control u_k as
acceleration feed-forward; the controller runs without its own learned term
(f_a-hat = 0), so the plan alone decides whether the interactions were foreseen.
The robots hover at their starts for ``t_pre`` s first and at their goals for
``t_post`` s after the plan."""
from __future__ import annotations

import numpy as np

from ns2plan.problem import GRAMS_TO_N, Problem


def plan_setpoints(trajs: list, kappa, t_pre: float):
    from ns2host.sim.cloop import Setpoints

    dt, T = trajs[0].dt, trajs[0].T
    P = np.stack([t.p for t in trajs])            # [N, T+1, 3]
    V = np.stack([t.v for t in trajs])
    U = np.stack([t.u for t in trajs])            # [N, T, 3]
    A = np.stack([t.accel(float(k)) for t, k in zip(trajs, kappa)])
    n = len(trajs)

    def sp(t, state=None):
        tau = t - t_pre
        if tau <= 0.0:
            return Setpoints(P[:, 0], np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n))
        if tau >= T * dt:
            return Setpoints(P[:, -1], np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n))
        k = min(int(tau / dt), T - 1)
        s = tau - k * dt
        return Setpoints(P[:, k] + V[:, k] * s + 0.5 * A[:, k] * s * s, V[:, k] + A[:, k] * s, U[:, k], np.zeros(n))

    return sp


def track(pb: Problem, trajs: list, gen_dir, t_pre: float = 1.0, t_post: float = 1.0) -> dict:
    """Fly the plan; per robot the worst tracking error max_t ||p - p_d|| (eq. metric)
    and the worst true |f_a,z| (g) from the start of the plan to the end of t_post."""
    from ns2host.sim.cloop import CLoopSwarm, robots_of

    sw = CLoopSwarm(pb.cfg, robots_of([r.type for r in pb.robots], pb.starts()), gen_dir, aero=True)
    duration = t_pre + trajs[0].T * trajs[0].dt + t_post
    log = sw.run(duration, plan_setpoints(trajs, pb.kappa(), t_pre))
    w = log["t"] >= t_pre
    err = np.linalg.norm(log["truth_p"][w] - log["p_d"][w], axis=2).max(0)
    fa = np.abs(log["truth_fa"][w, :, 2]).max(0) / GRAMS_TO_N
    return {"worst_error_m": err.tolist(), "worst_fa_g": fa.tolist(), "log": log}
