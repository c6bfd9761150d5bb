"""The controller that flew the paper's real flights in the simulator: ns2_pilot with
the authors' position law (paper/c/ctrl_authors.c, a position law of the simulator's
kernel: ns2host.sim.cloop.PositionLaw), its motor forces realized through the exact
inverse of psi_1 (gains.AUTHORS_PWM_EXACT), its gains the authors' (gains.py)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ns2host.cfhost import FlyLaw
from ns2host.sim.cloop import LawRobot, PositionLaw

from .gains import AUTHORS_PWM_EXACT, authors_gains

C_DIR = Path(__file__).resolve().parent / "c"
AUTHORS_LAW = FlyLaw(sources=(C_DIR / "ctrl_authors.c",), header=C_DIR / "ctrl_authors.h", cdef="""
typedef struct { float mass_kg; float kp[3]; float kd[3]; float ki[3]; float i_max; float k_fa; } ns2_authors_gains_t;
typedef struct { ns2_authors_gains_t g; float i_e[3]; uint32_t fa_given; float fa_given_g; } ns2_authors_t;
void ns2_authors_init(ns2_authors_t *a, const ns2_authors_gains_t *g);
void ns2_authors_law(void *ctx, ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, float dt);
""", function="ns2_authors_law")


@dataclass(frozen=True)
class AuthorsController(PositionLaw):
    """ns2_pilot with the position law of the controller that flew the real flights.
    gains: None (gains.authors_gains of the robot's type) or a dict of
    ns2_authors_gains_t, with its attitude gains under "att"; learned: as
    NS2Controller's; given: None, or ``given(t)`` -> the f_a,z-hat (g) the robot flies
    instead of its network's (read at 100 Hz: a real flight's logged prediction,
    ns2paper.replay; 0 while settling)."""
    gains: dict | None = None
    learned: str | None = None
    given: Callable | None = None

    def fly_law(self) -> FlyLaw:
        return AUTHORS_LAW

    def bind(self, ffi, lib, robot, veh, it) -> LawRobot:
        a = self.gains or authors_gains(robot.type)
        g = ffi.new("ns2_authors_gains_t *")
        g.mass_kg, g.i_max, g.k_fa = a["mass_kg"], a["i_max"], a.get("k_fa", 1.0)
        g.kp, g.kd, g.ki = list(a["kp"]), list(a["kd"]), list(a["ki"])
        ctx = ffi.new("ns2_authors_t *")
        lib.ns2_authors_init(ctx, g)
        it.law, it.law_ctx = ffi.cast("ns2_fly_law_fn", ffi.addressof(lib, AUTHORS_LAW.function)), ctx
        it.pwm_exact, it.psi1_nominal = int(AUTHORS_PWM_EXACT), list(veh.psi1)
        return _AuthorsRobot(ctx, self.given, self.learned, dict(a.get("att", {})))


class _AuthorsRobot(LawRobot):
    """One robot's authors' law: its C state (ns2_authors_t), the given prediction."""

    def __init__(self, ctx, given: Callable | None, learned: str | None, gains: dict):
        self.ctx, self.given, self.learned, self.gains = ctx, given, learned, gains

    def position(self, t: float | None) -> None:
        if self.given is not None:
            self.ctx.fa_given, self.ctx.fa_given_g = 1, float(self.given(t)) if t is not None else 0.0

    def fa_flown_g(self, pilot) -> float:
        if self.ctx.fa_given:
            return float(self.ctx.fa_given_g)
        return float(pilot.fa_hat_g) if self.learned else 0.0
