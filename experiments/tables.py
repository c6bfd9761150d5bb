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

from .blind import gains_table, mean_std, memory_rows, memory_table, table

RUNS = Path("docs/results/runs")
SIDECAR = "provenance.json"
NOT_RECORDED = "commit not recorded"


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
            doc.setdefault(k, v)
    return doc


def origin(doc: dict) -> tuple[str, str | None, str | None]:
    """(commit, command, source) of a loaded result; ``source``: the doc that records
    them when the file itself does not."""
    p = doc.get("provenance") or {}
    return p.get("commit") or NOT_RECORDED, p.get("command"), doc.get("source")


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
        for name, r in memory_rows(mem).items():
            now, w = _mean(r["wake_neutral"]["now"]), _mean(r["wake_neutral"]["with_past"])
            beyond = "beyond" if r["wake_lower_beyond_spread"] else "not beyond"
            text = (f"**the wake's memory** ({name}): seeing each neighbour's state {_lags(mem['lags_ms'])} ms ago "
                    f"{'lowers' if w < now else 'raises'} the blind wake MSE (mass-neutral) {abs(100 * (w / now - 1)):.0f} "
                    f"%, {beyond} the seeds' spread")
            if past and name == "collection 2020-06-16 left out":
                g = past["leave_one_collection_out"]["2020-06-16"]["gains"]["onboard"]["labels"]
                text += (f"; {_pct(g['overall_plain'])} / {_pct(g['overall_neutral'])} / {_pct(g['wake_plain'])} / "
                         f"{_pct(g['wake_neutral'])} below the flown network")
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


def _swap(rows: list, case: str, ctrl: str) -> float | None:
    r = [x for x in rows if x["case"] == case and x["controller"] == ctrl]
    return r[0]["median_worst_z_error_m"] if r else None


def sim_summary(d: dict) -> str:
    """make sim: NN against the tuned baseline in every swap; the rings' small robots."""
    parts = []
    swaps, rings = d.get("sim/swaps.json"), d.get("sim/rings.json")
    if swaps:
        cases = list(dict.fromkeys(r["case"] for r in swaps["rows"]))
        cells = []
        for c in cases:
            nn, bl = _swap(swaps["rows"], c, "NN"), _swap(swaps["rows"], c, "BL-tuned")
            if nn and bl:
                cells.append(f"{c} {100 * nn:.2f} vs {100 * bl:.2f} cm ({bl / nn:.2f}x)")
        parts.append(f"{swaps['simulator']} simulator, median worst z error NN vs the tuned baseline: " + ", ".join(cells))
    if rings:
        cells = []
        for case in dict.fromkeys(r["case"] for r in rings["rows"]):
            got = {r["controller"]: r["max_worst_z_error_m"] for r in rings["rows"]
                   if r["case"] == case and r["robot_type"].endswith("*")}
            cells.append(f"{case}: " + " / ".join(f"{k} {100 * v:.1f}" for k, v in got.items()))
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
            text = f"{label}: {100 * (r['mean'] / ref['mean'] - 1):+.0f} %"
            if "larger_teams" in r and "larger_teams" in ref:
                more = r["larger_teams"]["mean"] / ref["larger_teams"]["mean"] - 1
                text += f" (teams of 4-5 robots {100 * more:+.0f} %)"
            parts.append(text)
    for axis in ("H", "L"):
        others = {k: v["mean"] for k, v in a.get(axis, {}).items() if k not in ("20", "4")}
        if others:
            parts.append(f"{axis} " + ", ".join(f"{k}: {100 * (m / ref['mean'] - 1):+.0f} %" for k, m in others.items()))
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
                *((f"real/loco-{c}.json", f"build/real/loco-{c}.json") for c in ("2019-12-11", "2019-12-20", "2020-06-16")),
                ("real-mem/loco-2020-06-16.json", "build/real-mem/loco-2020-06-16.json"))),
    Experiment("sim", "simulated swaps and rings under Crazyflie sensing", "make sim",
               {"sim/swaps.json": "build/sim/results/swaps.json", "sim/rings.json": "build/sim/results/rings.json"},
               sim_summary, "below, [docs/simulator.md](docs/simulator.md)"),
    Experiment("calibrate", "the simulator against the real flights", "make calibrate",
               {"calibrate/calibration.json": "build/sim/calibration/calibration.json"},
               calibrate_summary, "[docs/simulator.md](docs/simulator.md)"),
    Experiment("planning", "planning experiments (flow-based truth), the full-scale default pipeline",
               "ns2 plan --checkpoint build/plan/full/model/model.pt --plan-data-rounds 2 --out build/plan/p24 "
               "--trials 25 --time-limit 90 --workers 2",
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
@dataclass(frozen=True)
class DocTable:
    doc: str
    name: str
    file: str                         # committed name under RUNS
    render: Callable[[dict], str]


DOC_TABLES = (
    DocTable("docs/real-flights.md", "blind", "real/blind.json", table),
    DocTable("docs/real-flights.md", "blind-gains", "real/blind.json",
             lambda doc: gains_table(doc, "collection 2020-06-16 left out")),
    DocTable("docs/real-flights.md", "memory", "real/memory.json",
             lambda doc: memory_table(doc, ",".join(map(str, doc["lags_ms"])))),
    DocTable("docs/real-flights.md", "memory-blind", "real-mem/blind.json", table),
)


def doc_block(root: Path, t: DocTable) -> str:
    """A docs table with the line that names its command and commit."""
    doc = load(root, t.file)
    if doc is None:
        return f"No committed result (`{RUNS / t.file}`)."
    commit, command, source = origin(doc)
    said = f" (as {source} records)" if source else ""
    try:
        body = t.render(doc)
    except (KeyError, TypeError, ValueError) as e:
        raise ResultsError(f"{root / RUNS / t.file}: not the result its table is made of (lacks {e!r})") from None
    return (f"Made by `{command or 'command not recorded'}` at {_short(commit)}{said}; "
            f"`{RUNS / t.file}`, table by `make results`:\n\n{body}")


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
