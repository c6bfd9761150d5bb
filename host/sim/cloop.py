"""C-in-the-loop: every robot runs its own instance of the firmware controller
(firmware/src/ns2_controller.c, built for the host) at the Crazyflie's rates,
attitude 500 Hz and position 100 Hz, and predicts f_a from its own neighbour set
with the firmware inference (float or fixed point) when the learned term is on
(the baseline sets it to zero, as in the paper)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ns2codegen.config import Config

from ..cbuild import CModel
from .aero import calibrated
from .dynamics import Dynamics, SwarmState
from .vehicle import G, Vehicle, vehicle

ATT_HZ, POS_HZ = 500, 100


def default_gains(veh: Vehicle) -> dict:
    """Gains scaled with mass and inertia (tuned in the simulator)."""
    J = veh.inertia
    return {"Lp": [2.0, 2.0, 2.5], "Kv": [4.0 * veh.mass] * 3, "Gv": [1.5] * 3,
            "Lq": [18.0, 18.0, 8.0], "Kw": list(40.0 * J), "Gw": list(20.0 * J),
            "Kwd": list(40.0 * J / veh.lam), "int_v_max": 0.5, "int_w_max": 1.0,
            "fa_max_N": 0.3 * veh.mass * G, "min_thrust_N": 0.1 * veh.mass * G, "d_filter": 0.5}


@dataclass
class Setpoints:
    """Desired p, v, a [N, 3] and yaw [N] at a time."""
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    yaw: np.ndarray


@dataclass
class Log:
    t: list = field(default_factory=list)
    p: list = field(default_factory=list)
    v: list = field(default_factory=list)
    p_d: list = field(default_factory=list)
    fa_true: list = field(default_factory=list)
    fa_hat: list = field(default_factory=list)
    pwm: list = field(default_factory=list)
    status: list = field(default_factory=list)

    def arrays(self) -> dict:
        return {k: np.array(v) for k, v in self.__dict__.items()}


class CLoopSwarm:
    def __init__(self, cfg: Config, types: list[str], gen_dir, positions, learned: str | None = None,
                 aero: bool = False, battery_V: float = 3.9, substeps: int = 2):
        """learned: None (baseline, f_a = 0), "float" or "fixed"; aero: ground-truth
        interactions (host/sim/aero.py) on or off."""
        self.cfg = cfg
        self.types = types
        self.type_idx = np.array([cfg.robot_types.index(t) for t in types])
        self.vehicles = [vehicle(cfg, t) for t in types]
        self.dyn = Dynamics(self.vehicles)
        self.state = SwarmState.hover(positions, self.vehicles)
        self.c = CModel(gen_dir)
        self.learned = learned
        self.aero = calibrated(self.vehicles, vehicle(cfg, cfg.robot_types[0])) if aero else None
        self.battery_V = battery_V
        self.substeps = substeps
        ffi, lib = self.c.ffi, self.c.lib
        self.ctrl = []
        for veh in self.vehicles:
            v = ffi.new("ns2_vehicle_t *")
            v.mass_kg, v.inertia, v.arm_m, v.kappa_m = veh.mass, list(veh.inertia), veh.arm, veh.kappa
            setattr(v, "lambda", veh.lam)  # 'lambda' is a Python keyword
            v.f_max_N, v.psi2 = veh.f_max, list(veh.psi2)
            g = ffi.new("ns2_gains_t *")
            for k, val in default_gains(veh).items():
                setattr(g, k, val)
            c = ffi.new("ns2_ctrl_t *")
            lib.ns2_ctrl_init(c, v, g)
            self.ctrl.append(c)
        self.cs = ffi.new("ns2_ctrl_state_t *")
        self.sp = ffi.new("ns2_setpoint_t *")
        self.fa = ffi.new("float[3]")
        self.fa_hat = np.zeros((len(types), 3))

    def _load_state(self, i: int) -> None:
        st, cs = self.state, self.cs
        cs.p, cs.v, cs.q, cs.w = list(st.p[i]), list(st.v[i]), list(st.q[i]), list(st.w[i])

    def _predict(self) -> None:
        """Each robot predicts f_a,z from its own neighbour set (decentralized)."""
        st, n = self.state, len(self.types)
        if self.learned is None:
            self.fa_hat[:] = 0.0
            return
        from ns2codegen.queries import Queries

        rel = np.concatenate([st.p[None, :, :] - st.p[:, None, :], st.v[None, :, :] - st.v[:, None, :]], axis=2)
        order = np.argsort(np.linalg.norm(rel[..., :3], axis=2), axis=1)[:, 1:]  # nearest first, not itself
        q = Queries(self.type_idx.astype(np.uint8), st.p.astype(np.float32), st.v.astype(np.float32),
                    np.full(n, n - 1), self.type_idx[order].astype(np.uint8),
                    np.take_along_axis(rel, order[..., None], 1).astype(np.float32))
        out, _ = self.c.predict(q, fixed=self.learned == "fixed")
        scale = 2.0 ** -self.c.lib.NS2_Q_OUT_FRAC if self.learned == "fixed" else 1.0
        self.fa_hat[:, 2] = out.astype(float) * scale * G / 1000.0  # grams -> N

    def run(self, duration: float, setpoints: Callable[[float], Setpoints], log_every: int = 5) -> dict:
        lib, n = self.c.lib, len(self.types)
        dt = 1.0 / ATT_HZ
        steps = int(round(duration * ATT_HZ))
        log = Log()
        for k in range(steps):
            t = k * dt
            if k % (ATT_HZ // POS_HZ) == 0:
                self._predict()
                sp = setpoints(t)
                for i in range(n):
                    self._load_state(i)
                    self.sp.p, self.sp.v, self.sp.a = list(sp.p[i]), list(sp.v[i]), list(sp.a[i])
                    self.sp.yaw, self.sp.w = float(sp.yaw[i]), [0.0, 0.0, 0.0]
                    self.fa[0:3] = list(self.fa_hat[i])
                    lib.ns2_ctrl_position(self.ctrl[i], self.cs, self.sp, self.fa, 1.0 / POS_HZ)
            pwm = np.zeros((n, 4))
            for i in range(n):
                self._load_state(i)
                lib.ns2_ctrl_attitude(self.ctrl[i], self.cs, dt, self.battery_V)
                pwm[i] = list(self.ctrl[i].pwm)
            u_c = np.array([veh.force_from_pwm(pwm[i], self.battery_V) for i, veh in enumerate(self.vehicles)])
            st = self.state
            f_a = self.aero(st.p, st.v, st.u.sum(axis=1)) if self.aero else np.zeros((n, 3))
            for _ in range(self.substeps):
                self.state = self.dyn.step(self.state, u_c, dt / self.substeps, f_a=f_a)
            if k % log_every == 0:
                log.t.append(t)
                log.p.append(self.state.p.copy())
                log.v.append(self.state.v.copy())
                log.p_d.append(setpoints(t).p.copy())
                log.fa_true.append(f_a.copy())
                log.fa_hat.append(self.fa_hat.copy())
                log.pwm.append(pwm)
                log.status.append([c.status for c in self.ctrl])
        return log.arrays()


def hover_setpoints(p0: np.ndarray) -> Callable[[float], Setpoints]:
    p0 = np.asarray(p0, float)
    z = np.zeros_like(p0)
    return lambda t: Setpoints(p0, z, z, np.zeros(len(p0)))


def figure_eight(center, ax: float = 0.5, ay: float = 0.25, period: float = 6.0) -> Callable[[float], Setpoints]:
    """Lemniscate x = ax sin(wt), y = ay sin(2wt) around center (single robot)."""
    c = np.asarray(center, float)
    w = 2 * np.pi / period

    def sp(t):
        p = c + [ax * np.sin(w * t), ay * np.sin(2 * w * t), 0.0]
        v = np.array([ax * w * np.cos(w * t), 2 * ay * w * np.cos(2 * w * t), 0.0])
        a = np.array([-ax * w * w * np.sin(w * t), -4 * ay * w * w * np.sin(2 * w * t), 0.0])
        return Setpoints(p[None], v[None], a[None], np.zeros(1))

    return sp
