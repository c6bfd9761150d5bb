"""Vehicle parameters as plain data, from the config's [[robot_types]] entries, and
the tracking controller's default gains (used by the simulator and written into
the generated firmware header ns2_vehicles.h)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import Config

G = 9.81  # m/s^2: the one value of g in Python (C: NS2_G_MPS2 in ns2_controller.h)


@dataclass(frozen=True)
class Vehicle:
    name: str
    mass: float            # kg
    inertia: np.ndarray    # kg m^2, principal axes
    arm: float             # m, center to motor
    kappa: float           # m, yaw torque per thrust
    lam: float             # 1/s, motor delay constant (eq. delay_model)
    f_max: float           # N per motor
    diameter: float        # m, overall (Table cfprops)
    psi1: np.ndarray       # force (g) from (PWM, V/4.2): 1, p, v, p^2, p v
    psi2: np.ndarray       # PWM from (force g, V/4.2): 1, f, v, f^2, f v

    @property
    def B0(self) -> np.ndarray:
        """eta = B0 u, u = motor forces (N), eta = [T, tau_x, tau_y, tau_z]; Crazyflie X
        layout, motors at arm/sqrt(2) * [(+,-), (-,-), (-,+), (+,+)]."""
        a = self.arm / np.sqrt(2.0)
        return np.array([[1, 1, 1, 1],
                         [-a, -a, a, a],
                         [-a, a, a, -a],
                         [-self.kappa, self.kappa, -self.kappa, self.kappa]], dtype=float)


STRONG = 1.35  # the "S*" variant: motors with 35 % more force at the same PWM


def base_type(name: str) -> str:
    """Robot type of a simulated vehicle name ("small*" is a small robot)."""
    return name.rstrip("*")


# config keys of a robot type that simulation and the controller need
RIGID_BODY_KEYS = ("arm_length_m", "inertia_kgm2", "thrust_to_torque_m", "psi1", "psi2")


def vehicle(cfg: Config, name: str) -> Vehicle:
    """Parameters of robot type ``name``; "<type>*" is the type with stronger motors
    (psi_1 and the maximum force scaled by STRONG, psi_2 its inverse accordingly)."""
    if name.endswith("*"):
        v = vehicle(cfg, base_type(name))
        k = STRONG
        p2 = v.psi2
        return Vehicle(name, v.mass, v.inertia, v.arm, v.kappa, v.lam, v.f_max * k, v.diameter, v.psi1 * k,
                       np.array([p2[0], p2[1] / k, p2[2], p2[3] / k ** 2, p2[4] / k]))
    t = cfg.vehicle(name)
    for key in RIGID_BODY_KEYS:
        if key not in t:
            raise ValueError(f"robot type {name}: {key} is needed for simulation and the controller")
    return Vehicle(name, t["mass_g"] / 1000.0, np.array(t["inertia_kgm2"], float), float(t["arm_length_m"]),
                   float(t["thrust_to_torque_m"]), float(t["lambda"]), t["max_thrust_g"] / 4.0 * G / 1000.0,
                   float(t.get("diameter_m", 0.12)), np.array(t["psi1"], float), np.array(t["psi2"], float))


def has_rigid_body(cfg: Config, name: str) -> bool:
    """Whether robot type ``name`` has what simulation and the controller need."""
    t = cfg.vehicle(name)
    return all(k in t for k in RIGID_BODY_KEYS)


def default_gains(veh: Vehicle) -> dict:
    """Gains of the tracking controller (ns2_gains_t) scaled with mass and inertia
    (tuned in the simulator)."""
    J = veh.inertia
    # Kwd = Kw / lambda is the motor-delay compensation of the rate term (tau_d_dot /
    # lambda, ns2_controller.h), but not about yaw: the rotors' drag torque is weak, so
    # a yaw D term turns the gyro's vibration into motor commands (the real robots'
    # free-air vibration, docs/notebook/2026-11-simulator-calibration-rounds.md: 0.27 PWM rms at hover on a large robot
    # with it, 0.04 without, real 0.05-0.06; the authors' large robots fly none either)
    return {"Lp": [2.0, 2.0, 2.5], "Kv": [4.0 * veh.mass] * 3, "Gv": [1.5] * 3,
            "Lq": [18.0, 18.0, 8.0], "Kw": list(40.0 * J), "Gw": list(20.0 * J),
            "Kwd": list(40.0 * J[:2] / veh.lam) + [0.0], "int_v_max": 0.5, "int_w_max": 1.0,
            "fa_max_N": 0.3 * veh.mass * G, "min_thrust_N": 0.1 * veh.mass * G, "d_filter": 0.5}
