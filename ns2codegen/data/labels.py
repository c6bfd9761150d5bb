"""Residual-force labels from flight logs, as the paper computes them for real flights
("Data Collection"): f_a = m v_dot - m g - R f_u, with

* v_dot from the logged velocity by five-point central differences,
  (-v[k+2] + 8 v[k+1] - 8 v[k-1] + v[k-2]) / (12 h), uniform log period h
  (the two first and last samples of a log get no label);
* f_u = [0; 0; T], T the sum of the motor forces: psi_1 (Table cfprops) of the
  logged PWM and battery voltage (grams per motor), passed through the first-order
  motor delay u_dot = lambda (u_c - u), discretized exactly for a command held
  over each log period.  No filtering beyond the differentiation stencil.

Inputs are only what a drone logs (t, p, v, q, pwm, battery voltage); the
simulator's ground truth is never read here.
"""
from __future__ import annotations

import numpy as np

from ..vehicle import G

V_NORM = 4.2


def five_point_derivative(x: np.ndarray, h: float) -> np.ndarray:
    """d/dt along axis 0; rows 0, 1, -2, -1 are NaN (no full stencil)."""
    d = np.full_like(x, np.nan, dtype=float)
    d[2:-2] = (-x[4:] + 8 * x[3:-1] - 8 * x[1:-3] + x[:-4]) / (12.0 * h)
    return d


def psi1_newtons(psi1, pwm, battery_V) -> np.ndarray:
    """Motor force (N) from normalized PWM and battery voltage through psi_1 (Table
    cfprops, grams, in PWM and V / 4.2); 0 for a stopped motor.  psi1 [..., 5],
    pwm [..., 4], battery_V [...] broadcast over the leading axes."""
    k = np.asarray(psi1, float)
    p = np.asarray(pwm, float)
    v = (np.asarray(battery_V, float) / V_NORM)[..., None]
    f_g = k[..., 0:1] + k[..., 1:2] * p + k[..., 2:3] * v + k[..., 3:4] * p * p + k[..., 4:5] * p * v
    return np.where(p > 0, np.clip(f_g, 0.0, None) * G / 1000.0, 0.0)


def first_order_delay(u_c: np.ndarray, a) -> np.ndarray:
    """u of the delay model u_dot = lambda (u_c - u) (eq. delay_model) sampled at t_k,
    exact for u_c[k] held on [t_k, t_k+1): u[k+1] = a u[k] + (1 - a) u_c[k] with
    a = exp(-lambda h_k) (a scalar, or one per step); u[0] = u_c[0] (steady state)."""
    a = np.broadcast_to(np.asarray(a, float), (max(len(u_c) - 1, 0),))
    u = np.empty_like(u_c)
    u[0] = u_c[0]
    for k in range(len(u_c) - 1):
        u[k + 1] = a[k] * u[k] + (1.0 - a[k]) * u_c[k]
    return u


def motor_forces(pwm: np.ndarray, battery_V: np.ndarray, psi1, lam: float, h: float) -> np.ndarray:
    """[T, 4] motor forces (N) from logged PWM [T, 4] and voltage [T] with the delay."""
    u_c = psi1_newtons(np.asarray(psi1, float)[None, :], pwm, battery_V)
    return first_order_delay(u_c, np.exp(-lam * h))  # logs start in steady state (hover)


def quat_to_R(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def residual_force(t, v, q, pwm, battery_V, mass_kg: float, psi1, lam: float) -> np.ndarray:
    """f_a [T, 3] (N) of one robot from its log; NaN where no label exists."""
    t = np.asarray(t, float)
    h = float(np.median(np.diff(t)))
    if not np.allclose(np.diff(t), h, rtol=1e-6, atol=1e-9):
        raise ValueError("log times must be uniformly spaced (resample first)")
    v_dot = five_point_derivative(np.asarray(v, float), h)
    T = motor_forces(np.asarray(pwm, float), np.asarray(battery_V, float), psi1, lam, h).sum(axis=1)
    R = quat_to_R(np.asarray(q, float))
    return mass_kg * v_dot - mass_kg * np.array([0.0, 0.0, -G]) - R[:, :, 2] * T[:, None]
