"""The planning margin of an experiment run: measured on held-out flights
(ns2exp.margin) and, calibrated, on the planner's own flown plans too, round by
round until the plans keep it."""
from __future__ import annotations

from ns2codegen.config import Config
from ns2host.sim.planmodel import NEAR_GAP_MAX
from ns2plan.forces import ForceModel
from ns2plan.problem import RRTParams, SCPParams

from .. import margin
from .cases import LIMITS_3D
from .runs import fly_plans, plan_executor, trial_rows


# the margin's calibration on the planner's own flown plans (calibrated_margin): per case and round,
# CALIBRATION_PLANS planned trials from the seeds in order (a case whose seeds find no path gets the
# next ones; seeds never used by an experiment, those are 0 .. trials - 1), and the most rounds of
# plan, fly, re-measure
CALIBRATION_SEEDS = tuple(range(1000, 1008))
CALIBRATION_PLANS = 2
CALIBRATION_ROUNDS = 4


def measured_margin(cfg: Config, fm: ForceModel, gen_dir, cache=None, log=print, calibration: dict | None = None,
                    workers: int = 1) -> dict:
    """The planning margin per robot type from the model's error on held-out flights
    (ns2exp.margin; flown once, ``workers`` at a time, kept in ``cache``), with its evidence; with
    ``calibration`` (calibrated_margin's keyword arguments, the checkpoint among
    them) also on the NN's own flown plans."""
    log(f"measuring the model's error on held-out flights ({', '.join(f'{k} {s:.0f} s' for k, s in margin.HELD_OUT)} "
        f"per pair of types, {', '.join(f'{k} {s:.0f} s' for k, s in margin.HELD_OUT_BYSTANDER)} per team of three, "
        f"seed {margin.HELD_OUT_SEED})")
    flights = margin.held_out_flights(cfg, gen_dir, gap_max=NEAR_GAP_MAX, cache=cache, workers=workers)
    if calibration is not None:
        return calibrated_margin(cfg, fm, gen_dir=gen_dir, held_out=flights, log=log, **calibration)
    return margin.measure(cfg, fm, flights, LIMITS_3D)


def calibration_wave(cases: list, seeds, plans: int, done: dict) -> list:
    """The next calibration trials (scenario, dims, seed): for each case of ``cases``
    short of ``plans`` planned trials in ``done`` (case -> [(seed, planned)]), as many of
    its next untried ``seeds`` as it is short."""
    wave = []
    for case in cases:
        got = done.get(case, [])
        short = plans - sum(ok for _, ok in got)
        wave += [(*case, s) for s in list(seeds)[len(got):len(got) + max(short, 0)]]
    return wave


def _outcomes(tasks: list, done: list) -> dict:
    """case (scenario, dims) -> [(seed, planned)] of the flown ``tasks`` (fly_plans' results ``done``)."""
    out: dict = {}
    for (name, d, s), res in zip(tasks, done):
        out.setdefault((name, d), []).append((s, res[1] is not None))
    return out


def calibrated_margin(cfg: Config, fm: ForceModel, checkpoint, gen_dir, held_out: list, scenarios, dims,
                      seeds=CALIBRATION_SEEDS, plans: int = CALIBRATION_PLANS, rounds: int = CALIBRATION_ROUNDS,
                      rrt: RRTParams = RRTParams(), scp_params: SCPParams = SCPParams(), workers: int = 2, log=print,
                      cache=None) -> dict:
    """The margin measured on the held-out flights and on the planner's own flown
    plans (ns2exp.margin): the planner drives each robot to its bound, i.e. to the
    states where the model reads lowest, which held-out flights it did not choose need
    not contain.  Round r measures the margin m_r on the held-out flights and every
    plan flown so far, plans every scenario x dims with the NN and m_r for calibration
    ``seeds`` in order (never an experiment seed) until the case has ``plans`` planned
    trials or its seeds run out (calibration_wave: a case that rarely plans is not left
    out), flies the plans (run_trial) and adds their states; it stops when no new state
    raises the margin (m_r kept every flown plan state of its own round within its
    promise: converged) or after ``rounds``.  Returns the ``measure`` report on all
    those flights (its margin is the last round's m_r when converged, the raised one
    otherwise) with the ``rounds``; with ``cache`` (.npz) the flown plans are kept
    there (ns2exp.margin.load_flights)."""
    flights, history = list(held_out), []
    rep = margin.measure(cfg, fm, flights, LIMITS_3D)
    cases = [(name, d) for d in dims for name in scenarios]
    with plan_executor(checkpoint, gen_dir, workers) as ex:
        for r in range(rounds):
            m = rep["margin_g"]
            log(f"margin calibration round {r}: {plans} NN plans per case of seeds {list(seeds)} with margin {m}")
            tasks, done = [], []
            while wave := calibration_wave(cases, seeds, plans, _outcomes(tasks, done)):
                flown = fly_plans(checkpoint, gen_dir, wave, m, rrt, scp_params, ex)
                log("  " + ", ".join(f"{d}D {name} seed {s}: {'planned' if res[1] is not None else 'no plan'}"
                                     for (name, d, s), res in zip(wave, flown)))
                tasks += wave
                done += flown
            flights += [fl for _, fl, _ in done if fl is not None]
            rep = margin.measure(cfg, fm, flights, LIMITS_3D)
            trials = trial_rows(cfg, tasks, done)
            history.append({"round": r, "margin_g": m, "margin_after_g": rep["margin_g"], "trials": trials})
            ok = [t for t in trials if t["planned"]]
            log(f"  planned {len(ok)}/{len(trials)}, {sum(t['over_limit'] for t in ok)} over a limit in flight, "
                f"{sum(t['over_limit_in_bound_states'] for t in ok)} flown states over a limit within the bound; "
                f"margin after: {rep['margin_g']}")
            if cache is not None:
                margin.save_flights(cache, flights[len(held_out):], "calibration plans")
            if rep["margin_g"] == m:
                break
    rep["rounds"] = history
    rep["converged"] = history[-1]["margin_after_g"] == history[-1]["margin_g"] if history else True
    rep["calibration_seeds"] = list(seeds)
    rep["calibration_plans_per_case"] = plans
    short = sorted({t["case"] for t in history[-1]["trials"]} - {t["case"] for t in history[-1]["trials"] if t["planned"]}
                   ) if history else []
    rep["source"] += (f"; on the held-out flights and the NN's own flown plans, {plans} per case from calibration "
                      f"seeds {list(seeds)} ({len(history)} round(s), "
                      f"{'converged' if rep['converged'] else 'NOT converged'}"
                      + (f"; no plan of {', '.join(short)}" if short else "") + ")")
    return rep
