"""Ground-truth aerodynamic interaction model of the simulator (NOT the network).

For robot i (the receiver) it returns f_a = downwash from every robot j above it
+ ground effect + linear drag (world frame, newtons):

* Downwash.  Robot j's slipstream is a turbulent round jet carrying the momentum
  flux of its thrust T_j (momentum theory, Leishman, Principles of Helicopter
  Aerodynamics, 2nd ed., ch. 2; self-similar round jet, Pope, Turbulent Flows,
  2000, sec. 5.1: momentum flux conserved, Gaussian profile whose width grows
  linearly, sigma = R_j + S dz with spreading rate S ~ 0.09).  The dynamic
  pressure on the receiver's disc falls off with the distance dz below j, as
  1 / (dz + x0) with a virtual origin x0 (the near wake of a rotor decays more
  slowly than the 1/dz^2 of the far jet), so
      f_z = -c_w T_j (D_i / D_small) exp(-r^2 / (2 sigma^2)) / (dz + x0),
  r the horizontal distance to the wake axis, which is carried sideways by the
  relative horizontal velocity over the travel time dz / U_w of the wake
  (U_w from momentum theory, 2 sqrt(T_j / (2 rho A_j))).  The receiver is pushed
  out of the wake by the profile's gradient, f_xy = -k_xy |f_z| (r / sigma) e_r.
  c_w is calibrated to the paper's "about -9 g for a small robot 0.3 m under
  another small one" (Fig. vis); a large robot's double thrust gives about twice
  that.  Close to the ground the wake spreads sideways, which mitigates the
  downwash (Fig. vis (b)): factor tanh(z_i / h_g).
* Ground effect: Cheeseman and Bennett (ARC R&M 3021, 1955),
  T_IGE / T_OGE = 1 / (1 - (R_e / (4 z))^2), with an effective multirotor radius
  R_e calibrated to the paper's ~5 g at z = 0.05 m for a small robot (multirotor
  ground effect exceeds the single-rotor value; Sanchez-Cuevas et al., RA-L
  2017); z is limited below at R_e / 2 (the formula's singularity at R_e / 4).
* Drag: f = -c_d m v, linear in the robot's velocity (Foerster 2015: the
  Crazyflie's rotor drag is linear in the body velocity, about 1.3e-2 N s/m at
  hover for the 34 g vehicle, i.e. c_d = 0.38 per second).
"""
from __future__ import annotations

import numpy as np

from .vehicle import G, Vehicle

RHO = 1.2          # kg/m^3
JET_S = 0.09       # spreading rate of the wake
X0 = 0.15          # m, virtual origin of the 1 / (dz + x0) decay
K_XY = 0.15        # lateral push relative to the vertical force, per unit r/sigma
H_GROUND = 0.12    # m, height scale of the downwash mitigation near the ground
C_DRAG = 0.38      # 1/s: linear drag per kg of vehicle mass


def _disc(veh: Vehicle) -> tuple[float, float]:
    """Radius and area of the disc spanned by the vehicle (Table cfprops diameter)."""
    r = veh.diameter / 2.0
    return r, np.pi * r * r


class AeroModel:
    def __init__(self, vehicles: list[Vehicle], c_w: float = 1.0, r_e_ratio: float = 1.0):
        """c_w: downwash coefficient; r_e_ratio: ground-effect radius / disc radius."""
        self.vehicles = vehicles
        self.mass = np.array([v.mass for v in vehicles])
        radius_area = [_disc(v) for v in vehicles]
        self.radius = np.array([r for r, _ in radius_area])
        self.area = np.array([a for _, a in radius_area])
        self.c_w = c_w
        self.r_e = r_e_ratio * self.radius
        self.radius_ref = 0.06  # m, the small vehicle's disc (12 cm diameter)

    def downwash(self, p: np.ndarray, v: np.ndarray, thrust: np.ndarray) -> np.ndarray:
        """[N, 3] downwash forces from all pairs (j above i)."""
        n = len(p)
        f = np.zeros((n, 3))
        if n < 2:
            return f
        dz = p[None, :, 2] - p[:, None, 2]                       # [i, j]: j above i when > 0
        above = dz > 1e-3
        dzp = np.where(above, dz, 1.0)
        thrust = np.clip(thrust, 0.0, None)
        u_w = np.maximum(2.0 * np.sqrt(thrust / (2.0 * RHO * self.area)), 0.1)  # [j] wake speed
        rel_v = v[None, :, :2] - v[:, None, :2]                    # j relative to i
        offset = p[None, :, :2] - p[:, None, :2] + rel_v * (dzp / u_w[None, :])[..., None]
        r = np.linalg.norm(offset, axis=2)
        sigma = self.radius[None, :] + JET_S * dzp
        profile = np.exp(-r ** 2 / (2.0 * sigma ** 2))
        size = (self.radius / self.radius_ref)[:, None]
        fz = -self.c_w * thrust[None, :] * size * profile / (dzp + X0)
        fz = np.where(above, fz, 0.0)
        mitigation = np.tanh(np.clip(p[:, 2], 0.0, None) / H_GROUND)[:, None]
        fz = fz * mitigation
        # outward push: away from the wake center, proportional to |f_z| r / sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            direction = np.where(r[..., None] > 1e-9, -offset / r[..., None], 0.0)
        fxy = K_XY * np.abs(fz)[..., None] * (r / sigma)[..., None] * direction
        f[:, 2] = fz.sum(1)
        f[:, :2] = fxy.sum(1)
        return f

    def ground_effect(self, p: np.ndarray, thrust: np.ndarray) -> np.ndarray:
        re = self.r_e
        z = np.maximum(p[:, 2], re / 2.0)
        ratio = 1.0 / (1.0 - (re / (4.0 * z)) ** 2)
        return np.column_stack([np.zeros(len(p)), np.zeros(len(p)), thrust * (ratio - 1.0)])

    def drag(self, v: np.ndarray) -> np.ndarray:
        return -C_DRAG * self.mass[:, None] * v

    def __call__(self, p: np.ndarray, v: np.ndarray, thrust: np.ndarray | None = None) -> np.ndarray:
        """f_a [N, 3] in newtons; thrust [N] defaults to hover thrust m g."""
        thrust = self.mass * G if thrust is None else thrust
        return self.downwash(p, v, thrust) + self.ground_effect(p, thrust) + self.drag(v)


def calibrated(vehicles: list[Vehicle], small: Vehicle) -> AeroModel:
    """The model for ``vehicles`` with the two constants fitted on small-robot pairs."""
    return _calibrated(vehicles, small)


def _calibrated(vehicles: list[Vehicle], small: Vehicle) -> AeroModel:
    """Fit c_w (downwash: -9 g 0.3 m under a hovering small robot) and R_e (ground
    effect: +5 g for a hovering small robot at z = 0.05 m) with small-vehicle pairs."""
    probe = AeroModel([small, small])
    p = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.3]])
    f = probe.downwash(p, np.zeros((2, 3)), np.full(2, small.mass * G))[0, 2]
    c_w = 9.0e-3 * G / -f
    # 1/(1 - (R/(4 z))^2) - 1 = 5/34  =>  R = 4 z sqrt(1 - 34/39)
    target = 5.0 / (small.mass * 1000.0)
    r_e = 4.0 * 0.05 * np.sqrt(1.0 - 1.0 / (1.0 + target))
    return AeroModel(vehicles, c_w=c_w, r_e_ratio=r_e / _disc(small)[0])
