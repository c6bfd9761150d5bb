"""Rigid-body quadrotor dynamics with motor delay, eq. (dynamics), for N robots at once
(the RK4 step is the C kernel host/ns2_sim.c, called once per step for all robots):

  p_dot = v                       m v_dot = m g + R f_u + f_a,   f_u = [0; 0; T]
  q_dot = 1/2 q (x) [0; w]        J w_dot = J w x w + tau_u + tau_a
  eta = [T; tau_u] = B0 u         u_dot = lambda (u_c - u)

State per robot: p (3), v (3), q (4, [w x y z], body to world), w (3), u (4, motor
forces in N).  Classic RK4; f_a, tau_a and u_c are held over a step; the quaternion is
renormalized after each step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .vehicle import G, Vehicle


@dataclass
class SwarmState:
    p: np.ndarray
    v: np.ndarray
    q: np.ndarray
    w: np.ndarray
    u: np.ndarray

    @staticmethod
    def hover(positions, vehicles: list[Vehicle]) -> "SwarmState":
        n = len(vehicles)
        q = np.zeros((n, 4))
        q[:, 0] = 1.0
        u = np.array([[veh.mass * G / 4.0] * 4 for veh in vehicles])
        return SwarmState(np.array(positions, float).reshape(n, 3), np.zeros((n, 3)), q, np.zeros((n, 3)), u)

    def pack(self) -> np.ndarray:
        return np.concatenate([self.p, self.v, self.q, self.w, self.u], axis=1)

    @staticmethod
    def unpack(x: np.ndarray) -> "SwarmState":
        return SwarmState(x[:, 0:3], x[:, 3:6], x[:, 6:10], x[:, 10:13], x[:, 13:17])


class Dynamics:
    """RK4 of eq. (dynamics) for N robots; the step runs in C (host/ns2_sim.c)."""

    def __init__(self, vehicles: list[Vehicle]):
        from ..cbuild import load_sim

        self.ffi, self.lib = load_sim()
        self.vehicles = vehicles
        self.par = np.ascontiguousarray(np.array(
            [[v.mass, *v.inertia, v.lam, *v.B0.ravel()] for v in vehicles], float))

    def step(self, st: SwarmState, u_c: np.ndarray, dt: float, f_a=None, tau_a=None) -> SwarmState:
        """One RK4 step of length dt; f_a (world force), tau_a (body torque) and the
        motor command u_c (N) held constant."""
        n = len(self.vehicles)
        x = np.ascontiguousarray(st.pack(), float)
        f_a = np.zeros((n, 3)) if f_a is None else np.ascontiguousarray(f_a, float)
        tau_a = np.zeros((n, 3)) if tau_a is None else np.ascontiguousarray(tau_a, float)
        u_c = np.ascontiguousarray(u_c, float)
        buf = lambda a: self.ffi.cast("double *", self.ffi.from_buffer(a))  # noqa: E731
        self.lib.ns2_sim_rk4(n, buf(x), buf(self.par), buf(u_c), buf(f_a), buf(tau_a), dt)
        return SwarmState.unpack(x)
