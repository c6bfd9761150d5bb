"""What a real Crazyflie has and the clean simulator does not: each effect separate,
switchable (``Roughness.without(name)``; ``None`` in cloop.py flies the clean
simulator).  The parameters are data: params/rough.toml (units, sources, the commit
and command of the fit), written by ``ns2 sim calibrate`` (experiments/calibrate.py,
``make calibrate``) from the real flights of 16 June 2020, never from a swap or ring
result; ``Roughness()`` is that file, ``load_roughness(path)`` another one.  The
models, the statistics they are fitted to and the current values: docs/simulator.md.

vibration    propeller vibration seen by the IMU: white noise per 1 kHz sample added
             (in quadrature) to the BMI088 datasheet noise of sensing.py, per robot
             type, accelerometer (g) and gyro (deg/s).
turbulence   rotor-wake turbulence: a force along z on every robot, a first-order
             Gauss-Markov process of correlation time tau_s whose standard deviation
             is ``ratio`` x |f_a,z| of the ground truth at that robot (the wakes and
             the ground it sits in; no wake, no turbulence).
thrust       per-robot thrust scatter: each robot's psi_1 (PWM -> force) scaled by
             1 + eps, eps ~ N(0, sd), drawn per flight; the controller keeps the
             type's nominal map.
battery      battery sag: the voltage the motors and the controller see falls
             linearly from start_V at sag_V_per_min.
wake         the wake's profile read off the real flights: the ground truth's initial
             jet width sigma_0 and spreading rate S (aero.py) scaled by
             wake_sigma0_scale and wake_spread_scale.
lateral      the wake's lateral force on a robot beside its axis: the truth's constant
             K_XY (aero.py, 0.15: pushed out by the profile's gradient) replaced per
             receiving robot's type by ``lateral_k_xy``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .paramfile import PARAMS_DIR, Param, dump_params, load_params
from .vehicle import base_type

EFFECTS = ("vibration", "turbulence", "thrust", "battery", "wake", "lateral")
# the Crazyflie 2.x firmware's low-battery voltage (crazyflie-firmware 2a18fc29,
# platform_defaults_cf2.h DEFAULT_BAT_LOW_VOLTAGE): a flight ends before it
LOW_BATTERY_V = 3.2


# The parameters of params/rough.toml: name (a field of Roughness) -> unit, source, kind.
# Keyed ones are by robot type.  The functions named are experiments/calibrate.py's.
ROUGH_PARAMS = {
    "vibration_acc_g": Param("g", "fit_vibration: the fast part of the free-air residual force, replays of the real "
                             "pair random walks flown as they flew against the same real flights, in quadrature; "
                             "white noise per 1 kHz accelerometer sample", keyed=True, nonneg=True),
    "vibration_gyro_dps": Param("deg/s", "fit_vibration: the free-air motor-command noise, the same replays, in "
                                "quadrature; white noise per 1 kHz gyro sample", keyed=True, nonneg=True),
    "turbulence_ratio": Param("1 (force sd per unit |f_a,z|)", "fit_turbulence: the real within-bin wake scatter "
                              "beyond the simulator's (the other effects on), per unit of the bins' rms force, "
                              "pooled over the pair swaps", nonneg=True),
    "turbulence_tau_s": Param("s", "fit_turbulence: the share of that excess scatter in the fast part "
                              "(roughness.hp_share)", nonneg=True),
    "thrust_sd": Param("1 (relative sd of psi_1)", "thrust_sd: the spread of the robots' hover thrust within a type "
                       "(`ns2 real data`, data_report.json hover.by_robot)", nonneg=True),
    "battery_start_V": Param("V", "flightstats.battery: median of pm.vbat in the first second of every flight piece",
                             nonneg=True),
    "battery_sag_V_per_min": Param("V/min", "flightstats.battery: median straight-line slope of pm.vbat of every "
                                   "flight piece, negated"),
    "wake_sigma0_scale": Param("1 (factor on aero.py's sigma_0)", "fit_wake: least squares of real label - truth at "
                               "the logged states of every robot under a neighbour (no replay)", nonneg=True),
    "wake_spread_scale": Param("1 (factor on aero.py's spreading rate S)", "fit_wake: the same least squares",
                               nonneg=True),
    "lateral_k_xy": Param("1 (aero.py K_XY: push per unit r / sigma)", "fit_lateral: the labels' reading of the "
                          "lateral push (lateral_k_xy) in the real pair swaps, matched by replays flown as they flew",
                          keyed=True),
    "hover_motor_noise": Param("1 (fraction of full PWM)", "flightstats.free_air motor_noise of the real flights; not "
                               "an effect: the bound of BL-tuned's gain search (experiments/swarm.py)",
                               keyed=True, nonneg=True),
}
ROUGH_FILE = PARAMS_DIR / "rough.toml"
_FILE = load_params(ROUGH_FILE, ROUGH_PARAMS)[0]     # Roughness()'s values


def _from_file(name: str):
    """A field whose default is params/rough.toml's value (a fresh copy of a table)."""
    v = _FILE[name]
    return field(default_factory=lambda: dict(v)) if isinstance(v, dict) else field(default=v)


