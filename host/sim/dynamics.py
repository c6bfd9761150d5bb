"""Rigid-body quadrotor dynamics with motor delay, eq. (dynamics), for N robots at once:

  p_dot = v                       m v_dot = m g + R f_u + f_a,   f_u = [0; 0; T]
  q_dot = 1/2 q (x) [0; w]        J w_dot = J w x w + tau_u + tau_a
  eta = [T; tau_u] = B0 u         u_dot = lambda (u_c - u)

State per robot: p (3), v (3), q (4, [w x y z], body to world), w (3), u (4, motor
forces in N).  Integrated with classic RK4; f_a, tau_a and u_c are held over a step.
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


def quat_to_R(q: np.ndarray) -> np.ndarray:
    """[N, 4] unit quaternions -> [N, 3, 3] rotation matrices (body to world)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


class Dynamics:
    def __init__(self, vehicles: list[Vehicle]):
        self.vehicles = vehicles
        self.m = np.array([veh.mass for veh in vehicles])[:, None]
        self.J = np.array([veh.inertia for veh in vehicles])
        self.lam = np.array([veh.lam for veh in vehicles])[:, None]
        self.B0 = np.array([veh.B0 for veh in vehicles])  # [N, 4, 4]

    def derivative(self, x: np.ndarray, u_c: np.ndarray, f_a: np.ndarray, tau_a: np.ndarray) -> np.ndarray:
        s = SwarmState.unpack(x)
        eta = np.einsum("nij,nj->ni", self.B0, s.u)
        R = quat_to_R(s.q / np.linalg.norm(s.q, axis=1, keepdims=True))
        v_dot = np.array([0.0, 0.0, -G]) + (R[:, :, 2] * eta[:, 0:1] + f_a) / self.m
        w, q = s.w, s.q
        q_dot = 0.5 * np.stack([-q[:, 1] * w[:, 0] - q[:, 2] * w[:, 1] - q[:, 3] * w[:, 2],
                                q[:, 0] * w[:, 0] + q[:, 2] * w[:, 2] - q[:, 3] * w[:, 1],
                                q[:, 0] * w[:, 1] + q[:, 3] * w[:, 0] - q[:, 1] * w[:, 2],
                                q[:, 0] * w[:, 2] + q[:, 1] * w[:, 1] - q[:, 2] * w[:, 0]], -1)
        w_dot = (np.cross(self.J * w, w) + eta[:, 1:4] + tau_a) / self.J
        u_dot = self.lam * (u_c - s.u)
        return np.concatenate([s.v, v_dot, q_dot, w_dot, u_dot], axis=1)

    def step(self, st: SwarmState, u_c: np.ndarray, dt: float, f_a=None, tau_a=None) -> SwarmState:
        """One RK4 step of length dt; f_a, tau_a (world force, body torque) held constant."""
        n = len(self.vehicles)
        f_a = np.zeros((n, 3)) if f_a is None else f_a
        tau_a = np.zeros((n, 3)) if tau_a is None else tau_a
        x = st.pack()
        k1 = self.derivative(x, u_c, f_a, tau_a)
        k2 = self.derivative(x + 0.5 * dt * k1, u_c, f_a, tau_a)
        k3 = self.derivative(x + 0.5 * dt * k2, u_c, f_a, tau_a)
        k4 = self.derivative(x + dt * k3, u_c, f_a, tau_a)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out = SwarmState.unpack(x.copy())
        out.q /= np.linalg.norm(out.q, axis=1, keepdims=True)
        return out
