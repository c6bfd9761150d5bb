"""Ground-truth aerodynamic interaction model of the simulator (NOT the network).

The force on a robot follows from the flow through its rotors; the wakes of all
robots combine as flows, and only then is each robot's force computed (so
neighbours and the ground do not add up pair by pair).  World frame, newtons.

* Rotor response (blade element + momentum theory, Leishman, Principles of
  Helicopter Aerodynamics, 2nd ed., ch. 2-3).  At fixed rotor speed the thrust
  of robot i falls linearly with the axial inflow ratio (C_T = sigma a / 2
  (theta / 3 - lambda / 2)); with the momentum relation for a rotor in an axial
  (and edgewise) stream, in units of the hover induced velocity v_h:
      t = 1 - kappa (x + nu - 1),   t = nu sqrt(h^2 + (nu + x)^2),
  t = T / T_0 (T_0: the commanded motor thrust), nu = v_i / v_h, x the axial
  flow through the disc from outside (downwash of the wakes above + the robot's
  own climb rate - the ground's upwash) and h its edgewise speed.  kappa =
  sigma a / (8 lambda_h) (Crazyflie propeller: 2 blades, 5.5 mm chord, 22.5 mm
  radius, sigma = 0.156, a = 5.7, tip speed at hover 38 m/s).  f_z = T_0 (t - 1):
  non-linear in x, so wakes that overlap at a robot do not add up.
* Wake of robot j: a round jet carrying the rotors' momentum flux (Pope,
  Turbulent Flows, 2000, sec. 5.1: momentum flux conserved, Gaussian profile of
  width sigma = sigma_0 + S s, so the centre-line speed falls as sigma_0 / sigma),
  with the actuator-disc contraction near the rotor (v = v_i (1 + s / sqrt(s^2 +
  r^2)), the far wake at 2 v_i).  v_i is robot j's own induced velocity from
  the rotor response above: a robot in the wake of another sheds a weaker wake
  of its own (momentum flux of a stack adds, velocities do not), a robot in
  forward flight or in a climb a weaker one too (Glauert).  The wake is left
  behind by the robot's horizontal motion (carried along its path for the
  travel time s / wake speed, i.e. skewed) and averaged over the receiver's disc.
  The spreading rate S is the one constant calibrated on the downwash: the paper's
  9 g for a small robot 0.3 m under another.
* Ground: an image rotor under the ground gives the robot an upwash
  v_h (R_e / 4 z)^2 (Cheeseman and Bennett, ARC R&M 3021, 1955, the source image
  behind T_IGE / T_OGE = 1 / (1 - (R_e / 4 z)^2)); R_e is calibrated on the
  paper's +5 g for a small robot at z = 0.05 m.  A wake that reaches the ground
  stagnates: its vertical speed falls to zero within the impingement region,
  about 0.14 of the source height (Beltaos and Rajaratnam, J. Hydraulic Research
  12, 1974), factor tanh(z_i / (0.14 z_j)): the downwash is "mitigated" near the
  ground (Fig. vis (b)), and with the upwash through the same non-linear rotor
  response.
* Lateral force: the receiver is pushed out of a wake by the profile's gradient,
  K_XY x (the linearized z force of that wake) x (r / sigma); horizontal drag
  -c_d m v_xy linear in the velocity (Foerster 2015, 1.3e-2 N s/m for the 34 g
  vehicle).  The vertical drag is the rotor response to the climb rate above.

``calibration_table()`` compares the model with every quantitative point the paper
gives (docs/ground-truth.md).
"""
from __future__ import annotations

import numpy as np

from .vehicle import G, Vehicle

