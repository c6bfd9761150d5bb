"""C-in-the-loop: every robot flies as a Crazyflie does, at the stabilizer's 1 kHz, in
C (host/ns2_fly.c): IMU with noise and bias -> the firmware's own EKF (kalman_core,
fed by one mocap marker at 100 Hz with latency and loss) -> the drone's code path
ns2_pilot (firmware/src: peer table from the same broadcast, sliced prediction, the
controller at 500/100 Hz, psi_2 PWM), ns2_pilot with a position law of its own (a
PositionLaw, its C compiled into the kernel) or the firmware's Mellinger controller -> motors
(psi_1) -> rigid-body dynamics.  The learned term is off in the baseline (f_a = 0, as
in the paper).  The ground truth (true state, interaction force) stays in Python and
in the log's ``truth_*`` fields; the drone's log fields are what the drone knows."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ns2codegen.config import Config
from ns2codegen.onboard import AdaptCfg, adapt_cfg_ok

from ..cbuild import fill_gains, fill_vehicle
from ..cfhost import FlyLaw, load_fly
from ..onboard import fill_adapt_cfg
from .aero import calibrated
from .dynamics import Dynamics, SwarmState
from .roughness import Roughness, Turbulence
from .sensing import Sensing
from .vehicle import G, base_type, default_gains, vehicle

TICK_HZ, ATT_HZ, POS_HZ = 1000, 500, 100
STEP_TICKS = TICK_HZ // ATT_HZ  # ticks per Python step (the interaction force is held over it)


@dataclass
class Setpoints:
    """Desired p, v, a [N, 3] and yaw [N] at a time."""
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    yaw: np.ndarray


LOG_HZ = 100  # what a Crazyflie logs to its uSD card, about every 10 ms


@dataclass
class FlightLog:
    """What the drones log (t, p, v, q: the EKF's estimate; w: filtered gyro; pwm,
    battery; [T, N, ...]) plus, kept apart, the simulator's ground truth (truth_p,
    truth_v, truth_fa) and the setpoints, for evaluation only."""
    t: list = field(default_factory=list)
    p: list = field(default_factory=list)
    v: list = field(default_factory=list)
    q: list = field(default_factory=list)
    w: list = field(default_factory=list)
    pwm: list = field(default_factory=list)
    battery_V: list = field(default_factory=list)
    truth_p: list = field(default_factory=list)
    truth_v: list = field(default_factory=list)
    truth_fa: list = field(default_factory=list)
    p_d: list = field(default_factory=list)
    fa_hat: list = field(default_factory=list)
    status: list = field(default_factory=list)
    pilot_status: list = field(default_factory=list)   # ns2_pilot's status (the app's LOG ns2.status)
    # the app's LOG ns2adapt (NS2Controller): bias (g), scale, trP, label (g), term (g), status, lstatus
    adapt_bias: list = field(default_factory=list)
    adapt_scale: list = field(default_factory=list)
    adapt_trP: list = field(default_factory=list)
    adapt_label: list = field(default_factory=list)
    adapt_term: list = field(default_factory=list)
    adapt_status: list = field(default_factory=list)
    adapt_lstatus: list = field(default_factory=list)

    def arrays(self) -> dict:
        return {k: np.array(v) for k, v in self.__dict__.items()}


LEARNED = (None, "float", "fixed")


def _check_learned(learned) -> None:
    if learned not in LEARNED:
        raise ValueError(f"learned must be None, 'float' or 'fixed', got {learned!r}")


@dataclass(frozen=True)
class NS2Controller:
    """The app's code path (ns2_pilot, firmware/src): the project's controller at
    500/100 Hz with psi_2 PWM.  learned: None (the baseline, f_a = 0, as in the paper),
    "float" or "fixed": the learned term of the export's network; adapt: None (the app's
    PARAM ns2adapt at boot: off) or the on-board adaptation's parameters (an
    ns2codegen.onboard.AdaptCfg, enable 1 to fly it; docs/adaptation.md): the on-board
    label and the adaptation run in ns2_pilot as in the app (only with a learned term
    does the adapted f_a reach the controller, as ns2.enable = 0 in the app)."""
    learned: str | None = None
    adapt: AdaptCfg | None = None

    def __post_init__(self):
        _check_learned(self.learned)
        if self.adapt is not None and not (isinstance(self.adapt, AdaptCfg) and adapt_cfg_ok(self.adapt)):
            raise ValueError(f"adapt: None or an AdaptCfg within ns2_adapt.h's ranges, got {self.adapt!r}")


class LawRobot:
    """One robot's position law in a flight (what PositionLaw.bind returns): ``gains``,
    the ns2_gains_t fields it replaces in the defaults (a robot's own gains still
    override them); ``position(t)`` runs before each 100 Hz tick of the law (t: flight
    time, None while settling); ``fa_flown_g(pilot)``: the f_a,z (g) the law flies, as
    logged (pilot: the robot's ns2_pilot_t)."""
    gains: dict = {}

    def position(self, t: float | None) -> None:
        pass

    def fa_flown_g(self, pilot) -> float:
        raise NotImplementedError


class PositionLaw:
    """A controller that flies ns2_pilot with a position law of its own in C
    (NS2_FLY_LAW, host/ns2_fly.h: the pilot's prediction, attitude loop and mixing stay);
    a subclass is a frozen dataclass with ``learned`` (as NS2Controller's) and gives
    ``fly_law()``, its C (a FlyLaw: compiled into the flight kernel of every swarm with
    such a robot), and ``bind(ffi, lib, robot, veh, it)``: one robot's law, which fills
    the kernel's ns2_fly_init_t ``it`` (law, law_ctx; pwm_exact, psi1_nominal) and
    returns its LawRobot (which keeps the law's C state alive)."""
    learned: str | None = None

    def __post_init__(self):
        _check_learned(self.learned)

    def fly_law(self) -> FlyLaw:
        raise NotImplementedError

    def bind(self, ffi, lib, robot: "Robot", veh, it) -> LawRobot:
        raise NotImplementedError


@dataclass(frozen=True)
class MellingerController:
    """The firmware's controller_mellinger.c + power_distribution_quadrotor.c with the
    stock configuration's battery compensation (a Crazyflie flying the stock firmware)."""
    learned = None


Controller = NS2Controller | PositionLaw | MellingerController


@dataclass(frozen=True)
class Robot:
    """One simulated robot.  type: a robot type of the config (with vehicle.py's
    variants, e.g. "small*"); p0: its start position (m; it starts hovering there);
    controller: NS2Controller (default), a PositionLaw or MellingerController;
    gains: None (default_gains, with a position law's own: LawRobot.gains) or a dict
    of ns2_gains_t fields replacing some of them; radio_id: None (its index + 1) or its
    radio id; type_table: None (it knows its peers' true types), or the words of its
    type table (the app's PARAM ns2type.t0..t15) in which it looks each peer's type up
    by radio id, as the app does (ns2 fly --sim); battery: its supply voltage (V): a
    number (the nominal one; the rough simulator's sag applies), or ``battery(t)`` -> V
    (a real flight's logged one, ns2paper.replay; read every step, the settling reads t = 0);
    payload_g: an unmodelled payload (g): the true mass grows by it, the controller, the
    label and the network keep the vehicle's; thrust_scale: this robot's psi_1 (PWM ->
    force) times this, on top of the rough simulator's thrust scatter."""
    type: str
    p0: tuple
    controller: Controller = NS2Controller()
    gains: dict | None = None
    radio_id: int | None = None
    type_table: tuple | None = None
    battery: float | Callable = 3.9
    payload_g: float = 0.0
    thrust_scale: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.payload_g) and -100.0 < self.payload_g < 1000.0):
            raise ValueError(f"payload_g: a finite mass in (-100, 1000) g, got {self.payload_g!r}")
        if not (np.isfinite(self.thrust_scale) and 0.5 <= self.thrust_scale <= 2.0):
            raise ValueError(f"thrust_scale: in [0.5, 2], got {self.thrust_scale!r}")


