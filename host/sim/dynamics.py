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


class Dynamics:
    def __init__(self, vehicles: list[Vehicle]):
        self.vehicles = vehicles
        self.m = np.array([veh.mass for veh in vehicles])[:, None]
        self.J = np.array([veh.inertia for veh in vehicles])
        self.lam = np.array([veh.lam for veh in vehicles])[:, None]
        self.B0 = np.array([veh.B0 for veh in vehicles])  # [N, 4, 4]

    def derivative(self, x: np.ndarray, u_c: np.ndarray, f_a: np.ndarray, tau_a: np.ndarray) -> np.ndarray:
        """x_dot for packed states [N, 17] (written out component-wise: the arrays are
        small, so fewer numpy calls make the simulator fast)."""
        qw, qx, qy, qz = x[:, 6], x[:, 7], x[:, 8], x[:, 9]
        wx, wy, wz = x[:, 10], x[:, 11], x[:, 12]
        u = x[:, 13:17]
        eta = np.einsum("nij,nj->ni", self.B0, u)
        inv_n2 = 1.0 / (qw * qw + qx * qx + qy * qy + qz * qz)   # R of the normalized quaternion
        thrust = eta[:, 0] / self.m[:, 0]
        d = np.empty_like(x)
        d[:, 0:3] = x[:, 3:6]
        d[:, 3] = 2.0 * (qx * qz + qw * qy) * inv_n2 * thrust + f_a[:, 0] / self.m[:, 0]
        d[:, 4] = 2.0 * (qy * qz - qw * qx) * inv_n2 * thrust + f_a[:, 1] / self.m[:, 0]
        d[:, 5] = (1.0 - 2.0 * (qx * qx + qy * qy) * inv_n2) * thrust + f_a[:, 2] / self.m[:, 0] - G
        d[:, 6] = -0.5 * (qx * wx + qy * wy + qz * wz)
        d[:, 7] = 0.5 * (qw * wx + qy * wz - qz * wy)
        d[:, 8] = 0.5 * (qw * wy + qz * wx - qx * wz)
        d[:, 9] = 0.5 * (qw * wz + qx * wy - qy * wx)
        Jx, Jy, Jz = self.J[:, 0], self.J[:, 1], self.J[:, 2]
        # J w_dot = (J w) x w + tau_u + tau_a
        d[:, 10] = ((Jy * wy) * wz - (Jz * wz) * wy + eta[:, 1] + tau_a[:, 0]) / Jx
        d[:, 11] = ((Jz * wz) * wx - (Jx * wx) * wz + eta[:, 2] + tau_a[:, 1]) / Jy
        d[:, 12] = ((Jx * wx) * wy - (Jy * wy) * wx + eta[:, 3] + tau_a[:, 2]) / Jz
        d[:, 13:17] = self.lam * (u_c - u)
        return d

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
