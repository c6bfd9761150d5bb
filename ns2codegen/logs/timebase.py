"""The robots' logged samples of one flight on a common time base (RobotLog: one
robot's samples on its own clock, read from a uSD log; ``align``: every robot's
clock offset, the common grid and the usable pieces), shared by the uSD folder
reader (align.py) and the radio log reader (radiolog.py).

Clock offset of robot i (its clock minus the common clock), estimated as
  1. the timestamp of its ``SYNC_EVENT`` entry, logged when the broadcast
     synchronization packet arrives (the paper's method; all robots receive the
     broadcast within the radio latency, < 1 ms), else
  2. its take-off: the broadcast take-off command starts all motors together, so
     the offset is the time at which its mean motor PWM first crosses
     ``PWM_ON``, linearly interpolated between the two log samples around the
     crossing (error about the motors' ramp within one 10 ms log period).
The common clock is 0 at the synchronization instant.  Each robot's samples are
interpolated onto the grid k / rate_hz: linear for p, v, PWM and voltage,
normalized linear (nlerp, sign-continuous) for the quaternion; no other filtering.
A grid point is used only when every robot has log samples around it no more than
``max_gap_s`` apart, has its motors running (mean PWM > PWM_ON; a single motor
may touch 0 in a hard manoeuvre) and is above
``z_min`` (on the ground the load cell is the floor: no valid label); the flight
is cut into contiguous pieces at unusable points (pieces shorter than
``MIN_PIECE`` samples are dropped).  Neighbour sets and labels then come from
``ns2codegen.data.from_logs`` (interaction volume, five-point differentiation).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data.from_logs import Flight
from ..errors import Ns2Error
from .compressed import state_si
from .usdlog import FIXED_FREQUENCY_NAME, UsdLog

VARIABLES = {
    "p": ("stateEstimate.x", "stateEstimate.y", "stateEstimate.z"),          # m
    "v": ("stateEstimate.vx", "stateEstimate.vy", "stateEstimate.vz"),       # m/s
    "q": ("stateEstimate.qw", "stateEstimate.qx", "stateEstimate.qy", "stateEstimate.qz"),
    "pwm": ("motor.m1", "motor.m2", "motor.m3", "motor.m4"),                 # 0..PWM_FULL
    "battery_V": ("pm.vbat",),                                               # V
}
PWM_FULL = 65535.0
SYNC_EVENT = "ns2Sync"
PWM_ON = 0.05          # normalized PWM: motors running
MIN_PIECE = 20         # samples
# physical range of every logged sample: beyond it the log is corrupt and refused
# (a z of 3e38 m, an all-zero quaternion or a battery at 0 V give absurd labels)
PLAUSIBLE = {"p": (-100.0, 100.0), "v": (-50.0, 50.0), "pwm": (0.0, 1.0), "battery_V": (2.0, 5.0)}
QUAT_NORM = (0.9, 1.1)
MAX_UPSAMPLE = 20      # grid points per log sample at most (a corrupt timestamp would span ages)


class LogError(Ns2Error, ValueError):
    """Logs that cannot be turned into a flight (missing variables, no sync, ...)."""


# the same quantities in the firmware's compressed state (the uSD deck's original
# format, the Neural-Swarm2 authors' logs): decoded by ``compressed.state_si``
COMPRESSED = {"pwm": ("pwm.m1_pwm", "pwm.m2_pwm", "pwm.m3_pwm", "pwm.m4_pwm"), "battery_mV": ("pm.vbatMV",)}
ONBOARD_FA = "ctrlFa.Faz"   # the on-board network's f_a,z (g) used in flight, when logged


@dataclass
class RobotLog:
    """One robot's fixed-frequency samples on its own clock (s)."""
    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    q: np.ndarray
    pwm: np.ndarray        # normalized 0..1
    battery_V: np.ndarray
    sync_s: float | None   # time of the first sync event on its clock, if logged
    setpoint_v: np.ndarray | None = None   # [T, 3] m/s, the commanded velocity, if logged
    fa_onboard_g: np.ndarray | None = None  # [T] the on-board prediction, if logged
    setpoint_p: np.ndarray | None = None    # [T, 3] m, the position setpoint, if logged
    w: np.ndarray | None = None             # [T, 3] rad/s, body rates (the filtered gyro), if logged

    @staticmethod
    def from_usd(log: UsdLog, sync_event: str = SYNC_EVENT) -> "RobotLog":
        ev = log.event(FIXED_FREQUENCY_NAME)
        compressed = "stateEstimateZ.quat" in ev
        need = [n for names in (COMPRESSED.values() if compressed else VARIABLES.values()) for n in names]
        if compressed:
            need += [f"stateEstimateZ.{n}" for n in ("x", "y", "z", "vx", "vy", "vz")]
        missing = [n for n in need if n not in ev]
        if missing:
            raise LogError(f"the fixedFrequency event lacks the variables {missing}")
        t = ev["timestamp_us"].astype(np.float64) * 1e-6
        if len(t) < MIN_PIECE:
            raise LogError(f"only {len(t)} fixedFrequency samples")
        order = np.argsort(t, kind="stable")
        if np.any(np.diff(t[order]) <= 0):
            raise LogError("repeated timestamps in the fixedFrequency event")
        ev = {k: np.asarray(a)[order] for k, a in ev.items()}
        names = dict(VARIABLES)
        if compressed:
            cols = state_si(ev)
            cols["pwm"] = np.stack([ev[n] for n in COMPRESSED["pwm"]], 1)
            cols["battery_V"] = ev[COMPRESSED["battery_mV"][0]][:, None] * 1e-3
            names = dict(p="stateEstimateZ.x/y/z", v="stateEstimateZ.vx/vy/vz", q="stateEstimateZ.quat",
                         pwm=COMPRESSED["pwm"], battery_V=COMPRESSED["battery_mV"])
        else:
            cols = {k: np.stack([ev[n] for n in nm], 1) for k, nm in VARIABLES.items()}
        cols["pwm"] = cols["pwm"] / PWM_FULL
        for key, (lo, hi) in PLAUSIBLE.items():
            bad = np.flatnonzero(~np.all((cols[key] >= lo) & (cols[key] <= hi), axis=1))
            if len(bad):
                k = bad[0]
                raise LogError(f"{names[key]} of sample {int(order[k])} is {cols[key][k].tolist()}, outside the "
                               f"physical range [{lo:g}, {hi:g}] ({len(bad)} such samples): corrupt log")
        qn = np.linalg.norm(cols["q"], axis=1)
        bad = np.flatnonzero(~((qn >= QUAT_NORM[0]) & (qn <= QUAT_NORM[1])))
        if len(bad):
            k = bad[0]
            raise LogError(f"{names['q']} of sample {int(order[k])} has norm {qn[k]:.3g}, not a unit "
                           f"quaternion ({len(bad)} such samples): corrupt log")
        sync = log.events.get(sync_event, {}).get("timestamp_us")
        return RobotLog(t[order], cols["p"], cols["v"], cols["q"], cols["pwm"], cols["battery_V"][:, 0],
                        float(sync[0]) * 1e-6 if sync is not None and len(sync) else None,
                        cols.get("setpoint_v"), ev[ONBOARD_FA] if ONBOARD_FA in ev else None,
                        cols.get("setpoint_p"), cols.get("w"))

    def takeoff_s(self) -> float:
        """Time at which the mean PWM first rises through PWM_ON (interpolated)."""
        m = self.pwm.mean(axis=1)
        up = np.flatnonzero((m[:-1] < PWM_ON) & (m[1:] >= PWM_ON))
        if not len(up):
            raise LogError("no motor start in the log (and no sync event): cannot synchronize its clock")
        k = up[0]
        return float(self.t[k] + (PWM_ON - m[k]) / (m[k + 1] - m[k]) * (self.t[k + 1] - self.t[k]))

    def setpoint_events(self) -> np.ndarray:
        """Times (own clock, s) where the commanded horizontal speed of each movement
        crosses half its peak, rising and falling, linearly interpolated (a movement
        that runs to the end of the log: its onset, to within half a log period):
        the instants of a broadcast trajectory start as every robot saw them."""
        if self.setpoint_v is None:
            return np.zeros(0)
        s = np.hypot(self.setpoint_v[:, 0], self.setpoint_v[:, 1])
        edges = np.flatnonzero(np.diff(np.concatenate([[0], (s > 0).astype(np.int8), [0]])))
        out = []
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < EVENT_MIN_SAMPLES or a == 0:
                continue   # too short, or cut by the log's start
            if b == len(s):   # runs to the end of the log (a random walk): its onset only,
                ok = self.t[a] - self.t[a - 1] <= EVENT_MAX_GAP_S   # midway between the samples around it
                out.append(0.5 * (self.t[a - 1] + self.t[a]) if ok else np.nan)
                continue
            half = 0.5 * s[a:b].max()
            seg, tt = s[a - 1:b + 1], self.t[a - 1:b + 1]
            up = np.flatnonzero((seg[:-1] < half) & (seg[1:] >= half))[0]
            dn = np.flatnonzero((seg[:-1] >= half) & (seg[1:] < half))[-1]
            for k in (up, dn):
                if tt[k + 1] - tt[k] <= EVENT_MAX_GAP_S:   # a log gap would blur the instant
                    out.append(tt[k] + (half - seg[k]) / (seg[k + 1] - seg[k]) * (tt[k + 1] - tt[k]))
                else:
                    out.append(np.nan)
        return np.array(out)