RHO = 1.2              # kg/m^3
ROTOR_R_SMALL = 0.0225  # m, Crazyflie 2.x propeller radius; other types scale with the diameter
D_SMALL = 0.12         # m, the small vehicle's diameter (Table cfprops)
SIGMA_A = 0.156 * 5.7  # solidity x lift slope of the propeller
TIP_SPEED = 38.0       # m/s at hover (about 16,000 rpm x 22.5 mm)
C_IMPINGE = 0.14       # impingement region / source height (Beltaos and Rajaratnam 1974)
K_XY = 0.15            # lateral push relative to the wake's vertical force, per unit r / sigma
C_DRAG = 0.38          # 1/s: horizontal linear drag per kg of vehicle mass
Z_MIN = 0.02           # m, landing-gear height: the ground terms are held below it
SWEEPS = 3             # Jacobi sweeps of the wake cascade (exact for stacks of 4 robots)


def rotor_radius(veh: Vehicle) -> float:
    return ROTOR_R_SMALL * veh.diameter / D_SMALL


def rotor_response(x, h, kappa):
    """(t, nu) of the rotor response: thrust ratio and induced velocity / v_h for
    axial inflow x and edgewise speed h (both / v_h).  Closed form for h = 0, then
    Newton on t(nu) = nu sqrt(h^2 + (nu + x)^2) = 1 - kappa (x + nu - 1)."""
    x = np.clip(x, -0.9, 4.0)   # descents faster than 0.9 v_h: vortex-ring state, out of scope
    b = x + kappa
    nu = 0.5 * (-b + np.sqrt(b * b + 4.0 * (1.0 + kappa - kappa * x)))
    h2 = np.asarray(h, float) ** 2
    if np.any(h2 > 0):
        for _ in range(6):
            q = np.sqrt(h2 + (nu + x) ** 2)
            g = nu * q - 1.0 + kappa * (x + nu - 1.0)
            dg = q + nu * (nu + x) / q + kappa
            nu = np.maximum(nu - g / dg, 1e-3)
    return 1.0 - kappa * (x + nu - 1.0), nu


