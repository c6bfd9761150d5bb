"""The on-board adaptation judged in flight, in the simulator (issue 53 item 5).

Every robot flies the app's code path (host/ns2_fly.c: ns2_pilot with the on-board
label and the adaptation of firmware/src, as ns2_app.c runs them) in the simulator
given (the rough one by default: per-robot thrust scatter Roughness.thrust_sd, battery
sag, turbulence, the calibrated wakes), with one robot carrying an unmodelled payload
(PAYLOAD_G: its true mass grows, the controller, the label and the network keep the
vehicle's).  Controllers (CONTROLLERS):

  BL-tuned   the project's controller with the tuned gains, f_a = 0
  NN         the same gains with the learned f_a (swarm.py's NN)
  NN+adapt   NN with the on-board adaptation on (PARAM ns2adapt.enable = 1, the other
             parameters the app's defaults)
  NN+composite G   (on request, ``track_gains``) NN+adapt with Neural-Fly's composite law:
             ns2adapt.trackGain = G (the controller's tracking error in z also moves theta)

Experiments: the paper's swaps (swarm.SWAP_CASES, the payload on the bottom robot, the
paper's metric: the bottom robot's worst z error per swap, the median over swaps and
seeds), the rings (swarm.RING_CASES, the payload on the first small robot: its worst z
error and the small robots' median), and a battery flown to the firmware's low-voltage
limit (S2S swaps for Roughness.flight_limit_s at the fitted sag, no payload: the worst z
error per swap over the first and the last minute, the adaptation's bias along the
flight).  Each flight is one job of ns2codegen.executor.run_map."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ns2codegen.config import Config
from ns2codegen.executor import run_map
from ns2codegen.export import export_config
from ns2codegen.fileio import atomic_write_bytes
from ns2codegen.onboard import ADAPT_UPDATED, AdaptCfg
from ns2codegen.results import stamp

from ns2host.sim.cloop import CLoopSwarm, NS2Controller, Setpoints, robots_of
from ns2host.sim.roughness import LOW_BATTERY_V, Roughness
from ns2host.sim.vehicle import base_type, vehicle

from .swarm import (RING_CASES, RING_DURATION_S, REST_S, SWAP_CASES, SWAP_S, bottom_worst_z, ring_flight,
                    ring_worst_z, swap_flight, tuned)

CONTROLLERS = ("BL-tuned", "NN", "NN+adapt")
COMPOSITE = "NN+composite"      # + " <trackGain>": NN+adapt with the composite law's tracking term
PAYLOAD_G = 3.0
SEEDS = (0, 1, 2)
SWAP_KINDS = ("swap", "swap-solo")
# swap-solo: before the swaps the bottom robot hovers SOLO_S alone (the others ASIDE_M aside in
# x, out of its interaction volume: the adaptation may learn), then they come in over MOVE_S
SOLO_S, MOVE_S, ASIDE_M = 4.0, 2.0, 1.0
BATTERY_CASE, BATTERY_S = "S2S", 60.0
BATTERY_WINDOW_S = 15.0   # the first and the last 15 s of the battery flight are compared


def composite(track_gain: float) -> str:
    """The name of the composite law's arm with ns2adapt.trackGain = ``track_gain``."""
    return f"{COMPOSITE} {track_gain:g}"


def _adapt_cfg(controller: str) -> AdaptCfg | None:
    """PARAM ns2adapt of a controller's robots (None: off, as the app boots)."""
    if controller == "NN+adapt":
        return AdaptCfg(enable=1)
    if controller.startswith(COMPOSITE + " "):
        return AdaptCfg(enable=1, track_gain=float(controller[len(COMPOSITE) + 1:]))
    return None


def _robots(cfg: Config, team, start, controller: str, tuning: dict, learned: str, payload_at: int | None,
            payload_g: float, **kw):
    adapt = _adapt_cfg(controller)
    ctrl = NS2Controller(None if controller == "BL-tuned" else learned, adapt)
    robots = robots_of(list(team), start, ctrl, [tuned(vehicle(cfg, t), tuning) for t in team], **kw)
    if payload_at is not None:
        robots[payload_at] = dataclasses.replace(robots[payload_at], payload_g=payload_g)
    return robots


