"""README's results table and the docs' tables that come from the committed result
files (docs/results/runs/), written by ``ns2 results`` (``make results``).

Each experiment's top-level JSON carries its ``provenance`` (``ns2codegen.results.stamp``:
commit, command, date).  ``ns2 results --collect EXPERIMENT`` copies an experiment's
stamped JSONs from where its command wrote them (``build/...``) into
``docs/results/runs/``; ``ns2 results`` rewrites every generated block from those files:
the part of a Markdown file between ``<!-- results:begin -->`` and ``<!-- results:end -->``
(README's table: one row per experiment) or ``<!-- results:NAME:begin -->`` and
``<!-- results:NAME:end -->`` (a docs table), and nothing else.  An experiment whose files
are not committed is a row "no committed result: <command>", never a number.

A committed file made before results were stamped takes its provenance from the folder's
``provenance.json`` (file name -> the ``provenance`` and any other fact, e.g. ``lags_ms``,
that a reference doc records about it, with that doc's section as ``source``); where no
doc records it, its commit is "commit not recorded"."""
from __future__ import annotations

import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ns2codegen.errors import Ns2Error
from ns2paper.collection import COLLECTIONS

from .bench_tables import (app_memory_sizes_table, app_sizes_table, app_sram_table, benchmarks_host_table,
                           benchmarks_target_table,
                           calibration_gaps_table, calibration_points_table, memory_table as cycles_table,
                           readme_measures_table, scp_programs_table, wake_memory_cycles_table)
from .blind import gains_table, mean_std, memory_rows, memory_table, table
from .real import ablation_table as real_ablation_table

REAL_AXES = ("H", "L", "P", "T", "V")   # make real's ablation-*.json (REAL_AXES), in the order of their table

RUNS = Path("docs/results/runs")
SIDECAR = "provenance.json"
NOT_RECORDED = "commit not recorded"
RECORDED_IN = "provenance_recorded_in"     # a loaded file's key: the doc section its folder's provenance.json names


class ResultsError(Ns2Error):
    """A committed result file or a generated block cannot be read or written."""


# ------------------------------------------------------------------ reading the files
def load(root: Path, rel: str) -> dict | None:
    """The committed result ``RUNS/rel`` of checkout ``root`` (None if missing), its
    provenance from the folder's provenance.json where the file has none."""
    path = Path(root) / RUNS / rel
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ResultsError(f"{path}: not a JSON result ({e})") from None
    if not isinstance(doc, dict):
        raise ResultsError(f"{path}: a result is a JSON object")
    side = path.parent / SIDECAR
    if "provenance" not in doc and side.is_file():
        try:
            recorded = json.loads(side.read_text()).get(path.name, {})
        except (OSError, ValueError, AttributeError) as e:
            raise ResultsError(f"{side}: not a provenance file ({e})") from None
        for k, v in recorded.items():
            if k == "source":          # the doc that records it (a file's own "source" is its data's)
                doc[RECORDED_IN] = v
            else:
                doc.setdefault(k, v)
    return doc


def origin(doc: dict) -> tuple[str, str | None, str | None]:
    """(commit, command, source) of a loaded result; ``source``: the doc that records
    them when the file itself does not."""
    p = doc.get("provenance") or {}
    return p.get("commit") or NOT_RECORDED, p.get("command"), doc.get(RECORDED_IN)


def _short(commit: str) -> str:
    return commit if commit == NOT_RECORDED else re.sub(r"^([0-9a-f]{7})[0-9a-f]*", r"\1", commit)


# ------------------------------------------------------------------ README's rows
def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def _mean(x):
    return x["mean"] if isinstance(x, dict) else x


def _lags(ms) -> str:
    ms = [str(m) for m in ms]
    return ", ".join(ms[:-1]) + f" and {ms[-1]}" if len(ms) > 1 else ms[0]


def real_summary(d: dict) -> str:
    """The paper's own flights: the paper's protocol, the blind day, the wake's memory, the C."""
    paper, blind, mem, past, cc, paper_past = (
        d.get(k) for k in ("real/paper.json", "real/blind.json", "real/memory.json", "real-mem/blind.json",
                           "real/c_check.json", "real-mem/paper.json"))
    parts = []
    if paper:
        parts.append(f"the paper's network **{mean_std(paper['H']['20'])} g^2** under the paper's random split over "
                     f"{paper['samples']:,} samples of all three collections (paper 6.42 +- 0.18)")
    if paper_past:
        n = paper_past["seeds"]
        parts.append(f"with the wake's memory (the exported network) {mean_std(paper_past['H']['20'])} g^2 under the same "
                     f"split ({n} seed{'s' if n > 1 else ''})")
    if blind:
        g, o = (blind["leave_one_collection_out"]["2020-06-16"]["gains"]["onboard"][c] for c in ("labels", "other_masses"))
        parts.append(f"**blind**, trained on 2019 only and scored on 16 June 2020 against the network that flew "
                     f"that day (trained before it): {_pct(g['overall_plain'])} / {_pct(g['overall_neutral'])} lower "
                     f"MSE overall (plain / mass-neutral), {_pct(g['wake_plain'])} / {_pct(g['wake_neutral'])} lower "
                     "in the wake, labels with the hover masses " + " / ".join(f"{blind['masses_g'][t]:.1f}" for t in blind["robot_types"])
                     + " g; relabelled with the authors' " + " / ".join(f"{blind['other_masses_g'][t]:g}"
                                                                         for t in blind["robot_types"])
                     + " g: " + " / ".join(_pct(o[k]) for k in ("overall_plain", "overall_neutral", "wake_plain",
                                                                "wake_neutral")) + " lower")
    if mem:
        said = []
        for name, r in memory_rows(mem).items():
            now, w = _mean(r["wake_neutral"]["now"]), _mean(r["wake_neutral"]["with_past"])
            said.append(f"{'-' if w < now else '+'}{abs(100 * (w / now - 1)):.0f} % "
                        f"({'beyond' if r['wake_lower_beyond_spread'] else 'not beyond'} the seeds' spread) with "
                        f"{name}")
        text = (f"**the wake's memory**: seeing each neighbour's state {_lags(mem['lags_ms'])} ms ago changes the "
                "blind wake MSE (mass-neutral) by " + ", ".join(said))
        if past and "2020-06-16" in past["leave_one_collection_out"]:
            g = past["leave_one_collection_out"]["2020-06-16"]["gains"]["onboard"]["labels"]
            text += (f"; on 16 June 2020 {_pct(g['overall_plain'])} / {_pct(g['overall_neutral'])} / "
                     f"{_pct(g['wake_plain'])} / {_pct(g['wake_neutral'])} below the flown network")
        parts.append(text)
    if cc:
        lags = cc.get("history_ms")
        net = "the exported network (trained on every flight" + (
            f", with each neighbour's state {', '.join(map(str, lags))} ms ago)" if lags else ")")
        if cc["float_mismatches"] == 0 and cc["fixed_mismatches"] == 0:
            text = (f"{net} equals the references bit for bit in C, float "
                    f"and fixed point, on all {cc['samples']:,} held-out samples")
        else:
            text = (f"{net} differs from the references in C on "
                    f"{cc['float_mismatches']} (float) and {cc['fixed_mismatches']} (fixed point) of "
                    f"{cc['samples']:,} held-out samples")
        sel = cc.get("selection_all_flights")
        if sel:
            text += (f", and its neighbour selection the data's on all {sel['samples']:,}" if sel["mismatches"] == 0
                     else f"; its neighbour selection differs from the data's on {sel['mismatches']} of {sel['samples']:,}")
        parts.append(text)
    return "; ".join(parts)