EVENT_MIN_SAMPLES = 5      # a movement shorter than 50 ms is no trajectory
MIN_EVENTS = 4             # fewer common setpoint events are no evidence of a broadcast trajectory
LOG_START_MAX_S = 0.05     # a clock whose first sample is this early counts from the log's start
EVENT_MAX_GAP_S = 0.015    # the log samples around an event instant at most this far apart


def clock_offsets(robots: list[RobotLog]) -> tuple[np.ndarray, str, dict]:
    """Offsets (s) of the robots' clocks from the common clock, the method used and
    its measured error (module docstring): the sync event; else the broadcast
    setpoint events every robot logged (each robot's offset is the median of its
    event times minus the flight's mean event times; the error is the residual);
    else the take-off."""
    if all(r.sync_s is not None for r in robots):
        return np.array([r.sync_s for r in robots]), "sync event", {}
    if any(r.sync_s is not None for r in robots):
        raise LogError("only some robots logged the sync event: fix the logging config of the others")
    if len(robots) == 1:
        return np.zeros(1), "single robot", {}
    events = [r.setpoint_events() for r in robots]
    if len(events[0]) >= MIN_EVENTS and all(len(e) == len(events[0]) for e in events):
        E = np.array(events)                                   # [robots, events]
        ok = np.all(np.isfinite(E), axis=0)
        if ok.any():
            E = E[:, ok]
            rel = E - E.mean(axis=0)
            off = np.median(rel, axis=1)
            off -= off.mean()
            resid = rel - off[:, None]
            err = {"events": int(E.shape[1]), "residual_rms_ms": float(np.sqrt(np.mean(resid ** 2)) * 1e3),
                   "residual_max_ms": float(np.abs(resid).max() * 1e3),
                   "raw_max_ms": float(np.abs(rel).max() * 1e3)}
            return off, "setpoint events", err
    if all(r.t[0] <= LOG_START_MAX_S for r in robots):
        # every clock counts from its log's start, which one broadcast started
        return np.zeros(len(robots)), "log start", {}
    return np.array([r.takeoff_s() for r in robots]), "take-off", {}