class AeroModel:
    def __init__(self, vehicles: list[Vehicle], spread: float = 0.1, r_e_ratio: float = 1.0, k_xy: float = K_XY,
                 sigma0_scale: float = 1.0):
        """spread: the wake's spreading rate S; r_e_ratio: ground-effect radius / rotor
        radius; k_xy: the lateral push per unit r / sigma (K_XY), one for all or one per
        receiving robot; sigma0_scale: the jet's initial width sigma_0 relative to
        sqrt(2) r_rot (1: the momentum jet)."""
        self.vehicles = vehicles
        self.mass = np.array([v.mass for v in vehicles])
        self.r_rot = np.array([rotor_radius(v) for v in vehicles])
        self.area = 4.0 * np.pi * self.r_rot ** 2                 # four rotors
        self.disc = np.array([v.diameter / 2.0 for v in vehicles])  # the receiver's disc
        self.sigma0 = sigma0_scale * np.sqrt(2.0) * self.r_rot    # jet of the rotors' momentum flux
        v_h = np.sqrt(self.mass * G / (2.0 * RHO * self.area))
        self.kappa = SIGMA_A * TIP_SPEED / (8.0 * v_h)            # sigma a / (8 lambda_h) at hover
        self.spread = spread
        self.r_e = r_e_ratio * self.r_rot
        self.k_xy = np.broadcast_to(np.asarray(k_xy, float), (len(vehicles),))

    # -- the pieces -------------------------------------------------------------
    def _wakes(self, p, v, v_i, w_in, ground: bool):
        """Downward speed w[i, j] of robot j's wake at robot i's disc, with the wake
        axis offset o[i, j] (xy) and the disc-averaged width sigma_e[i, j]."""
        return self._wake_at(p, self.disc, np.arange(len(p)), p, v, v_i, w_in, ground)

    def _wake_at(self, pts, radius, owner, p, v, v_i, w_in, ground: bool):
        """Downward speed w[m, j] of robot j's wake (robots at p, v, induced velocity
        v_i, inflow w_in) at receiver m (centre pts[m], a disc of radius[m], belonging
        to robot owner[m]: 0 for j = owner[m]), with the wake axis offset o[m, j] (xy)
        and the disc-averaged width sigma_e[m, j]."""
        s = p[None, :, 2] - pts[:, None, 2]                        # depth of m below j
        sp = np.maximum(s, 0.0)
        r_j, s0 = self.r_rot[None, :], self.sigma0[None, :]
        sigma = s0 + self.spread * sp
        axial = 1.0 + s / np.sqrt(s * s + r_j * r_j)               # actuator-disc contraction
        u_c = v_i[None, :] * axial * s0 / sigma                    # centre line, momentum flux kept
        speed = np.maximum(2.0 * v_i + w_in, 0.5)[None, :]
        tau = sp * (1.0 + self.spread * sp / (2.0 * s0)) / speed   # wake travel time to depth s
        o = p[None, :, :2] - v[None, :, :2] * tau[..., None] - pts[:, None, :2]
        sig_e2 = sigma ** 2 + radius[:, None] ** 2 / 4.0           # averaged over the receiver's disc
        w = u_c * (sigma ** 2 / sig_e2) * np.exp(-(o ** 2).sum(-1) / (2.0 * sig_e2))
        if ground:
            zi = np.maximum(pts[:, None, 2], 0.0)
            w = w * np.tanh(zi / (C_IMPINGE * np.maximum(p[None, :, 2], Z_MIN)))
        w[np.arange(len(pts)), owner] = 0.0
        return w, o, np.sqrt(sig_e2)

    def _flow(self, p, v, thrust, ground: bool, sources):
        """The flow of every robot through the wake cascade: thrust [N], v_h [N], the
        edgewise speed h and own axial inflow (/ v_h, m/s) [N], the thrust ratio t and
        induced velocity nu [N], and the wakes' (w, o, sigma_e) of _wakes with the
        final cascade's inflow w_in [N] (None for one robot)."""
        n = len(p)
        thrust = self.mass * G if thrust is None else np.clip(np.asarray(thrust, float), 1e-4, None)
        v_h = np.sqrt(thrust / (2.0 * RHO * self.area))
        h = np.linalg.norm(v[:, :2], axis=1) / v_h
        own = v[:, 2]
        if ground:
            z = np.maximum(p[:, 2], Z_MIN)
            own = own - v_h * np.minimum((self.r_e / (4.0 * z)) ** 2, 0.9)
        mask = np.ones(n, bool) if sources is None else np.asarray(sources, bool)
        t, nu = rotor_response(own / v_h, h, self.kappa)
        w_in, wakes = np.zeros(n), None
        for _ in range(SWEEPS if n > 1 else 0):                   # wakes feed the rotors below
            w, o, sig = self._wakes(p, v, nu * v_h, w_in, ground)
            w = w * mask[None, :]
            wakes = (w, o, sig, w_in)
            w_in = w.sum(1)
            t, nu = rotor_response((w_in + own) / v_h, h, self.kappa)
        return thrust, v_h, h, own, mask, t, nu, wakes

    def forces(self, p: np.ndarray, v: np.ndarray, thrust: np.ndarray | None = None,
               ground: bool = True, sources: np.ndarray | None = None) -> np.ndarray:
        """f_a [N, 3] in newtons; thrust [N] defaults to hover thrust m g.  ground=False
        takes the ground away (free air); sources [N] bool: only those robots shed a
        wake (the others still feel the flow)."""
        p, v = np.asarray(p, float), np.asarray(v, float)
        return self._forces(p, v, self._flow(p, v, thrust, ground, sources))

    def _forces(self, p, v, flow) -> np.ndarray:
        thrust, v_h, _, _, _, t, _, wakes = flow
        n = len(p)
        f = np.zeros((n, 3))
        f[:, 2] = thrust * (t - 1.0)
        if n > 1:
            w, o, sig, _ = wakes
            c0 = self.kappa * (1.0 - (1.0 + self.kappa) / (2.0 + self.kappa))   # -dt/dx at x = 0
            r = np.linalg.norm(o, axis=2)
            with np.errstate(invalid="ignore", divide="ignore"):
                e = np.where(r[..., None] > 1e-9, -o / r[..., None], 0.0)
            push = (self.k_xy * (c0 * thrust / v_h))[:, None] * w * (r / sig)
            f[:, :2] = (push[..., None] * e).sum(1)
        f[:, :2] -= C_DRAG * self.mass[:, None] * v[:, :2]
        return f

    def __call__(self, p: np.ndarray, v: np.ndarray, thrust: np.ndarray | None = None) -> np.ndarray:
        """f_a [N, 3] in newtons; thrust [N] defaults to hover thrust m g."""
        return self.forces(p, v, thrust)