def _medians(doc: dict) -> dict:
    """{(case, controller): median worst z error} of a make sim swaps.json."""
    return {(r["case"], r["controller"]): r["median_worst_z_error_m"] for r in doc["rows"]}


def _s_star_max(doc: dict) -> dict:
    """{(case, controller): largest worst z error of an S* robot} of a make sim rings.json."""
    return {(r["case"], r["controller"]): r["max_worst_z_error_m"] for r in doc["rows"] if r["robot_type"].endswith("*")}


def sim_summary(d: dict, folder: str = "sim") -> str:
    """make sim (its files under ``folder``): NN against the tuned baseline in every swap;
    the rings' small robots."""
    parts = []
    swaps, rings = d.get(f"{folder}/swaps.json"), d.get(f"{folder}/rings.json")
    if swaps:
        med, cells = _medians(swaps), []
        for c in dict.fromkeys(r["case"] for r in swaps["rows"]):
            nn, bl = med.get((c, "NN")), med.get((c, "BL-tuned"))
            if nn and bl:
                cells.append(f"{c} {100 * nn:.2f} vs {100 * bl:.2f} cm ({bl / nn:.2f}x)")
        parts.append(f"{swaps['simulator']} simulator, median worst z error NN vs the tuned baseline: " + ", ".join(cells))
    if rings:
        star, cells = _s_star_max(rings), []
        for case in dict.fromkeys(r["case"] for r in rings["rows"]):
            cells.append(f"{case}: " + " / ".join(f"{k} {100 * v:.1f}" for (c, k), v in star.items() if c == case))
        parts.append("the paper's rings, the S* robots' largest z error (cm) " + "; ".join(cells))
    return "; ".join(parts)


def calibrate_summary(d: dict) -> str:
    """make calibrate: the paper's L2S flown as the paper's flights flew, against the paper."""
    cal = d["calibrate/calibration.json"]
    return "the paper's L2S flown as it flew, median worst z error of the bottom robot: " + ", ".join(
        f"{k} {100 * v['median_worst_z_error_m']:.1f} cm (paper {100 * v['paper_m']:.0f})"
        for k, v in cal["paper_l2s"].items())


def planning_summary(d: dict) -> str:
    """The planning experiment: per dimension and planner, trials planned and within the limits in flight."""
    cases = d["planning/plan.json"]["cases"]
    out = []
    for dim in sorted({k.split()[0] for k in cases}, reverse=True):
        cells = []
        for mode in ("NN", "BL"):
            s = [c[mode]["summary"] for k, c in cases.items() if k.split()[0] == dim and mode in c]
            if s:
                planned = sum(x["planned"] for x in s)
                within = sum(x["planned"] - x["trials_any_over_limit"] for x in s if x["planned"])
                cells.append(f"{mode} {planned} of {sum(x['trials'] for x in s)} planned, {within} within the "
                             "force limits in flight")
        out.append(f"{dim}: " + "; ".join(cells))
    return ". ".join(out)


def ablation_summary(d: dict) -> str:
    """make ablation: the paper's network and each ablation, validation MSE and on larger teams."""
    a = d["ablation/ablation.json"]
    ref = a["H"]["20"]
    parts = [f"validation MSE of H = 20, L = 4: {mean_std(ref)} g^2 ({a['samples']:,} samples, {a['seeds']} seeds)"]
    for axis, key, label in (("V", "without", "without relative velocity"), ("T", "type-agnostic", "type-agnostic"),
                             ("P", "pairwise sum", "the sum of pairwise models")):
        r = a.get(axis, {}).get(key)
        if r:
            text = f"{label}: {_rel(r['mean'], ref['mean'])}"
            if "larger_teams" in r and "larger_teams" in ref:
                text += f" (teams of 4-5 robots {_rel(r['larger_teams']['mean'], ref['larger_teams']['mean'])})"
            parts.append(text)
    for axis in ("H", "L"):
        others = {k: v["mean"] for k, v in a.get(axis, {}).items() if k not in ("20", "4")}
        if others:
            parts.append(f"{axis} " + ", ".join(f"{k}: {_rel(m, ref['mean'])}" for k, m in others.items()))
    return "; ".join(parts)


def paper_data_summary(d: dict) -> str:
    """make paper-data: the paper-sized simulated set and its network."""
    p = d["paper-data/paper_data.json"]
    return (f"{p['data']['samples']:,} samples of the {p['data']['simulator']} simulator; the network's validation MSE "
            f"{p['training']['validation_mse_g2']:.2f} g^2 (label variance {p['training']['label_variance_g2']:.2f})")


@dataclass(frozen=True)
class Experiment:
    key: str
    title: str
    command: str
    files: dict            # committed name under RUNS -> where the command writes it
    summary: Callable[[dict], str]
    details: str
    also: tuple = ()       # further files of the command that --collect copies beside (committed name, made at)


