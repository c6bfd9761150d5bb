"""Double integrator plus the learned interaction force, eq. (planning-dynamics):

    x = [p; v; f_a,z-hat],   x_dot = [v; u + kappa f_a,z-hat e_z; d/dt f_a,z-hat]

(u in m/s^2, f_a,z-hat in grams, kappa = g / (1000 m) converts grams to m/s^2), and
its discretization with a zero-order hold on u + f_a over a step, eq.
(planning-discreteDynamics):

    v_{k+1} = v_k + a_k dt,  p_{k+1} = p_k + v_k dt + a_k dt^2 / 2,  a_k = u_k + kappa fa_k e_z

i.e. the Euler step of eq. (planning-discreteDynamics) for v, and for p the exact
integral of the held acceleration (the Euler position row plus a_k dt^2 / 2), so
that a plan is exactly a C^1 piecewise quadratic p(t): the Crazyflie polynomials of
output.py represent it without fitting error.  The force is an algebraic state:
fa_k = f_a,z-hat(p_k, v_k, neighbours at step k) (its own "dynamics" row).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

E_Z = np.array([0.0, 0.0, 1.0])


def accel(u: np.ndarray, fa: np.ndarray, kappa) -> np.ndarray:
    """a = u + kappa f_a,z e_z (broadcasts over leading axes)."""
    return u + (np.asarray(kappa) * fa)[..., None] * E_Z


def step(p: np.ndarray, v: np.ndarray, u: np.ndarray, fa: np.ndarray, kappa, dt: float):
    """One step of eq. (planning-discreteDynamics), batched over leading axes."""
    a = accel(u, fa, kappa)
    return p + v * dt + 0.5 * a * dt * dt, v + a * dt


@dataclass
class Trajectory:
    """States x_0..x_T (p, v [T+1, 3], fa [T+1] grams) and actions u_0..u_{T-1} [T, 3]."""
    p: np.ndarray
    v: np.ndarray
    fa: np.ndarray
    u: np.ndarray
    dt: float

    @property
    def T(self) -> int:
        return len(self.u)

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.T + 1) * self.dt

    def accel(self, kappa: float) -> np.ndarray:
        return accel(self.u, self.fa[:-1], kappa)

    def effort(self) -> float:
        """sum_k ||u_k|| dt: the discrete objective of eq. (motion-planning) (Stage 1 cost)."""
        return float(np.linalg.norm(self.u, axis=1).sum() * self.dt)

    def held(self, T: int, kappa: float) -> "Trajectory":
        """Post-processing to uniform length T (Algorithm "planning", PostProcess):
        repeat the last position at rest with the null action that cancels the force."""
        extra = T - self.T
        if extra < 0:
            raise ValueError("cannot shorten a trajectory")
        p = np.concatenate([self.p, np.repeat(self.p[-1:], extra, 0)])
        v = np.concatenate([self.v, np.zeros((extra, 3))])
        fa = np.concatenate([self.fa, np.repeat(self.fa[-1:], extra)])
        u_hold = -accel(np.zeros((extra, 3)), fa[self.T:self.T + extra], kappa)
        return Trajectory(p, v, fa, np.concatenate([self.u, u_hold]), self.dt)

    def copy(self) -> "Trajectory":
        return Trajectory(self.p.copy(), self.v.copy(), self.fa.copy(), self.u.copy(), self.dt)


def hold_arrays(traj: Trajectory, H: int) -> tuple[np.ndarray, np.ndarray]:
    """p, v [H+1, 3] of a robot that stays at its last position after its trajectory
    (how a finished robot is seen by the others: a dynamic obstacle at rest)."""
    extra = H - traj.T
    p = np.concatenate([traj.p, np.repeat(traj.p[-1:], max(extra, 0), 0)])[:H + 1]
    v = np.concatenate([traj.v, np.zeros((max(extra, 0), 3))])[:H + 1]
    return p, v


def substates(p: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float, m: int):
    """States inside each step (held acceleration a) at s = q dt / m, q = 1..m-1:
    p, v [..., m-1, 3] for p, v, a [..., 3] at the start of the step.  The learned
    force is a narrow spike when a robot crosses another's wake, so the force limits
    are checked at these points too, not only at the knots."""
    s = (np.arange(1, m) / m * dt)[:, None]
    p, v, a = p[..., None, :], v[..., None, :], a[..., None, :]
    return p + v * s + 0.5 * a * s * s, v + a * s


def team_substates(trajs: list, kappa, m: int):
    """substates of every robot of a uniform-length team: P, V [T (m-1), N, 3]
    (time-major: step k's points are rows k (m-1) .. (k+1)(m-1) - 1)."""
    out_p, out_v = [], []
    for tr, k in zip(trajs, kappa):
        ps, vs = substates(tr.p[:-1], tr.v[:-1], tr.accel(float(k)), tr.dt, m)
        out_p.append(ps.reshape(-1, 3))
        out_v.append(vs.reshape(-1, 3))
    return np.stack(out_p, 1), np.stack(out_v, 1)


def segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Minimum distance between two robots moving linearly from a0 to a1 and from b0
    to b1 over the same interval (closed form), batched over leading axes."""
    d0 = a0 - b0
    dd = (a1 - b1) - d0
    den = (dd * dd).sum(-1)
    s = np.clip(-(d0 * dd).sum(-1) / np.where(den > 1e-12, den, 1.0), 0.0, 1.0)
    s = np.where(den > 1e-12, s, 0.0)
    return np.linalg.norm(d0 + s[..., None] * dd, axis=-1)