def _unwrap_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs so that consecutive quaternions lie in the same hemisphere."""
    flip = np.concatenate([[False], np.einsum("ij,ij->i", q[1:], q[:-1]) < 0])
    return q * np.where(np.logical_xor.accumulate(flip), -1.0, 1.0)[:, None]


def resample(r: RobotLog, t_own: np.ndarray, max_gap_s: float) -> tuple[dict, np.ndarray]:
    """Interpolate one robot's samples at its own clock times ``t_own``; returns the
    arrays and the mask of times with log samples around them at most max_gap_s apart."""
    k = np.clip(np.searchsorted(r.t, t_own, side="right"), 1, len(r.t) - 1)
    ok = (t_own >= r.t[0]) & (t_own <= r.t[-1]) & (r.t[k] - r.t[k - 1] <= max_gap_s)
    lerp = lambda x: np.stack([np.interp(t_own, r.t, c) for c in np.atleast_2d(x.T)], 1)  # noqa: E731
    q = lerp(_unwrap_quaternions(r.q))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {"p": lerp(r.p), "v": lerp(r.v), "q": q, "pwm": lerp(r.pwm), "battery_V": lerp(r.battery_V)[:, 0]}, ok


TOUCH_MARGIN_M = 0.01   # z at most this far above the robot's ground plane: on (or hitting) the floor
IMPACT_MPS2 = 30.0      # |dv/dt| of the logged velocity beyond 3 g: a collision or a crash
CUT_PAD_S = 0.3         # cut this long around a ground touch or impact (the transient before and after)


def _cut_reasons(x: dict, ok: np.ndarray, ground_z: float | None, z_min: float, rate_hz: float) -> dict:
    """Unusable grid points of one robot, by reason (masks over the grid)."""
    z = x["p"][:, 2]
    if ground_z is None:   # no ground plane given: only "on the ground" (z <= z_min), unpadded
        touch, low = np.zeros(len(z), bool), z <= z_min
    else:
        touch, low = z <= ground_z + TOUCH_MARGIN_M, np.zeros(len(z), bool)
    dv = np.zeros(len(z))
    if len(z) > 1:
        dv[1:] = np.linalg.norm(np.diff(x["v"], axis=0), axis=1) * rate_hz
        dv[:-1] = np.maximum(dv[:-1], dv[1:])
    impact = dv > IMPACT_MPS2
    pad = int(round(CUT_PAD_S * rate_hz))
    if pad and len(z):
        kernel = np.ones(2 * pad + 1)
        touch = np.convolve(touch, kernel, "same") > 0
        impact = np.convolve(impact, kernel, "same") > 0
    return {"log gap": ~ok, "motors off": x["pwm"].mean(axis=1) <= PWM_ON, "ground touch": touch,
            "on the ground": low, "impact": impact}


def align(types: list[str], robots: list[RobotLog], rate_hz: float = 100.0, max_gap_s: float = 0.05,
          z_min: float = 0.02, ground_z: list[float | None] | None = None, labelled: list[bool] | None = None,
          name: str = "", ids: list[str] | None = None) -> tuple[list[Flight], dict]:
    """Common time base, usable pieces (see the module docstring); returns the
    Flights and a report (offsets, method, alignment error, what was cut and why).
    ``ground_z``: each robot's ground plane (z standing on the floor; None: z_min)."""
    offsets, method, err = clock_offsets(robots)
    start = max(r.t[0] - o for r, o in zip(robots, offsets))
    end = min(r.t[-1] - o for r, o in zip(robots, offsets))
    if end <= start:
        raise LogError("the robots' logs do not overlap in time after synchronization")
    n_grid = (end - start) * rate_hz
    if n_grid > MAX_UPSAMPLE * max(len(r.t) for r in robots):
        raise LogError(f"the logs span {end - start:.6g} s for at most {max(len(r.t) for r in robots)} samples "
                       f"(a corrupt timestamp?): {n_grid:.3g} grid points at {rate_hz:g} Hz")
    grid = np.arange(np.ceil(start * rate_hz - 1e-6), np.floor(end * rate_hz + 1e-6) + 1) / rate_hz
    ground_z = ground_z or [None] * len(robots)
    ids = ids or [str(k) for k in range(len(robots))]
    res, usable, cuts = [], np.ones(len(grid), bool), {}
    for r, o, gz, rid in zip(robots, offsets, ground_z, ids):
        x, ok = resample(r, grid + o, max_gap_s)
        x["fa_onboard_g"] = (np.interp(grid + o, r.t, r.fa_onboard_g) if r.fa_onboard_g is not None
                             else np.full(len(grid), np.nan))
        for key, col in (("p_d", r.setpoint_p), ("w", r.w)):
            x[key] = (np.stack([np.interp(grid + o, r.t, c) for c in col.T], 1) if col is not None
                      else np.full((len(grid), 3), np.nan))
        res.append(x)
        for reason, mask in _cut_reasons(x, ok, gz, z_min, rate_hz).items():
            usable &= ~mask
            if mask.any():
                cuts.setdefault(reason, {})[rid] = round(float(mask.sum()) / rate_hz, 2)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], usable.astype(np.int8), [0]])))
    flights = []
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < MIN_PIECE:
            continue
        st = {k: np.stack([x[k][a:b] for x in res], 1) for k in res[0]}
        flights.append(Flight(list(types), grid[a:b], st["p"], st["v"], st["q"], st["pwm"], st["battery_V"],
                              labelled=list(labelled) if labelled is not None else None,
                              fa_onboard_g=st["fa_onboard_g"], name=name, p_d=st["p_d"],
                              robots=list(ids), w=st["w"] if np.isfinite(st["w"]).any() else None))
    report = {"clock_offsets_s": offsets.tolist(), "sync": method, "alignment_error": err,
              "grid_samples": int(len(grid)), "duration_s": round(float(len(grid)) / rate_hz, 2),
              "used_samples": int(sum(len(f.t) for f in flights)), "pieces": len(flights),
              "cut_s_by_reason_and_robot": cuts}
    return flights, report