def robots_of(types, positions, controller: Controller | list = NS2Controller(), gains=None, **kw) -> list[Robot]:
    """Robots of these types at these start positions, all with this controller (or one
    per robot) and gains (None, or one dict or None per robot); ``kw``: Robot's other
    fields, the same for every robot."""
    n = len(types)
    ctrls = list(controller) if isinstance(controller, (list, tuple)) else [controller] * n
    gains = list(gains) if gains is not None else [None] * n
    if len(ctrls) != n or len(gains) != n or len(positions) != n:
        raise ValueError(f"{n} robot types, {len(positions)} positions, {len(ctrls)} controllers, {len(gains)} gains")
    return [Robot(t, tuple(float(c) for c in p), c, g, **kw) for t, p, c, g in zip(types, positions, ctrls, gains)]


_KIND = {NS2Controller: "NS2_FLY_PILOT", PositionLaw: "NS2_FLY_LAW", MellingerController: "NS2_FLY_MELLINGER"}


def _kind(ctrl) -> str | None:
    """The kernel's kind (ns2_fly.h) of a controller object, None if it is none."""
    return next((k for c, k in _KIND.items() if isinstance(ctrl, c)), None)


class CLoopSwarm:
    def __init__(self, cfg: Config, robots: list[Robot], gen_dir, aero: bool = False,
                 sensing: Sensing | None = None, rough: Roughness | None = None, seed: int = 0):
        """robots: one Robot each (type, start, controller, gains, radio id, type table,
        supply); aero: ground-truth interactions (host/sim/aero.py) on or off; sensing:
        the figures of host/sim/sensing.py; rough: a real Crazyflie's unmodelled effects
        (host/sim/roughness.py; None: the clean simulator); seed: noise, biases and losses."""
        robots = list(robots)
        if not robots or not all(isinstance(r, Robot) for r in robots):
            raise ValueError("robots: a non-empty list of cloop.Robot")
        if any(_kind(r.controller) is None for r in robots):
            raise ValueError(f"controller: one of {[c.__name__ for c in _KIND]} per robot")
        self.cfg = cfg
        self.spec = robots
        self.types = types = [r.type for r in robots]
        n = len(types)
        self.type_idx = np.array([cfg.robot_types.index(base_type(t)) for t in types])
        self.vehicles = [vehicle(cfg, t) for t in types]
        self.dyn = Dynamics(self.vehicles)
        self.state = SwarmState.hover([r.p0 for r in robots], self.vehicles)
        self.aero = (calibrated(self.vehicles, vehicle(cfg, cfg.robot_types[0]),
                                **(rough.aero_kwargs(types) if rough is not None else {})) if aero else None)
        self.sensing = sensing or Sensing()
        self.rng = np.random.default_rng(seed)
        self.ffi, self.lib = load_fly(gen_dir, tuple(r.controller.fly_law() for r in robots
                                                      if isinstance(r.controller, PositionLaw)))
        ffi, lib = self.ffi, self.lib
        if n > lib.NS2_FLY_MAX_ROBOTS:
            raise ValueError(f"at most {lib.NS2_FLY_MAX_ROBOTS} robots, got {n}")
        self.robots = ffi.new("ns2_fly_robot_t[]", n)
        acc_b, acc_scale, gyro_b = self.sensing.biases(self.rng, n)
        se = self.sensing
        self.rough = rough
        thrust = rough.thrust_factors(seed, n) if rough is not None else np.ones(n)
        self.turbulence = Turbulence(rough, n, 1.0 / ATT_HZ, seed) if rough is not None else None
        self.laws: dict[int, LawRobot] = {}   # the robots flying a position law of their own
        for i, (rb, veh) in enumerate(zip(robots, self.vehicles)):
            ctrl = rb.controller
            it = ffi.new("ns2_fly_init_t *")
            it.kind = getattr(lib, _kind(ctrl))
            if isinstance(ctrl, PositionLaw):
                self.laws[i] = ctrl.bind(ffi, lib, rb, veh, it)
            it.id, it.type = rb.radio_id if rb.radio_id is not None else i + 1, int(self.type_idx[i])
            if rb.type_table is not None:
                it.use_type_table, it.type_table = 1, list(rb.type_table)
            par = np.array(self.dyn.par[i], float)
            par[0] += rb.payload_g / 1000.0     # the true mass only (ns2_sim.c par[0])
            it.par, it.p0 = list(par), list(self.state.p[i])
            it.psi1 = list(np.asarray(veh.psi1) * (thrust[i] * rb.thrust_scale))
            it.bias_acc_g, it.bias_gyro_dps, it.acc_scale = list(acc_b[i]), list(gyro_b[i]), acc_scale[i]
            sd_acc, sd_gyro = ((se.acc_sd_g, se.gyro_sd_dps) if rough is None
                               else rough.imu_sd(rb.type, se.acc_sd_g, se.gyro_sd_dps))
            it.sd_acc_g, it.sd_gyro_dps, it.ext_pos_std_m = sd_acc, sd_gyro, se.ext_pos_std_m
            fill_vehicle(it.veh, veh)
            g = default_gains(veh)
            if i in self.laws:   # and a position law's own (e.g. its attitude gains)
                g.update(self.laws[i].gains)
            g.update(rb.gains or {})
            fill_gains(it.gains, g)
            lib.ns2_pilot_default_cfg(ffi.addressof(it, "pilot_cfg"), it.type)
            it.pilot_cfg.enable = int(ctrl.learned is not None)
            it.pilot_cfg.fixed = int(ctrl.learned != "float")
            ad = getattr(ctrl, "adapt", None) or AdaptCfg(enable=0)   # the app's PARAM ns2adapt at boot
            fill_adapt_cfg(it.adapt_cfg, ad)
            lib.ns2_fly_init(ffi.addressof(self.robots, i), it)
        self.sps = np.zeros((n, 13), np.float32)      # ns2_setpoint_t: p, v, a, yaw, w
        self.est = ffi.new("float[13]")
        self._ms, self._k, self._frames = 0, 0, deque()   # where a later run() goes on from

    def _battery_V(self, t: float, k_all: int) -> np.ndarray:
        """[N] each robot's supply voltage at flight time t (step k_all since the start)."""
        return np.array([r.battery(max(t, 0.0)) if callable(r.battery)
                         else (r.battery if self.rough is None else self.rough.battery_V(k_all / ATT_HZ, r.battery))
                         for r in self.spec], float)

    def _fa_flown_g(self, i: int) -> float:
        r = self.robots[i]
        if i in self.laws:
            return self.laws[i].fa_flown_g(r.pilot)
        if not self.spec[i].controller.learned:
            return 0.0
        # the app's path flies f_a,z with the adapted term (= the network's bit for bit with it off)
        return float(r.pilot.fa_used_g if isinstance(self.spec[i].controller, NS2Controller) else r.pilot.fa_hat_g)

    def _log_adapt(self, log: FlightLog) -> None:
        """The app's LOG ns2adapt of every robot (ns2_app.c: the pilot's label and adaptation)."""
        pl = [self.robots[i].pilot for i in range(len(self.spec))]
        log.adapt_bias.append([p.adapt.theta[0] for p in pl])
        log.adapt_scale.append([p.adapt.theta[1] for p in pl])
        log.adapt_trP.append([self.lib.ns2_adapt_trace(self.ffi.addressof(p, "adapt")) for p in pl])
        log.adapt_label.append([p.label.label_g for p in pl])
        log.adapt_term.append([p.adapt.term_g for p in pl])
        log.adapt_status.append([p.adapt.status for p in pl])
        log.adapt_lstatus.append([p.label.status for p in pl])

    def _estimate(self, i: int) -> np.ndarray:
        self.lib.ns2_fly_estimate(self.ffi.addressof(self.robots, i), self.est)
        return np.frombuffer(self.ffi.buffer(self.est), np.float32).astype(float)

    def run(self, duration: float, setpoints: Callable, log_hz: int = LOG_HZ, trace_robot: int | None = None,
            settle_s: float = 2.0) -> dict:
        """Fly for ``duration`` s; ``setpoints(t, state)`` (true state) gives the Setpoints,
        read at 100 Hz.  First ``settle_s`` s (not logged) hovering at the first setpoint, as
        after a take-off: the EKF converges from its initial covariance.  trace_robot: also
        return ``trace``, the inputs and outputs of every ns2_pilot_tick of that robot
        (ns2_fly_trace_t records).  A later call goes on with the same flight (no settling;
        its clock, log times and mocap frames in flight continue): a flight flown in pieces."""
        ffi, lib, n, se = self.ffi, self.lib, len(self.types), self.sensing
        first = self._ms == 0
        settle = int(round(settle_s * ATT_HZ)) if first else 0
        steps = settle + int(round(duration * ATT_HZ))
        every_log = TICK_HZ // log_hz
        frame_every = TICK_HZ // se.mocap_hz
        log = FlightLog()
        ptr = lambda ctype, a: ffi.cast(ctype, ffi.from_buffer(a))  # noqa: E731
        x = np.ascontiguousarray(self.state.pack(), float)
        frames = self._frames
        frame = ffi.new("ns2_fly_frame_t *")
        tr_max = steps + 1
        tr = ffi.new("ns2_fly_trace_t[]", tr_max) if trace_robot is not None else ffi.NULL
        n_tr = 0
        for k in range(steps):
            ms = self._ms + k * STEP_TICKS
            t = (self._k + k - settle) / ATT_HZ
            st = SwarmState.unpack(x)
            if k == 0 and first:
                sp0 = setpoints(0.0, st)
                z = np.zeros_like(sp0.p)
                hover = Setpoints(sp0.p, z, z, sp0.yaw)
            if ms % (TICK_HZ // POS_HZ) == 0:
                sp = hover if k < settle else setpoints(t, st)
                self.sps[:, 0:3], self.sps[:, 3:6], self.sps[:, 6:9] = sp.p, sp.v, sp.a
                self.sps[:, 9], self.sps[:, 10:13] = sp.yaw, 0.0
                for law in self.laws.values():
                    law.position(t if k >= settle else None)
            if ms % frame_every == 0:  # a mocap frame of every marker, broadcast after latency_ms
                p_meas = (st.p + self.rng.normal(0.0, se.mocap_sd_m, st.p.shape)).astype(np.float32)
                rx = (self.rng.random(n) >= se.loss).astype(np.uint8)
                frames.append((ms + se.latency_ms, p_meas, rx))
            fr = ffi.NULL
            if frames and frames[0][0] < ms + STEP_TICKS:
                tick, p_meas, rx = frames.popleft()
                frame.tick, frame.p, frame.rx = tick, ptr("float *", p_meas), ptr("uint8_t *", rx)
                fr = frame
            f_a = np.zeros((n, 3)) if self.aero is None else self.aero(st.p, st.v, st.u.sum(axis=1))
            if self.turbulence is not None:
                f_a = f_a + self.turbulence.force(f_a)
            battery_V = self._battery_V(t, self._ms // STEP_TICKS + k)
            battery_f32 = battery_V.astype(np.float32)   # what the C reads (kept alive while it does)
            if k >= settle and ms % every_log == 0:
                est = np.array([self._estimate(i) for i in range(n)])
                log.t.append(t)
                log.p.append(est[:, 0:3])
                log.v.append(est[:, 3:6])
                log.q.append(est[:, 6:10])
                log.w.append(est[:, 10:13])
                log.pwm.append(np.array([list(self.robots[i].pwm) for i in range(n)]))
                log.battery_V.append(battery_V.copy())
                log.truth_p.append(st.p.copy())
                log.truth_v.append(st.v.copy())
                log.truth_fa.append(f_a.copy())
                log.p_d.append(self.sps[:, 0:3].astype(float))
                log.fa_hat.append([[0.0, 0.0, self._fa_flown_g(i) * G / 1000.0] for i in range(n)])
                log.status.append([self.robots[i].pilot.ctrl.status for i in range(n)])
                log.pilot_status.append([self.robots[i].pilot.status for i in range(n)])
                self._log_adapt(log)
            noise = self.rng.standard_normal((STEP_TICKS, n, 6), dtype=np.float32)
            fa = np.ascontiguousarray(f_a, float)
            n_tr += lib.ns2_fly_run(self.robots, n, ptr("double *", x), ptr("double *", fa),
                                    ffi.NULL, ms, STEP_TICKS,   # no aerodynamic torque
                                    ptr("float *", noise), ptr("ns2_setpoint_t *", self.sps), fr,
                                    ptr("float *", battery_f32),
                                    tr + n_tr if tr != ffi.NULL else ffi.NULL, trace_robot or 0, tr_max - n_tr)
        self.state = SwarmState.unpack(x.copy())
        self._ms += steps * STEP_TICKS
        self._k += steps - settle
        out = log.arrays()
        if trace_robot is not None:
            out["trace"] = (tr, n_tr)
        return out


def hover_setpoints(p0: np.ndarray) -> Callable:
    p0 = np.asarray(p0, float)
    z = np.zeros_like(p0)
    return lambda t, state=None: Setpoints(p0, z, z, np.zeros(len(p0)))


def figure_eight(center, ax: float = 0.5, ay: float = 0.25, period: float = 6.0) -> Callable:
    """Lemniscate x = ax sin(wt), y = ay sin(2wt) around center (single robot)."""
    c = np.asarray(center, float)
    w = 2 * np.pi / period

    def sp(t, state=None):
        p = c + [ax * np.sin(w * t), ay * np.sin(2 * w * t), 0.0]
        v = np.array([ax * w * np.cos(w * t), 2 * ay * w * np.cos(2 * w * t), 0.0])
        a = np.array([-ax * w * w * np.sin(w * t), -4 * ay * w * w * np.sin(2 * w * t), 0.0])
        return Setpoints(p[None], v[None], a[None], np.zeros(1))

    return sp