EXPERIMENTS = (
    Experiment("real", "the paper's own flights (the authors' logs of 2019-12-11, 2019-12-20 and 2020-06-16)",
               "make real",
               {"real/paper.json": "build/real/paper.json", "real/blind.json": "build/real/blind.json",
                "real/memory.json": "build/real/memory.json", "real-mem/blind.json": "build/real-mem/blind.json",
                "real/c_check.json": "build/real/c_check.json", "real-mem/paper.json": "build/real-mem/paper.json"},
               real_summary, "[docs/real-flights.md](docs/real-flights.md)",
               (("real/heldout.json", "build/real/heldout.json"), ("real/authors.json", "build/real/authors.json"),
                ("real/data_report.json", "build/real/data_report.json"),
                ("real/adapt.json", "build/real/adapt.json"),
                *((f"real/ablation-{a}.json", f"build/real/ablation-{a}.json") for a in REAL_AXES),
                *((f"{d}/loco-{c.key}.json", f"build/{d}/loco-{c.key}.json") for d in ("real", "real-mem")
                  for c in COLLECTIONS),
                ("real-mem/heldout.json", "build/real-mem/heldout.json"))),
    Experiment("sim", "simulated swaps and rings under Crazyflie sensing", "make sim",
               {"sim/swaps.json": "build/sim/results/swaps.json", "sim/rings.json": "build/sim/results/rings.json"},
               sim_summary, "below, [docs/simulator.md](docs/simulator.md)",
               (("sim/gain_search.json", "build/sim/results/gain_search.json"),)),
    Experiment("sim-clean", "the same on the clean simulator (none of the rough effects)",
               "make sim SIMULATOR=clean SIM=build/sim-clean",
               {"sim-clean/swaps.json": "build/sim-clean/results/swaps.json",
                "sim-clean/rings.json": "build/sim-clean/results/rings.json"},
               lambda d: sim_summary(d, "sim-clean"),
               "[docs/simulator.md](docs/simulator.md)",
               (("sim-clean/gain_search.json", "build/sim-clean/results/gain_search.json"),)),
    Experiment("calibrate", "the simulator against the real flights", "make calibrate",
               {"calibrate/calibration.json": "build/sim/calibration/calibration.json"},
               calibrate_summary, "[docs/simulator.md](docs/simulator.md)"),
    Experiment("planning", "planning experiments (flow-based truth), the full-scale default pipeline",
               "ns2 plan --checkpoint build/plan/full/model/model.pt --plan-data-rounds 2 --out build/plan/p24 "
               "--trials 25 --time-limit 90 --workers 2 --runs docs/results/runs/planning",
               {"planning/plan.json": "build/plan/p24/plan.json"},
               planning_summary, "[docs/planning.md](docs/planning.md)"),
    Experiment("paper-data", "the paper-sized simulated data set", "make paper-data",
               {"paper-data/paper_data.json": "build/paper_data.json"},
               paper_data_summary, "[docs/ground-truth.md](docs/ground-truth.md)"),
    Experiment("ablation", "the paper's ablations (paper-sized simulated data, 3 seeds)", "make ablation",
               {"ablation/ablation.json": "build/ablation.json"},
               ablation_summary, "[docs/ground-truth.md](docs/ground-truth.md)"),
)


def _made_by(docs: dict, command: str) -> str:
    """``command`` at the distinct commits of the files (in the files' order)."""
    commits = list(dict.fromkeys(_short(origin(doc)[0]) for doc in docs.values()))
    return f"`{command}` at " + ", ".join(commits)