def solo_first(start, sp):
    """(start positions, setpoints, seconds before the swaps): the bottom robot hovers alone
    SOLO_S with the others ASIDE_M aside in x, they come in over MOVE_S (cosine), then the
    swaps ``sp``."""
    start = np.asarray(start, float)
    aside = start.copy()
    aside[1:, 0] += ASIDE_M
    pre = SOLO_S + MOVE_S

    def f(t, state=None):
        if t >= pre:
            return sp(t - pre, state)
        s = min(max((t - SOLO_S) / MOVE_S, 0.0), 1.0)
        ds = 0.5 * np.pi / MOVE_S * np.sin(np.pi * s) if 0.0 < s < 1.0 else 0.0
        a = 0.5 * (1.0 - np.cos(np.pi * s))
        return Setpoints(aside + a * (start - aside), ds * (start - aside), np.zeros_like(start), np.zeros(len(start)))

    return aside, f, pre


def _after(log: dict, t0: float) -> dict:
    """The log from flight time t0 on, its clock starting there."""
    k = log["t"] >= t0 - 1e-9
    return {**{key: v[k] for key, v in log.items() if isinstance(v, np.ndarray) and len(v) == len(k)},
            "t": log["t"][k] - t0}


def _updated_share(log: dict, robot: int) -> float:
    """The share of the logged ticks on which the robot's adaptation updated (ADAPT_UPDATED)."""
    return float(np.mean((log["adapt_status"][:, robot] & ADAPT_UPDATED) != 0))


def _adapt_trace(log: dict, robot: int, every_s: float) -> dict:
    """The robot's logged ns2adapt bias and label every ``every_s`` s (the app's LOG ns2adapt)."""
    k = np.arange(0, len(log["t"]), max(int(round(every_s / (log["t"][1] - log["t"][0]))), 1))
    return {"t_s": [float(x) for x in log["t"][k]], "bias_g": [float(x) for x in log["adapt_bias"][k, robot]],
            "label_g": [float(x) for x in log["adapt_label"][k, robot]]}


def fly(job: dict) -> dict:
    """One flight (a run_map job): job = {kind: swap | ring | battery, case, controller,
    seed, gen_dir, tuning, learned, rough (Roughness or None), swaps, payload_g}."""
    cfg = export_config(job["gen_dir"])
    kind, ctrl, seed, rough = job["kind"], job["controller"], job["seed"], job["rough"]
    if kind == "ring":
        team, start, sp = ring_flight(RING_CASES[job["case"]])
        small = [i for i, t in enumerate(team) if base_type(t) == "small"]
        robots = _robots(cfg, team, start, ctrl, job["tuning"], job["learned"], small[0], job["payload_g"])
        log = CLoopSwarm(cfg, robots, job["gen_dir"], aero=True, seed=seed, rough=rough).run(RING_DURATION_S, sp)
        worst, _ = ring_worst_z(log)
        return {**_key(job), "payload_robot": small[0], "payload_worst_z_error_m": float(worst[small[0]]),
                "small_worst_z_error_m": [float(worst[i]) for i in small],
                "payload_bias_g_end": float(log["adapt_bias"][-1, small[0]])}
    team, start, sp = swap_flight(job["case"], seed)
    pre, kw = 0.0, {}
    if kind != "swap":      # swap-solo, battery: the bottom robot alone first
        start, sp, pre = solo_first(start, sp)
    if kind == "battery":   # the supply falling linearly to the firmware's low-battery voltage
        v0 = rough.battery_start_V if rough is not None else 4.2
        kw["battery"] = lambda t: v0 - (v0 - LOW_BATTERY_V) * min(t / (pre + BATTERY_S), 1.0)
    robots = _robots(cfg, team, start, ctrl, job["tuning"], job["learned"], 0 if kind != "battery" else None,
                     job["payload_g"], **kw)
    swaps = job["swaps"]
    log = CLoopSwarm(cfg, robots, job["gen_dir"], aero=True, seed=seed, rough=rough).run(
        pre + swaps * (SWAP_S + REST_S), sp)
    swap_log = _after(log, pre)
    worst, z_err = bottom_worst_z(swap_log, swaps)
    out = {**_key(job), "worst_z_error_m": worst, "z_error_rms_m": float(np.sqrt((z_err ** 2).mean())),
           "bottom_bias_g_at_swaps": float(swap_log["adapt_bias"][0, 0]),
           "bottom_bias_g_end": float(log["adapt_bias"][-1, 0]),
           "bottom_updated_share": _updated_share(log, 0), "bottom_updated_share_swaps": _updated_share(swap_log, 0)}
    if kind == "battery":
        out["battery_V_start_end"] = [float(log["battery_V"][0, 0]), float(log["battery_V"][-1, 0])]
        out["adapt"] = _adapt_trace(log, 0, 5.0)
    return out