@dataclass(frozen=True)
class Roughness:
    # propeller vibration (per 1 kHz sample), by robot type
    vibration_acc_g: dict = _from_file("vibration_acc_g")
    vibration_gyro_dps: dict = _from_file("vibration_gyro_dps")
    # rotor-wake turbulence
    turbulence_ratio: float = _from_file("turbulence_ratio")
    turbulence_tau_s: float = _from_file("turbulence_tau_s")
    # per-robot thrust scatter (relative standard deviation of psi_1)
    thrust_sd: float = _from_file("thrust_sd")
    # battery sag
    battery_start_V: float = _from_file("battery_start_V")
    battery_sag_V_per_min: float = _from_file("battery_sag_V_per_min")
    # the wake's profile (aero.calibrated's scales)
    wake_sigma0_scale: float = _from_file("wake_sigma0_scale")
    wake_spread_scale: float = _from_file("wake_spread_scale")
    # the wake's lateral push per unit r / sigma on a robot of each type (aero.py K_XY)
    lateral_k_xy: dict = _from_file("lateral_k_xy")
    # not an effect: the motor-command noise of the real robots in free air (flightstats),
    # the bound of BL-tuned's gain search in the rough simulator (experiments/swarm.py)
    hover_motor_noise: dict = _from_file("hover_motor_noise")
    enabled: tuple = EFFECTS   # the calibrated simulator: all on

    def without(self, *names: str) -> "Roughness":
        _known(names)
        return replace(self, enabled=tuple(e for e in self.enabled if e not in names))

    def only(self, *names: str) -> "Roughness":
        _known(names)
        return replace(self, enabled=tuple(e for e in EFFECTS if e in names))

    def plus(self, *names: str) -> "Roughness":
        """These effects on as well."""
        return self.only(*set(self.enabled) | set(names))

    def on(self, name: str) -> bool:
        return name in self.enabled

    def imu_sd(self, robot_type: str, acc_sd_g: float, gyro_sd_dps: float) -> tuple[float, float]:
        """The IMU noise per sample of a robot of this type: datasheet plus vibration."""
        if not self.on("vibration"):
            return acc_sd_g, gyro_sd_dps
        t = base_type(robot_type)
        return (math.hypot(acc_sd_g, self.vibration_acc_g.get(t, 0.0)),
                math.hypot(gyro_sd_dps, self.vibration_gyro_dps.get(t, 0.0)))

    def thrust_factors(self, seed: int, n: int) -> np.ndarray:
        """1 + eps per robot (ones without the effect), from a stream of its own: no
        effect moves the simulator's other noises, so with every effect off the rough
        simulator is the clean one bit for bit."""
        if not self.on("thrust"):
            return np.ones(n)
        return 1.0 + np.random.default_rng([seed, 0x54]).normal(0.0, self.thrust_sd, n)

    def aero_kwargs(self, robot_types) -> dict:
        """aero.calibrated's keyword arguments for a team of these types: the wake's
        profile and the lateral push per robot (none of either without its effect)."""
        out = {}
        if self.on("wake"):
            out.update(sigma0_scale=self.wake_sigma0_scale, spread_scale=self.wake_spread_scale)
        if self.on("lateral"):
            out["k_xy"] = np.array([self.lateral_k_xy[base_type(t)] for t in robot_types])
        return out

    def battery_V(self, t_s: float, nominal_V: float) -> float:
        if not self.on("battery"):
            return nominal_V
        return self.battery_start_V - self.battery_sag_V_per_min * max(t_s, 0.0) / 60.0

    def flight_limit_s(self) -> float:
        """The longest flight on one battery charge: until the sag reaches the firmware's
        low-battery voltage (199 s at the fitted sag; the real flights of 16 June last at
        most 64 s); unlimited without the effect."""
        if not self.on("battery") or self.battery_sag_V_per_min <= 0.0:
            return math.inf
        return max(self.battery_start_V - LOW_BATTERY_V, 0.0) / self.battery_sag_V_per_min * 60.0