def readme_table(root: Path, experiments=EXPERIMENTS) -> str:
    lines = ["| experiment | result | made by (command, commit) | details |", "|---|---|---|---|"]
    for e in experiments:
        docs = {rel: doc for rel in e.files if (doc := load(root, rel)) is not None}
        if not docs:
            lines.append(f"| {e.title} | no committed result: `{e.command}` | - | {e.details} |")
            continue
        missing = [rel for rel in e.files if rel not in docs]
        try:
            cell = e.summary(docs)
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as err:
            raise ResultsError(f"{root / RUNS}: the files of `{e.command}` ({', '.join(docs)}) lack "
                               f"{err!r}: not that command's results") from None
        if missing:
            cell += "; no committed result: " + ", ".join(f"`{m}`" for m in missing)
        lines.append(f"| {e.title} | {cell} | {_made_by(docs, e.command)} | {e.details} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ the docs' tables
def _rel(x: float, ref: float) -> str:
    """x against ref in whole percent, signed ("+3 %", "-2 %"); "0 %" when it rounds to 0."""
    pct = round(100 * (x / ref - 1))
    return f"{pct:+d} %" if pct else "0 %"


def _cm(x: float, digits: int = 1) -> str:
    return f"{100 * x:.{digits}f}"


def sim_swaps_table(doc: dict) -> str:
    """make sim's swaps: per case, each controller's median / max worst z error of the
    bottom robot, and BL-tuned / NN (the headline ratio)."""
    by = {(r["case"], r["controller"]): r for r in doc["rows"]}
    ctrls = list(dict.fromkeys(r["controller"] for r in doc["rows"]))
    lines = [f"| swap ({doc['swaps']} swaps), median / max worst z error of the bottom robot (cm) | "
             + " | ".join(ctrls) + " | BL-tuned / NN |", "|---" * (len(ctrls) + 2) + "|"]
    for case in dict.fromkeys(r["case"] for r in doc["rows"]):
        cells = [f"{_cm(by[case, c]['median_worst_z_error_m'])} / {_cm(by[case, c]['max_worst_z_error_m'])}"
                 if (case, c) in by else "-" for c in ctrls]
        nn, bl = (by.get((case, c), {}).get("median_worst_z_error_m") for c in ("NN", "BL-tuned"))
        lines.append(f"| {case} | " + " | ".join(cells) + (f" | {bl / nn:.2f} |" if nn and bl else " | - |"))
    return "\n".join(lines)


def sim_rings_table(doc: dict) -> str:
    """make sim's rings: per case and robot type (the S* robots first), each controller's
    mean / max worst z error; "(BL)" where that controller did not fly the type."""
    by = {(r["case"], r["robot_type"], r["controller"]): r for r in doc["rows"]}
    ctrls = list(dict.fromkeys(r["controller"] for r in doc["rows"]))
    lines = [f"| rings ({doc['duration_s']:g} s flights), mean / max worst z error (cm) | robot | " + " | ".join(ctrls)
             + " |", "|---" * (len(ctrls) + 2) + "|"]
    for case in dict.fromkeys(r["case"] for r in doc["rows"]):
        kinds = list(dict.fromkeys(r["robot_type"] for r in doc["rows"] if r["case"] == case))
        for kind in sorted(kinds, key=lambda k: (not k.endswith("*"), kinds.index(k))):
            cells = [f"{_cm(r['mean_worst_z_error_m'])} / {_cm(r['max_worst_z_error_m'])}"
                     if (r := by.get((case, kind, c))) else "(BL)" for c in ctrls]
            lines.append(f"| {case} | {kind} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _tuning(t: dict) -> str:
    return (f"Lp = {t['Lp_xy']:g} / {t['Lp_xy']:g} / {t['Lp_z']:g} 1/s, "
            f"Kv = {t['Kv_xy']:g} / {t['Kv_xy']:g} / {t['Kv_z']:g} N s/m per kg")


def sim_tuning_table(swaps: dict, search: dict) -> str:
    """make sim's BL-tuned: the gains its swaps and rings flew (swaps.json's tuning, which
    must be the gain search's) and the search that chose them (gain_search.json)."""
    from .swarm import DEFAULT_TUNING

    t = search["tuning"]
    if swaps["tuning"] != t:
        raise ValueError("swaps.json's tuning is not gain_search.json's")
    cands = search["candidates"]
    chosen = [c for c in cands if all(c[k] == v for k, v in t.items())][-1]
    n_ok = sum(bool(c["admissible"]) for c in cands)
    return "\n".join([
        f"| gains of | x / y / z | L2S median worst z error, f_a = 0 (cm) | "
        f"hover motor-command noise of a small robot (% PWM rms; bound {100 * search['hover_noise_limit']:.2f}) |",
        "|---|---|---|---|",
        f"| default (BL, NN-default) | {_tuning(DEFAULT_TUNING)} | - | - |",
        f"| BL-tuned (BL-tuned, NN): {n_ok} of {len(cands)} candidates within the bound | {_tuning(t)} | "
        f"{_cm(chosen['median_worst_z_error_m'], 2)} | {100 * chosen['hover_motor_cmd_rms']:.2f} |"])


def sim_noise_table(doc: dict) -> str:
    """make sim's swaps: per controller, the range over the cases of the bottom robot's z
    error rms and motor-command noise (PWM rms after removing a moving average)."""
    ctrls = list(dict.fromkeys(r["controller"] for r in doc["rows"]))
    lines = ["| swaps, range over the cases | " + " | ".join(ctrls) + " |", "|---" * (len(ctrls) + 1) + "|"]
    for key, label in (("z_error_rms_m", "z error rms (cm)"), ("motor_cmd_rms", "motor-command noise (% PWM rms)")):
        cells = []
        for c in ctrls:
            v = [r[key] for r in doc["rows"] if r["controller"] == c]
            cells.append(f"{_cm(min(v))}-{_cm(max(v))}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# the paper's rings (its text, section "Generalization to larger swarms"): the largest z error of a
# small robot in a vertical ring, with the powerful motors (S*), BL -> NN, metres
PAPER_RINGS_S_STAR_M = {"5-robot rings": (0.10, 0.05), "16-robot three rings": (0.15, 0.10)}


def readme_sim_table(swaps: dict, rings: dict, clean_swaps: dict, clean_rings: dict) -> str:
    """README's make sim tables: the swaps' median worst z error per controller on the
    rough simulator beside BL / BL-tuned / NN on the clean one; the rings' largest z error
    of an S* robot beside the paper's real rings."""
    rough, clean = _medians(swaps), _medians(clean_swaps)
    ctrls = list(dict.fromkeys(r["controller"] for r in swaps["rows"]))
    three = ("BL", "BL-tuned", "NN")
    lines = [f"| swap: median worst z error of the bottom robot ({swaps['swaps']} swaps, cm) | " + " | ".join(ctrls)
             + " | clean: " + " / ".join(three) + " |", "|---" * (len(ctrls) + 2) + "|"]
    for case in dict.fromkeys(r["case"] for r in swaps["rows"]):
        lines.append(f"| {case} | " + " | ".join(_cm(rough[case, c]) if (case, c) in rough else "-" for c in ctrls)
                     + " | " + " / ".join(_cm(clean[case, c]) if (case, c) in clean else "-" for c in three) + " |")

    rr, cr = _s_star_max(rings), _s_star_max(clean_rings)
    lines += ["", "| the paper's rings (the authors' geometry): largest z error of an S* robot (cm) | "
              + " | ".join(three) + " | clean: " + " / ".join(three) + " | paper (real), BL -> NN |",
              "|---" * 6 + "|"]
    for case in dict.fromkeys(r["case"] for r in rings["rows"]):
        paper = PAPER_RINGS_S_STAR_M.get(case)
        lines.append(f"| {case} | " + " | ".join(_cm(rr[case, c]) if (case, c) in rr else "-" for c in three)
                     + " | " + " / ".join(_cm(cr[case, c]) if (case, c) in cr else "-" for c in three)
                     + " | " + (f"{_cm(paper[0], 0)} -> {_cm(paper[1], 0)}" if paper else "-") + " |")
    return "\n".join(lines)


PAPER_DATA_AXES = {"H": "H (at L = 4)", "L": "L (at H = 20)", "W": "widths phi/rho (24/16 on board)"}


def paper_data_table(doc: dict) -> str:
    """make paper-data: the data set, its network's validation MSE overall and per scenario,
    and the short ablation on the same set (one seed)."""
    d, t, a = doc["data"], doc["training"], doc["ablation"]
    per = t["validation_mse_per_scenario_g2"]
    lines = [f"{d['samples']:,} labelled samples of the {d['simulator']} simulator: {d['teams']} teams flying the "
             f"{d['scenarios']} scenarios, {d['flight_seconds_per_team']:g} s of flight per team, made in "
             f"{d['generation_s']:.0f} s; the 5 networks trained {t['epochs']} epochs on {t['train_samples']:,} of "
             f"them ({t['train_time_s']:.0f} s). Validation MSE (g^2; label variance of the training part "
             f"{t['label_variance_g2']:.2f}):", "",
             "| overall | " + " | ".join(per) + " |", "|---" * (len(per) + 1) + "|",
             f"| {t['validation_mse_g2']:.2f} | " + " | ".join(f"{v:.2f}" for v in per.values()) + " |", "",
             f"The short ablation on the same set ({a['epochs']} epochs each, one seed), validation MSE (g^2):", "",
             "| " + " | ".join(PAPER_DATA_AXES.get(k, k) for k in a if k != "epochs") + " |",
             "|---" * (len(a) - 1) + "|"]
    axes = {k: v for k, v in a.items() if k != "epochs"}
    lines.append("| " + " | ".join(", ".join(f"{x} {m:.2f}" for x, m in sorted(v.items(), key=_numeric))
                                         for v in axes.values()) + " |")
    return "\n".join(lines)


def _numeric(item) -> tuple:
    k = item[0]
    try:
        return (0, float(k), k)
    except ValueError:
        return (1, 0.0, k)


def planning_table(doc: dict) -> str:
    """The planning experiment's table (its own, ns2exp.planning.reports.table), the cases
    in the experiment's order: per dimension, the scenarios as planning.cases lists them."""
    from .planning.cases import SCENARIOS
    from .planning.reports import table as plan_table

    cases = doc["cases"]
    order = sorted(cases, key=lambda k: (k.split()[0], list(SCENARIOS).index(k.split()[1])))
    return plan_table({k: cases[k] for k in order})


def planning_model_table(doc: dict) -> str:
    """The planning model against the simulator's truth (plan.json's model_check: a robot
    hovering under another, predicted / true f_a,z per pair of types and gap)."""
    from .planning.reports import downwash_table

    return downwash_table(doc["model_check"])


ABLATION_LABELS = {"H": "H = {}", "L": "L = {}", "W": "widths {}", "V": "{} relative velocity", "P": "sum of pairwise models",
                   "T": "type-agnostic deep set"}
ABLATION_PAPER_NOTES = {"P=pairwise sum": "(deep set chosen over it)"}


def ablation_table(doc: dict) -> str:
    """make ablation: each configuration's validation MSE (mean +- std, per seed), epochs,
    the larger teams' MSE, each against the paper's network; the paper's numbers (its real
    flights) beside them."""
    from .ablation import SAME_AS_PAPER
    from .real import PAPER_TABLE

    ref = doc["H"]["20"]
    paper_ref = float(PAPER_TABLE["H=20"].split()[0])

    def row(label, r, key, first=False):
        paper = PAPER_TABLE.get(key)
        big = r.get("larger_teams")
        cells = [f"{r['mean']:.3f} +- {r['std']:.3f}", ", ".join(f"{x:.3f}" for x in r["runs"]),
                 ", ".join(str(e) for e in r["epochs"]), mean_std(big) if big else "-",
                 paper or ABLATION_PAPER_NOTES.get(key, "")]
        if first:
            cells[0], cells[4] = f"**{cells[0]}**", f"**{cells[4]}**"
        else:
            cells[0] += f" ({_rel(r['mean'], ref['mean'])})"
            if big and "larger_teams" in ref:
                cells[3] += f" ({_rel(big['mean'], ref['larger_teams']['mean'])})"
            if paper:
                cells[4] += f" ({_rel(float(paper.split()[0]), paper_ref)})"
        return f"| {label} | " + " | ".join(cells) + " |"

    lines = ["| configuration | validation MSE (g^2), mean +- std | per seed | epochs | larger teams (g^2) | "
             "paper (validation, real flights) |", "|---|---|---|---|---|---|",
             row("H = 20, L = 4 (the paper's network)", ref, "H=20", first=True)]
    for axis, label in ABLATION_LABELS.items():
        for value, r in doc.get(axis, {}).items():
            if (axis, value) not in SAME_AS_PAPER and (axis, value) != ("H", "20"):
                lines.append(row(label.format(value), r, f"{axis}={value}"))
    return "\n".join(lines)


def _adapt_in_order(doc: dict) -> dict:
    """A real adapt result (its JSON has sorted keys) in the experiment's order: the split
    the laws were chosen on first (the held-out flights, so named), each seed's laws in
    the order ns2exp.adaptation.variants tried them."""
    from .adaptation import variants

    order = list(variants())
    first = doc.get("chosen_on")
    splits = {("held-out flights" if k == "held_out_flights" else k): s for k, s in
              sorted(doc["splits"].items(), key=lambda kv: kv[0] != first)}
    for s in splits.values():
        for r in s["seeds"]:
            r["variants"] = {v: r["variants"][v] for v in sorted(r["variants"], key=order.index)}
    return dict(doc, splits=splits)


def adapt_table(doc: dict) -> str:
    from .adaptation import table as adapt_laws_table
    return adapt_laws_table(_adapt_in_order(doc))


def adapt_types_table(doc: dict) -> str:
    from .adaptation import by_type_table
    return by_type_table(_adapt_in_order(doc))


def adapt_masses_table(doc: dict) -> str:
    from .adaptation import other_masses_table
    return other_masses_table(_adapt_in_order(doc))


def adapt_offset_table(doc: dict) -> str:
    """The 3 g test on the split the laws were chosen on: MSE with the offset (mean over
    seeds) and seed 0's recovery times, per law."""
    from .adaptation import variants

    split = _adapt_in_order(doc)["splits"]
    seeds = next(iter(split.values()))["seeds"]
    laws = [k for k in seeds[0] if k.startswith("mass_offset")]
    order = [""] + [f", {v}" for v in variants()]
    laws.sort(key=lambda k: order.index(k[len("mass_offset"):]))

    def rec(x):
        return (f"{x.get('median_s', '-')} / {x.get('p90_s', '-')} / {x.get('max_s', '-')} s, "
                f"never {x['never']} of {x['robots']}")
    lines = ["| law | overall plain with the offset: static / adapted | from take-off: median / 90 % / max (seed 0) | "
             "from a step mid-flight (seed 0) | robots flagged < 50 % of the time, from the step (seed 0) |",
             "|---|---|---|---|---|"]
    for key in laws:
        m = [r[key] for r in seeds]
        law = "bias (the default law)" if key == "mass_offset" else key.split(", ", 1)[1]
        static, adapted = (sum(x[w]["plain"] for x in m) / len(m) for w in ("static", "adapted"))
        lines.append(f"| {law} | {static:.2f} / {adapted:.2f} | {rec(m[0]['recovery_from_takeoff'])} | "
                     f"{rec(m[0]['recovery_from_step_mid_flight'])} | "
                     f"{rec(m[0]['flag_under_half_the_time']['recovery_from_step_mid_flight'])} |")
    return "\n".join(lines)


SIM_ADAPT_BATTERY_WINDOW_S = 15      # ns2exp.simadapt.BATTERY_WINDOW_S (a test checks they agree)


def _updated(doc: dict, kind: str, case: str, ctrl: str = "NN+adapt") -> str:
    """The share of position ticks the bottom robot's adaptation updated on, over the seeds' flights."""
    got = sorted({round(100 * r["bottom_updated_share"]) for r in doc["flights"]
                  if (r["kind"], r["case"], r["controller"]) == (kind, case, ctrl)})
    return "-" if not got else (f"{got[0]} %" if len(got) == 1 else f"{got[0]}-{got[-1]} %")


def _sim_adapt_rows(doc: dict) -> list:
    """(row label, {controller: metres}, (kind, case) of the updated share or None) of a sim adapt result."""
    s, rows = doc["summary"], []
    for kind, what in (("swap", "the paper's swap"), ("swap-solo", "after 4 s alone")):
        for case, d in s.get(kind, {}).items():
            label = f"{case}, {what}" if kind == "swap" else f"{case} {what}"
            rows.append((label, {k: v["median_worst_z_error_m"] for k, v in d.items()}, (kind, case)))
    for case, d in s.get("rings", {}).items():
        rows.append((f"{case}, the payload robot (median over seeds)",
                     {k: v["payload_median_worst_z_error_m"] for k, v in d.items()}, None))
        rows.append((f"{case}, every small robot (median)", {k: v["small_median_worst_z_error_m"] for k, v in d.items()},
                     None))
    if s.get("battery"):
        v0, v1 = next(iter(s["battery"].values()))["V"]
        case = next((r["case"] for r in doc["flights"] if r["kind"] == "battery"), "")
        for w in ("first", "last"):
            rows.append((f"{case}, the supply falling {v0:.2f} -> {v1:.2f} V, no payload: {w} "
                         f"{SIM_ADAPT_BATTERY_WINDOW_S} s", {k: v[f"{w}_median_worst_z_error_m"]
                                                             for k, v in s["battery"].items()},
                         ("battery", case) if w == "first" else None))
    return rows


def sim_adapt_table(doc: dict) -> str:
    """ns2 sim adapt: the bottom robot's median worst z error per case and controller, and
    on how many ticks NN+adapt's adaptation updated (per seed: lowest-highest)."""
    ctrls = doc["controllers"]
    lines = ["| median worst z error, bottom robot (cm) | " + " | ".join(ctrls) + " | its adaptation updated on |",
             "|---" * (len(ctrls) + 2) + "|"]
    for label, got, upd in _sim_adapt_rows(doc):
        lines.append(f"| {label} | " + " | ".join(_cm(got[c], 2) if c in got else "-" for c in ctrls)
                     + f" | {_updated(doc, *upd) if upd else ''} |")
    return "\n".join(lines)


def sim_adapt_law_table(doc: dict, before: dict) -> str:
    """ns2 sim adapt flown again with another law (``doc``) beside the run before it
    (``before``): NN, NN+adapt of each (named by its commit), and on how many ticks the
    new law updated."""
    old = {label: got for label, got, _ in _sim_adapt_rows(before)}
    now, was = (_short(origin(d)[0]) for d in (doc, before))
    lines = [f"| median worst z error, bottom robot (cm) | NN | NN+adapt at {was} | NN+adapt at {now} | "
             f"its adaptation updated on (at {now}) |", "|---|---|---|---|---|"]
    for label, got, upd in _sim_adapt_rows(doc):
        was = old.get(label, {}).get("NN+adapt")
        lines.append(f"| {label} | {_cm(got['NN'], 2)} | {'-' if was is None else _cm(was, 2)} | "
                     f"{_cm(got['NN+adapt'], 2)} | {_updated(doc, *upd) if upd else ''} |")
    return "\n".join(lines)


def hover_table(doc: dict) -> str:
    """ns2 real data: the median hover thrust per collection, type and robot, and over
    every collection (each type with its own block)."""
    h = doc["hover"]
    types = sorted(h["by_type"], key=doc["masses_g"].get)
    lines = ["| collection | " + " | ".join(types) + " | per robot |", "|---" * (len(types) + 2) + "|"]
    for c in doc["collections"]:
        got = h["by_collection"].get(c, {})
        robots = ", ".join(f"{k} {v['median_g']:.2f} g" for k, v in h["by_robot"].get(c, {}).items())
        lines.append(f"| {c} | " + " | ".join(f"{got[t]['median_g']:.2f} g" if t in got else "-" for t in types)
                     + f" | {robots or 'no hover stretch'} |")
    lines.append("| all | " + " | ".join(f"**{h['by_type'][t][f'block of {t}']['median_g']:.2f} g**" for t in types)
                 + " | |")
    return "\n".join(lines)


def flights_table(doc: dict) -> str:
    from .real import flights_table as real_flights
    return real_flights(doc["flights"])


def _k(x: float) -> str:
    return f"{round(x):,}"


def stabilizer_parts_table(doc: dict) -> str:
    """bench_stabilizer: each part's worst 1 ms tick (the firmware's Kalman estimator, the
    stock PID, the app fixed point and float), instructions and cycles."""
    fx, fl = doc["fixed"], doc["float"]

    def row(label: str, r: dict) -> str:
        return (f"| {label} | {_k(r['instructions'])} | {_k(r['cycles'])} | {r['us_at_168MHz']:.0f} | "
                f"{r['memory_us_at_168MHz']:.0f} |")

    def costliest(x: dict) -> str:
        return f"k = {max(range(10), key=lambda k: x['app_by_tick']['memory'][k])}"

    return "\n".join([
        "| part (worst 1 ms tick) | instructions | cycles | µs, zero wait | µs, memory model |", "|---|---|---|---|---|",
        row("Kalman: 100 Hz prediction + a mocap position measurement", fx["estimator_kalman_predict_and_position"]),
        row("Kalman: the other ticks (process noise, finalize, externalize)", fx["estimator_kalman_other_ticks"]),
        row("stock PID controller", fx["stock_controller_pid"]),
        row(f"ns2 app, fixed point: its costliest millisecond ({costliest(fx)} on the memory model)",
            fx["app_controller_oot"]),
        row(f"ns2 app, float ({costliest(fl)})", fl["app_controller_oot"])])


def stabilizer_app_table(present: dict, memory: dict) -> str:
    """bench_stabilizer on the present-state network and on the wake-memory network side by
    side: the app's cycles per millisecond of its period, the worst iteration with the
    estimator over every phase, what the app adds to the stock worst iteration (issue 53's
    bound: 10 %), with the adaptation on and its bound, the float app, the mean load."""
    nets = (present, memory)

    def cells(f) -> str:
        return " | ".join(f(d) for d in nets)

    def share(x: float) -> str:
        return f"{100 * x:.2f} %"

    fx = [d["fixed"] for d in nets]
    stock = fx[0]["stock_worst_tick"]["memory"]["share_of_1ms"]
    return "\n".join([
        f"| | present state ({present['network']['phi'][0]} inputs) | wake memory ({memory['network']['phi'][0]} inputs, "
        f"{', '.join(str(ms) for ms in memory['network']['history_ms'])} ms) |", "|---|---|---|",
        "| the app's cycles in each millisecond k = 0..9 of its 100 Hz period, memory model | "
        + cells(lambda d: " / ".join(_k(c) for c in d["fixed"]["app_by_tick"]["memory"])) + " |",
        "| its costliest millisecond, zero wait / memory model | "
        + cells(lambda d: f"{_k(max(d['fixed']['app_by_tick']['zero_wait']))} / "
                          f"{_k(max(d['fixed']['app_by_tick']['memory']))} cycles") + " |",
        f"| worst 1 ms iteration, Kalman + the app, all phases, memory model (stock PID: {share(stock)}) | "
        + cells(lambda d: share(d["fixed"]["app_worst_tick"]["memory"]["share_of_1ms"])) + " |",
        "| **the app adds to the stock worst iteration**, zero wait / memory model (issue 53's bound: 10 %) | "
        + cells(lambda d: f"**{share(d['fixed']['app_adds_to_worst_tick']['zero_wait'])} / "
                          f"{share(d['fixed']['app_adds_to_worst_tick']['memory'])}**") + " |",
        "| the same with the adaptation on (`ns2adapt.enable` 1), memory model | "
        + cells(lambda d: share(d["fixed_adaptation"]["app_adds_to_worst_tick"]["memory"])) + " |",
        "| and with a whole label-and-update step in its position tick (bound), zero wait / memory model | "
        + cells(lambda d: f"{share(d['fixed_adaptation']['adds_to_worst_tick_bound_zero_wait'])} / "
                          f"{share(d['fixed_adaptation']['adds_to_worst_tick_bound_memory'])}") + " |",
        "| the float app (`NS2_INFER=float`, not the default) adds, zero wait / memory model | "
        + cells(lambda d: f"{share(d['float']['app_adds_to_worst_tick']['zero_wait'])} / "
                          f"{share(d['float']['app_adds_to_worst_tick']['memory'])}") + " |",
        f"| mean CPU load, memory model (stock: {share(fx[0]['stock_mean_load']['memory'])}) | "
        + cells(lambda d: share(d["fixed"]["app_mean_load"]["memory"])) + " |"])


def calibrate_table(part: str) -> Callable[[dict], str]:
    """One table of calibration.md (experiments/calibrate.py's report_parts) of the committed
    calibration.json: roughness, replays, paper-l2s, read-law, wake, lateral."""
    from .calibrate import report_parts

    def render(doc: dict) -> str:
        make = report_parts(doc).get(part)
        return make() if make else "No fit in this run (`--no-refit`)."
    return render


@dataclass(frozen=True)
class DocTable:
    doc: str
    name: str
    file: str                         # committed name under RUNS
    render: Callable[..., str]        # render(the file's JSON, *the JSON of ``more``)
    more: tuple = ()                  # further committed files the table is made of


# the Cortex-M4 benchmarks of the paper-sized, present-state network (make export's firmware/generated)
BENCH_TARGET, BENCH_STABILIZER = ("wake-memory-cycles/bench_target_default.json",
                                  "wake-memory-cycles/bench_stabilizer_default.json")
GROUND_TRUTH = "ground-truth/calibration.json"

DOC_TABLES = (
    DocTable("README.md", "readme-measures", BENCH_TARGET, readme_measures_table, (BENCH_STABILIZER, GROUND_TRUTH)),
    DocTable("README.md", "readme-sim", "sim/swaps.json", readme_sim_table,
             ("sim/rings.json", "sim-clean/swaps.json", "sim-clean/rings.json")),
    DocTable("docs/benchmarks.md", "bench-target", BENCH_TARGET, benchmarks_target_table),
    DocTable("docs/benchmarks.md", "bench-host", "host-bench/bench_core.json", benchmarks_host_table,
             ("host-bench/bench_sim.json", "bench-plan/bench_plan.json")),
    DocTable("docs/memory.md", "cycles", BENCH_TARGET, cycles_table),
    DocTable("docs/ground-truth.md", "calibration", GROUND_TRUTH, calibration_points_table),
    DocTable("docs/ground-truth.md", "gaps", GROUND_TRUTH, calibration_gaps_table),
    DocTable("docs/real-flights.md", "hover", "real/data_report.json", hover_table),
    DocTable("docs/real-flights.md", "blind", "real/blind.json", table),
    DocTable("docs/real-flights.md", "blind-gains", "real/blind.json",
             lambda doc: gains_table(doc, "collection 2020-06-16 left out")),
    DocTable("docs/real-flights.md", "memory", "real/memory.json",
             lambda doc: memory_table(doc, ",".join(map(str, doc["lags_ms"])))),
    DocTable("docs/real-flights.md", "memory-blind", "real-mem/blind.json", table),
    DocTable("docs/real-flights.md", "real-ablation", "real/paper.json",
             lambda paper, held, *rest: real_ablation_table(paper, held, *rest[:-1], authors=rest[-1]),
             ("real/heldout.json", *(f"real/ablation-{a}.json" for a in REAL_AXES), "real/authors.json")),
    DocTable("docs/real-flights.md", "flights", "real/data_report.json", flights_table),
    DocTable("docs/app.md", "app-sizes", "app-sizes/fixed.json", app_sizes_table,
             ("app-sizes/float.json", "app-sizes/both.json")),
    DocTable("docs/app.md", "app-memory-sizes", "app-sizes/fixed.json", app_memory_sizes_table, ("app-sizes/memory.json",)),
    DocTable("docs/app.md", "app-sram", "app-sizes/fixed.json", app_sram_table, ("app-sizes/fixed-ram.json",)),
    DocTable("docs/app.md", "wake-memory-cycles", BENCH_TARGET, wake_memory_cycles_table,
             ("wake-memory-cycles/bench_target.json",)),
    DocTable("docs/app.md", "stabilizer-parts", BENCH_STABILIZER, stabilizer_parts_table),
    DocTable("docs/app.md", "stabilizer-app", BENCH_STABILIZER, stabilizer_app_table,
             ("wake-memory-cycles/bench_stabilizer.json",)),
    DocTable("docs/simulator.md", "calibrate-lateral", "calibrate/calibration.json", calibrate_table("lateral")),
    DocTable("docs/simulator.md", "calibrate-replays", "calibrate/calibration.json", calibrate_table("replays")),
    DocTable("docs/simulator.md", "calibrate-paper-l2s", "calibrate/calibration.json", calibrate_table("paper-l2s")),
    DocTable("docs/simulator.md", "calibrate-wake", "calibrate/calibration.json", calibrate_table("wake")),
    DocTable("docs/simulator.md", "calibrate-roughness", "calibrate/calibration.json", calibrate_table("roughness")),
    DocTable("docs/simulator.md", "calibrate-read-law", "calibrate/calibration.json", calibrate_table("read-law")),
    DocTable("docs/simulator.md", "sim-tuning", "sim/swaps.json", sim_tuning_table, ("sim/gain_search.json",)),
    DocTable("docs/simulator.md", "sim-swaps", "sim/swaps.json", sim_swaps_table),
    DocTable("docs/simulator.md", "sim-noise", "sim/swaps.json", sim_noise_table),
    DocTable("docs/simulator.md", "sim-rings", "sim/rings.json", sim_rings_table),
    DocTable("docs/simulator.md", "paper-data", "paper-data/paper_data.json", paper_data_table),
    DocTable("docs/simulator.md", "sim-clean-tuning", "sim-clean/swaps.json", sim_tuning_table,
             ("sim-clean/gain_search.json",)),
    DocTable("docs/simulator.md", "sim-clean-swaps", "sim-clean/swaps.json", sim_swaps_table),
    DocTable("docs/simulator.md", "sim-clean-rings", "sim-clean/rings.json", sim_rings_table),
    DocTable("docs/planning.md", "scp-programs", "bench-plan/bench_plan.json", scp_programs_table),
    DocTable("docs/planning.md", "planning", "planning/plan.json", planning_table),
    DocTable("docs/planning.md", "planning-model", "planning/plan.json", planning_model_table),
    DocTable("docs/ground-truth.md", "ablation", "ablation/ablation.json", ablation_table),
    DocTable("docs/adaptation.md", "sim-adapt", "sim-adapt/adapt.json", sim_adapt_table),
    DocTable("docs/adaptation.md", "sim-adapt-gate0", "sim-adapt-gate0/adapt.json", sim_adapt_law_table,
             ("sim-adapt-gate1/adapt.json",)),
    DocTable("docs/adaptation.md", "real-adapt", "real/adapt.json", adapt_table),
    DocTable("docs/adaptation.md", "real-adapt-types", "real/adapt.json", adapt_types_table),
    DocTable("docs/adaptation.md", "real-adapt-masses", "real/adapt.json", adapt_masses_table),
    DocTable("docs/adaptation.md", "real-adapt-offset", "real/adapt.json", adapt_offset_table),
)


def _made(docs: list, rels: tuple) -> str:
    """The command and commit of each file, files of the same command, commit and record together."""
    groups: dict = {}
    for doc, rel in zip(docs, rels):
        groups.setdefault(origin(doc), []).append(f"`{RUNS / rel}`")
    parts = []
    for (commit, command, source), files in groups.items():
        said = f" (as {source} records)" if source else ""
        parts.append(f"`{command or 'command not recorded'}` at {_short(commit)}{said}; " + ", ".join(files))
    return "; and ".join(parts)


def doc_block(root: Path, t: DocTable) -> str:
    """A docs table with the line that names the command and commit of each file it is made of."""
    rels = (t.file, *t.more)
    docs = [load(root, rel) for rel in rels]
    missing = [f"`{RUNS / rel}`" for rel, doc in zip(rels, docs) if doc is None]
    if missing:
        return f"No committed result ({', '.join(missing)})."
    try:
        body = t.render(*docs)
    except (KeyError, TypeError, ValueError) as e:
        raise ResultsError(f"{root / RUNS / t.file}: not the result its table is made of (lacks {e!r})") from None
    made = _made(docs, rels)
    return f"Made by {made}, table by `make results`:\n\n{body}"


# ------------------------------------------------------------------ the blocks in the files
def markers(name: str | None) -> tuple[str, str]:
    tag = "results" if name is None else f"results:{name}"
    return f"<!-- {tag}:begin -->", f"<!-- {tag}:end -->"


def replace_block(text: str, name: str | None, body: str, where: str) -> str:
    """``text`` with the part between ``name``'s markers replaced by ``body``."""
    begin, end = markers(name)
    i, j = text.find(begin), text.find(end)
    if i < 0 or j < i or text.count(begin) != 1 or text.count(end) != 1:
        raise ResultsError(f"{where}: needs one {begin} and one {end} after it")
    return text[:i + len(begin)] + "\n" + body.rstrip("\n") + "\n" + text[j:]


def generated(root: Path) -> dict:
    """{file (relative to root): its text with every generated block rewritten}."""
    root = Path(root)
    blocks: dict[str, list] = {"README.md": [(None, readme_table(root))]}
    for t in DOC_TABLES:
        blocks.setdefault(t.doc, []).append((t.name, doc_block(root, t)))
    out = {}
    for rel, items in blocks.items():
        path = root / rel
        try:
            text = path.read_text()
        except OSError as e:
            raise ResultsError(f"{path}: cannot read ({e.strerror or e})") from None
        for name, body in items:
            text = replace_block(text, name, body, str(path))
        out[rel] = text
    return out


def write(root: Path, check: bool = False) -> list[str]:
    """Rewrite the generated blocks (``check``: only compare); the files that differ(ed)."""
    from ns2codegen.fileio import atomic_write_bytes

    changed = []
    for rel, text in generated(root).items():
        path = Path(root) / rel
        if path.read_text() != text:
            changed.append(rel)
            if not check:
                atomic_write_bytes(path, text.encode())
    return changed


def collect(root: Path, key: str) -> list[str]:
    """Copy experiment ``key``'s stamped result files from where its command wrote them
    into RUNS (a file without a provenance stamp is refused); the files copied."""
    by_key = {e.key: e for e in EXPERIMENTS}
    if key not in by_key:
        raise ResultsError(f"experiment {key!r}: not one of {', '.join(by_key)}")
    copied = []
    for rel, made in [*by_key[key].files.items(), *by_key[key].also]:
        src = Path(root) / made
        if not src.is_file():
            continue
        try:
            prov = json.loads(src.read_text()).get("provenance")
        except (OSError, ValueError, AttributeError) as e:
            raise ResultsError(f"{src}: not a JSON result ({e})") from None
        if not prov or not prov.get("commit"):
            raise ResultsError(f"{src}: no provenance (made before results were stamped): rerun `{by_key[key].command}`")
        dst = Path(root) / RUNS / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
        copied.append(rel)
    return copied