def _key(job: dict) -> dict:
    return {k: job[k] for k in ("kind", "case", "controller", "seed")}


def controllers(track_gains=(), baselines=True) -> tuple[str, ...]:
    """The arms: CONTROLLERS (without BL-tuned unless ``baselines``), then the composite law
    for every gain of ``track_gains``."""
    return tuple(k for k in CONTROLLERS if baselines or k != "BL-tuned") + tuple(composite(g) for g in track_gains)


def jobs(gen_dir, tuning: dict, seeds=SEEDS, swaps: int = 6, learned: str = "fixed", rough: Roughness | None = None,
         cases=None, rings=None, battery_seeds=(0,), payload_g: float = PAYLOAD_G, arms=CONTROLLERS) -> list[dict]:
    """Every flight of the experiment: swaps (``cases``, default all of SWAP_CASES) and
    rings (``rings``, default all of RING_CASES) for every seed and arm (``arms``, default
    CONTROLLERS), the battery flight for ``battery_seeds``."""
    base = {"gen_dir": str(gen_dir), "tuning": tuning, "learned": learned, "rough": rough, "swaps": swaps,
            "payload_g": payload_g}

    def swap(w):
        return [{**base, "kind": w, "case": c, "controller": k, "seed": s}
                for c in (SWAP_CASES if cases is None else cases) for s in seeds for k in arms]
    n = int(BATTERY_S // (SWAP_S + REST_S))
    return (swap("swap-solo")
            + [{**base, "kind": "battery", "case": BATTERY_CASE, "controller": k, "seed": s, "swaps": n}
               for s in battery_seeds for k in arms]
            + [{**base, "kind": "ring", "case": c, "controller": k, "seed": s}
               for c in (RING_CASES if rings is None else rings) for s in seeds for k in arms]
            + swap("swap"))


def summarize(rows: list[dict]) -> dict:
    """Per experiment and controller: the paper's metric pooled over swaps and seeds, the
    median per seed, and the share of ticks the payload robot's adaptation updated."""
    out: dict = {w: {} for w in SWAP_KINDS}
    out.update(rings={}, battery={})
    for r in rows:
        c, k = r["case"], r["controller"]
        if r["kind"] in SWAP_KINDS:
            d = out[r["kind"]].setdefault(c, {}).setdefault(k, {"worst": [], "per_seed": [], "updated": []})
            d["worst"] += r["worst_z_error_m"]
            d["per_seed"].append(float(np.median(r["worst_z_error_m"])))
            d["updated"].append(r["bottom_updated_share"])
        elif r["kind"] == "ring":
            d = out["rings"].setdefault(c, {}).setdefault(k, {"payload": [], "small": []})
            d["payload"].append(r["payload_worst_z_error_m"])
            d["small"] += r["small_worst_z_error_m"]
        else:
            m = int(BATTERY_WINDOW_S // (SWAP_S + REST_S))
            d = out["battery"].setdefault(k, {"first": [], "last": [], "V": r["battery_V_start_end"]})
            d["first"] += r["worst_z_error_m"][:m]
            d["last"] += r["worst_z_error_m"][-m:]
    for w in SWAP_KINDS:
        for c in out[w].values():
            for d in c.values():
                d["median_worst_z_error_m"] = float(np.median(d.pop("worst")))
                d["bottom_updated_share"] = float(np.mean(d.pop("updated")))
    for c in out["rings"].values():
        for d in c.values():
            d["payload_median_worst_z_error_m"] = float(np.median(d["payload"]))
            d["small_median_worst_z_error_m"] = float(np.median(d.pop("small")))
    for d in out["battery"].values():
        d["first_median_worst_z_error_m"] = float(np.median(d.pop("first")))
        d["last_median_worst_z_error_m"] = float(np.median(d.pop("last")))
    return out


def table(summary: dict, arms=CONTROLLERS) -> str:
    """Markdown of the summary (cm), a column per arm."""
    cm = lambda x: f"{100 * x:.2f}"  # noqa: E731
    head = " | ".join(arms) + " |"
    rule = "|---" * (len(arms) + 1) + "|"
    lines = []
    for w, what in (("swap", "the paper's swaps"), ("swap-solo", "the swaps after SOLO_S alone")):
        lines += [f"| {w}: case | " + head, rule]
        for c, d in summary[w].items():
            lines.append(f"| {c} | " + " | ".join(cm(d[k]["median_worst_z_error_m"]) for k in arms) + " |")
        share = [f"{c} {k} {100 * d[k]['bottom_updated_share']:.0f} %" for c, d in summary[w].items()
                 for k in arms if _adapt_cfg(k) is not None and k in d]
        lines += ["", f"{what}: median worst z error of the bottom robot (cm; it carries the payload), pooled over "
                  f"swaps and seeds; ticks on which its adaptation updated: {', '.join(share)}.", ""]
    if summary["rings"]:
        lines += ["| rings | " + head, rule]
        for c, d in summary["rings"].items():
            lines.append(f"| {c} | " + " | ".join(
                f"{cm(d[k]['payload_median_worst_z_error_m'])} / {cm(d[k]['small_median_worst_z_error_m'])}"
                for k in arms) + " |")
        lines += ["", "rings: the payload robot's worst z error (median over seeds) / the small robots' median (cm).",
                  ""]
    if summary["battery"]:
        lines += ["| battery | " + head, rule]
        for w in ("first", "last"):
            lines.append(f"| {w} {BATTERY_WINDOW_S:.0f} s | " + " | ".join(
                cm(summary["battery"][k][f"{w}_median_worst_z_error_m"]) for k in arms) + " |")
        lines += ["", f"battery: S2S swaps after SOLO_S alone, the supply falling linearly to {LOW_BATTERY_V} V at the "
                  "end; median worst z error of the bottom robot per swap (cm) in the first and the last "
                  f"{BATTERY_WINDOW_S:.0f} s."]
    return "\n".join(lines) + "\n"


def experiment(gen_dir, out_dir, tuning: dict, workers: int = 1, progress=None, **kw) -> dict:
    """Fly every job (run_map over ``workers``), write out_dir/adapt.json and adapt.md (and
    each flight's row to out_dir/adapt.partial.jsonl as it lands)."""
    js = jobs(gen_dir, tuning, **kw)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    partial = out / "adapt.partial.jsonl"
    partial.write_text("")

    def done(i, row):
        with partial.open("a") as f:
            f.write(json.dumps(row) + "\n")

    rows = run_map(fly, [(j,) for j in js], workers=workers, progress=progress, on_done=done)
    rough = kw.get("rough")
    arms = tuple(kw.get("arms", CONTROLLERS))
    res = {"controllers": list(arms), "payload_g": js[0]["payload_g"], "seeds": list(kw.get("seeds", SEEDS)),
           "swaps": js[0]["swaps"], "tuning": tuning, "simulator": "clean" if rough is None else "rough",
           "adapt": AdaptCfg(enable=1).as_dict(),
           "adapt_per_arm": {k: a.as_dict() for k in arms for a in [_adapt_cfg(k)] if a is not None},
           "summary": summarize(rows), "flights": rows}
    atomic_write_bytes(out / "adapt.json", (json.dumps(stamp(res), indent=2) + "\n").encode())
    atomic_write_bytes(out / "adapt.md", table(res["summary"], arms).encode())
    return res