SNAPSHOT_SPACING_M = 1000.0   # snapshots side by side: a wake or push 1 km away is exactly 0 (exp underflows)


def forces_of_snapshots(model_of, P: np.ndarray, V: np.ndarray, chunk: int = 16) -> np.ndarray:
    """f_a [K, N, 3] (N) of K independent snapshots P, V [K, N, 3] of one team, ``chunk``
    at once (5x faster than one by one): the snapshots side by side
    SNAPSHOT_SPACING_M apart along x, where every wake and push between them is
    exactly 0, so each is its own forces() to within rounding (the rotor response's
    Newton steps run on a whole chunk once any robot in it moves edgewise; tested).
    model_of(k): the AeroModel of k copies of the team."""
    P, V = np.asarray(P, float), np.asarray(V, float)
    K, N = P.shape[:2]
    out = np.empty((K, N, 3))
    for a in range(0, K, chunk):
        k = min(chunk, K - a)
        p = P[a:a + k].copy()
        p[:, :, 0] += SNAPSHOT_SPACING_M * np.arange(k)[:, None]
        out[a:a + k] = model_of(k).forces(p.reshape(k * N, 3), V[a:a + k].reshape(k * N, 3)).reshape(k, N, 3)
    return out


# -- calibration -----------------------------------------------------------------
DOWNWASH_POINT = (0.3, -9.0)      # m, g: small 0.3 m under a hovering small robot (paper, introduction)
GROUND_POINT = (0.05, 5.0)        # m, g: small robot alone at z = 0.05 m (paper, Fig. vis (a))


def _bisect(f, lo: float, hi: float, it: int = 60) -> float:
    flo = f(lo)
    for _ in range(it):
        mid = 0.5 * (lo + hi)
        if (f(mid) > 0) == (flo > 0):
            lo, flo = mid, f(mid)
        else:
            hi = mid
    return 0.5 * (lo + hi)


_CACHE: dict = {}


def _constants(small: Vehicle) -> tuple[float, float]:
    key = (small.mass, small.diameter)
    if key not in _CACHE:
        _CACHE[key] = _fit(small)
    return _CACHE[key]


def _fit(small: Vehicle) -> tuple[float, float]:
    gap, target = DOWNWASH_POINT
    p = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0 + gap]])
    grams = lambda m, q: m.forces(q, np.zeros_like(q))[0, 2] * 1000.0 / G  # noqa: E731
    spread = _bisect(lambda s: grams(AeroModel([small, small], spread=s), p) - target, 0.01, 1.0)
    z, ge = GROUND_POINT
    q = np.array([[0.0, 0.0, z]])
    ratio = _bisect(lambda r: grams(AeroModel([small], r_e_ratio=r), q) - ge, 0.01, 4.0 * z / ROTOR_R_SMALL * 0.99)
    return spread, ratio


def calibrated(vehicles: list[Vehicle], small: Vehicle, k_xy=K_XY, sigma0_scale: float = 1.0,
               spread_scale: float = 1.0) -> AeroModel:
    """The model for ``vehicles`` with its two constants fitted on small-robot points:
    the wake's spreading rate on the 9 g at 0.3 m, the ground-effect radius on the
    +5 g at z = 0.05 m.  sigma0_scale, spread_scale: the wake's initial width and
    spreading rate relative to those (the rough simulator's wake read off the real
    flights, roughness.py "wake"; 1 and 1: the paper's); k_xy: the lateral push, one
    for all or one per robot (roughness.py "lateral")."""
    spread, ratio = _constants(small)
    return AeroModel(vehicles, spread=spread * spread_scale, r_e_ratio=ratio, k_xy=k_xy, sigma0_scale=sigma0_scale)