def load_roughness(path) -> Roughness:
    """The Roughness of a parameter file (ROUGH_PARAMS; the default effects on)."""
    return Roughness(**load_params(path, ROUGH_PARAMS)[0])


def dump_roughness(rough: Roughness, origin: dict) -> str:
    """params/rough.toml's text of ``rough``'s parameters, made as ``origin`` says
    (paramfile: commit, command, ...)."""
    values = {name: getattr(rough, name) for name in ROUGH_PARAMS}
    return dump_params(values, ROUGH_PARAMS, origin,
                       "The rough simulator's parameters (host/sim/roughness.py Roughness), fitted to the real\n"
                       "flights of 16 June 2020; `make calibrate` writes a new one beside its report.")


def _known(names) -> None:
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown roughness effects {unknown}: {EFFECTS}")


class GaussMarkov:
    """Unit first-order Gauss-Markov states of correlation time tau_s, ``shape`` of
    them, advanced once per simulator step dt, from a random stream of their own
    (``stream``: one per effect, so no effect moves another's noise); all zero and
    never advanced when off."""

    def __init__(self, shape, dt: float, tau_s: float, seed: int, stream: int, on: bool):
        self.on = on
        self.rho = math.exp(-dt / tau_s) if tau_s > 0 else 0.0
        self.rng = np.random.default_rng([seed, stream])
        self.x = self.rng.standard_normal(shape) if on else np.zeros(shape)

    def step(self) -> np.ndarray:
        self.x = self.rho * self.x + math.sqrt(1.0 - self.rho ** 2) * self.rng.standard_normal(self.x.shape)
        return self.x


class Turbulence:
    """The wake turbulence of one flight: per robot a unit Gauss-Markov state along z,
    advanced once per simulator step (dt), scaled by ratio x |f_a,z|."""

    def __init__(self, rough: Roughness, n: int, dt: float, seed: int):
        self.ratio = rough.turbulence_ratio
        self.gm = GaussMarkov(n, dt, rough.turbulence_tau_s, seed, 0x7B,
                              rough.on("turbulence") and rough.turbulence_ratio > 0.0)

    def force(self, f_a: np.ndarray) -> np.ndarray:
        """The turbulent force [N, 3] (N) to add to the truth f_a [N, 3] of this step."""
        out = np.zeros_like(f_a)
        if self.gm.on:
            out[:, 2] = self.ratio * np.abs(f_a[:, 2]) * self.gm.step()
        return out


def hp_share(tau_s: float, dt: float = 0.01, window: int = 21) -> float:
    """Share of a Gauss-Markov process's variance (correlation time tau_s, sampled at
    dt) left in x minus its centred moving average of ``window`` samples (the fast
    part of flightstats): used to read tau from the real fast share."""
    rho = math.exp(-dt / tau_s)
    w = -np.ones(window) / window
    w[window // 2] += 1.0
    k = np.abs(np.subtract.outer(np.arange(window), np.arange(window)))
    return float(w @ (rho ** k) @ w)
