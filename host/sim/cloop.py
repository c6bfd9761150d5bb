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
from ns2codegen.data.labels import psi1_newtons

from ..cbuild import CModel
from .aero import calibrated
from .dynamics import Dynamics, SwarmState
from .vehicle import G, base_type, vehicle

ATT_HZ, POS_HZ = 500, 100


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
    """What the drones log (t, p, v, q, w, pwm, battery; [T, N, ...]) plus, kept
    apart, the simulator's ground truth (f_a) and the setpoints, for evaluation only."""
    t: list = field(default_factory=list)
    p: list = field(default_factory=list)
    v: list = field(default_factory=list)
    q: list = field(default_factory=list)
    w: list = field(default_factory=list)
    pwm: list = field(default_factory=list)
    battery_V: list = field(default_factory=list)
    truth_fa: list = field(default_factory=list)
    p_d: list = field(default_factory=list)
    fa_hat: list = field(default_factory=list)
    status: list = field(default_factory=list)

    def arrays(self) -> dict:
        return {k: np.array(v) for k, v in self.__dict__.items()}


class CLoopSwarm:
    def __init__(self, cfg: Config, types: list[str], gen_dir, positions, learned: str | None = None,
                 aero: bool = False, battery_V: float = 3.9, substeps: int = 1):
        """learned: None (baseline, f_a = 0), "float" or "fixed"; aero: ground-truth
        interactions (host/sim/aero.py) on or off."""
        self.cfg = cfg
        self.types = types
        self.type_idx = np.array([cfg.robot_types.index(base_type(t)) for t in types])
        self.vehicles = [vehicle(cfg, t) for t in types]
        self.dyn = Dynamics(self.vehicles)
        self.state = SwarmState.hover(positions, self.vehicles)
        self.c = CModel(gen_dir)
        self.learned = learned
        self.aero = calibrated(self.vehicles, vehicle(cfg, cfg.robot_types[0])) if aero else None
        self.battery_V = battery_V
        self.substeps = substeps
        ffi, lib = self.c.ffi, self.c.lib
        n = len(types)
        self.ctrl = self.c.controller(self.vehicles)
        assert ffi.sizeof("ns2_ctrl_state_t") == 13 * 4 and ffi.sizeof("ns2_setpoint_t") == 13 * 4
        self.states = np.zeros((n, 13), np.float32)   # ns2_ctrl_state_t: p, v, q, w
        self.sps = np.zeros((n, 13), np.float32)      # ns2_setpoint_t: p, v, a, yaw, w
        self.fa_hat = np.zeros((n, 3))
        self.pwm = np.zeros((n, 4), np.float32)
        self._psi1 = np.array([veh.psi1 for veh in self.vehicles])

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

    def run(self, duration: float, setpoints: Callable, log_hz: int = LOG_HZ) -> dict:
        """Fly for ``duration`` s; ``setpoints(t, state)`` gives the Setpoints."""
        ffi, lib, n = self.c.ffi, self.c.lib, len(self.types)
        dt = 1.0 / ATT_HZ
        steps = int(round(duration * ATT_HZ))
        every = ATT_HZ // POS_HZ
        log = FlightLog()
        ptr = lambda ctype, a: ffi.cast(ctype, ffi.from_buffer(a))  # noqa: E731
        fa32 = np.zeros((n, 3), np.float32)
        for k in range(steps):
            t = k * dt
            st = self.state
            self.states[:] = np.concatenate([st.p, st.v, st.q, st.w], axis=1)
            do_pos = k % every == 0
            if do_pos:
                self._predict()
                sp = setpoints(t, st)
                self.sps[:, 0:3], self.sps[:, 3:6], self.sps[:, 6:9] = sp.p, sp.v, sp.a
                self.sps[:, 9], self.sps[:, 10:13] = sp.yaw, 0.0
                fa32[:] = self.fa_hat
            lib.ns2_host_ctrl_tick(self.ctrl, n, ptr("ns2_ctrl_state_t *", self.states),
                                   ptr("ns2_setpoint_t *", self.sps),
                                   ptr("float *", fa32) if self.learned else ffi.NULL, int(do_pos),
                                   1.0 / POS_HZ, dt, self.battery_V, ptr("float *", self.pwm))
            u_c = psi1_newtons(self._psi1, self.pwm, np.full(n, self.battery_V))
            f_a = self.aero(st.p, st.v, st.u.sum(axis=1)) if self.aero else np.zeros((n, 3))
            if k % (ATT_HZ // log_hz) == 0:
                log.t.append(t)
                log.p.append(st.p.copy())
                log.v.append(st.v.copy())
                log.q.append(st.q.copy())
                log.w.append(st.w.copy())
                log.pwm.append(self.pwm.astype(float))
                log.battery_V.append(np.full(n, self.battery_V))
                log.truth_fa.append(f_a.copy())
                log.p_d.append(self.sps[:, 0:3].astype(float))
                log.fa_hat.append(self.fa_hat.copy())
                log.status.append([self.ctrl[i].status for i in range(n)])
            for _ in range(self.substeps):
                self.state = self.dyn.step(self.state, u_c, dt / self.substeps, f_a=f_a)
        return log.arrays()


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
