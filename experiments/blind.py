"""Blind scores on the authors' real flights (issue 52; docs/real-flights.md, "Blind
scores"): every model scored on flights it never trained on, by ``realscore``'s
yardsticks (overall, in the wake, per scenario; plain and mass-neutral; both mass
conventions).

Two blind splits of ``ns2 real data``'s sets:

* **leave one collection out**: for each collection, the project's network trained on
  the other two (``loco-<key>/H-20-seed<k>.pt``, ``make real``) scored on it;
* **whole held-out flights** (every fifth flight of each scenario): the networks trained
  without them (``heldout/H-20-seed<k>.pt``).

Beside them, on the same samples: **the on-board ``ctrlFa.Faz``** logged in flight (16 June
2020 only: that network was trained before that day, so there it is a blind reference;
in 2019 no network flew), **the authors' published network** (trained on every
collection: on these flights its score is a training score, never blind), and **zero**
(no model).  Where the on-board prediction is part of a table, every model is scored on
the samples where it exists (``ctrlFa.Faz`` finite and not exactly 0: before the network
starts it logs 0).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ns2paper.collection import COLLECTIONS

from .real import AUTHORS_MASSES_G, RealDataError
from .realscore import both_conventions, gain

ONBOARD_COLLECTION = "2020-06-16"
HELDOUT = "heldout"          # the split of the whole held-out flights (every fifth of each scenario)
MODEL_ORDER = ["ours", "authors", "zero", "onboard"]     # the rows of a split in the tables


def load_samples(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: (z[k].tolist() if k in ("flight_names", "robot_ids") else z[k]) for k in z.files}
    except (OSError, KeyError, ValueError) as e:
        raise RealDataError(f"{path}: not a sample table of `ns2 real data` ({e})") from None


def predictions(checkpoint: Path, ds) -> np.ndarray:
    """The checkpoint's f_a,z (g) of every sample; a network without the history inputs
    of a data set built with ``model.history_ms`` reads the present state only (the
    first 6 values of each row)."""
    import torch

    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.train import Batched, predict

    ck = load_checkpoint(checkpoint)
    b = Batched.of(ds)
    b.nbr_state = torch.from_numpy(np.ascontiguousarray(ds.nbr_state[:, :ck.cfg.input_dim]))
    return predict(ck.model(), b).numpy().astype(np.float64)


def _summ(rows: list[dict]) -> dict:
    """Mean and std over seeds of every number of ``both_conventions``'s output."""
    def walk(xs):
        if isinstance(xs[0], dict):
            return {k: walk([x[k] for x in xs]) for k in xs[0]}
        if xs[0] is None or isinstance(xs[0], str):
            return xs[0]
        a = np.array(xs, float)
        return {"mean": round(float(a.mean()), 4), "std": round(float(a.std()), 4)} if len(a) > 1 else xs[0]
    return walk(rows)


def score_split(ds, info: dict, models: dict, masses: dict, type_names: list[str],
                onboard: bool) -> dict:
    """Every model (name -> [predictions per seed]) on the data set ``ds``; with
    ``onboard``, the logged ``ctrlFa.Faz`` too and every model on its samples only."""
    keep = np.ones(len(ds), bool)
    if onboard:
        ob = info["onboard_g"]
        keep = np.isfinite(ob) & (ob != 0.0)
        models = dict(models, onboard=[ob])
    sub = {k: (v[keep] if isinstance(v, np.ndarray) and len(v) == len(ds) else v) for k, v in info.items()}
    out = {"samples": int(len(ds)), "scored": int(keep.sum()), "models": {}}
    for name, preds in models.items():
        per_seed = [both_conventions(ds.label_g[keep], p[keep], sub, ds.robot_type[keep], type_names,
                                     ds.scenario[keep], ds.scenario_names, masses, AUTHORS_MASSES_G) for p in preds]
        out["models"][name] = dict(_summ(per_seed), seeds=len(preds))
    return out


def _mean(x):
    return x["mean"] if isinstance(x, dict) else x


def _flat(res: dict) -> dict:
    """The headline numbers (mean over seeds) of one score."""
    return {"plain": _mean(res["plain"]), "neutral": _mean(res["neutral"]),
            "wake": {"plain": _mean(res["wake"]["plain"]), "neutral": _mean(res["wake"]["neutral"])}}


def gains(split: dict, ours: str = "ours", refs=("onboard", "authors", "zero")) -> dict:
    """1 - ours / ref for each reference in the split, under both conventions."""
    out = {}
    for ref in refs:
        if ref in split["models"] and ours in split["models"]:
            out[ref] = {conv: gain(_flat(split["models"][ours][conv]), _flat(split["models"][ref][conv]))
                        for conv in ("labels", "other_masses")}
    return out


def blind(data_dir: str | Path, authors: str | Path | None = None, seeds: int = 3, collections=None) -> dict:
    """The blind splits of ``data_dir`` (``make real``'s folder) scored (module docstring);
    ``collections``: only these splits, each a collection left out or ``heldout`` (the whole
    held-out flights); default every one."""
    from ns2codegen.config import Config
    from ns2codegen.data.dataset import Dataset

    d = Path(data_dir)
    cfg = Config.load(d / "real.toml")
    masses = {t: cfg.vehicle(t)["mass_g"] for t in cfg.robot_types}
    out = {"masses_g": masses, "other_masses_g": AUTHORS_MASSES_G, "robot_types": cfg.robot_types,
           "leave_one_collection_out": {}}

    def models(ds, ckpts: list[Path]) -> dict:
        m = {"ours": [predictions(c, ds) for c in ckpts]} if ckpts else {}
        if authors:
            m["authors"] = [predictions(Path(authors), ds)]
        m["zero"] = [np.zeros(len(ds))]
        return m

    names = [c.key for c in COLLECTIONS] + [HELDOUT]
    unknown = sorted(set(collections or ()) - set(names))
    if unknown:
        raise RealDataError(f"collection {unknown[0]}: not one of {', '.join(names)}")
    for c in COLLECTIONS:
        if collections is not None and c.key not in collections:
            continue
        ckpts = sorted((d / f"loco-{c.key}").glob("H-20-seed*.pt"))[:seeds]
        if not ckpts:
            raise RealDataError(f"{d / f'loco-{c.key}'}: no trained network (make real trains them)")
        ds = Dataset.load(d / f"c-{c.key}.npz")
        out["leave_one_collection_out"][c.key] = score_split(
            ds, load_samples(d / f"c-{c.key}_samples.npz"), models(ds, ckpts), masses, cfg.robot_types,
            onboard=c.key == ONBOARD_COLLECTION)
        out["leave_one_collection_out"][c.key]["gains"] = gains(out["leave_one_collection_out"][c.key])
    held = sorted((d / "heldout").glob("H-20-seed*.pt"))[:seeds] if collections is None or HELDOUT in collections else []
    if collections is not None and HELDOUT in collections and not held:
        raise RealDataError(f"{d / 'heldout'}: no trained network (make real trains them)")
    if held:
        ds = Dataset.load(d / "heldout.npz")
        info = load_samples(d / "heldout_samples.npz")
        june = np.array([n.startswith(ONBOARD_COLLECTION) for n in info["flight_names"]])[info["flight"]]
        out["held_out_flights"] = score_split(ds, info, models(ds, held), masses, cfg.robot_types,
                                              onboard=bool(june.all()))
        out["held_out_flights"]["gains"] = gains(out["held_out_flights"])
    return out


def splits(res: dict) -> dict:
    """The blind splits of a ``blind`` result by their names in the tables."""
    out = {f"collection {k} left out": v for k, v in res["leave_one_collection_out"].items()}
    if "held_out_flights" in res:
        out["whole held-out flights"] = res["held_out_flights"]
    return out


def mean_std(x) -> str:
    """mean +- std over seeds, or a single number."""
    return f"{x['mean']:.2f} +- {x['std']:.2f}" if isinstance(x, dict) else f"{x:.2f}"


def table(res: dict) -> str:
    """Markdown: one row per split and model, the four headline MSEs under the labels'
    masses and (in brackets) relabelled with the other convention."""
    first = next(iter(splits(res).values()))["models"]
    types = res.get("robot_types") or list(next(iter(first.values()))["labels"]["wake_by_type"])
    lines = ["| split: scored on | model | samples | overall plain | overall mass-neutral | wake plain | "
             f"wake mass-neutral | wake {' / '.join(types)}, mass-neutral |", "|---|---|---|---|---|---|---|---|"]
    label = {"ours": "ours (blind)", "onboard": "flown on board (blind)",
             "authors": "authors' published (training score)", "zero": "zero"}

    def cell(m, *path):
        a, b = m["labels"], m["other_masses"]
        for p in path:
            a, b = a[p], b[p]
        f = lambda x: "-" if x is None else mean_std(x)  # noqa: E731
        return f"{f(a)} ({f(b)})"

    for name, s in splits(res).items():
        for mname in sorted(s["models"], key=lambda k: (MODEL_ORDER + [k]).index(k)):   # as scored, or read back
            m = s["models"][mname]
            wt = m["labels"]["wake_by_type"]
            lines.append(f"| {name} | {label.get(mname, mname)} | {s['scored']} "
                         f"(wake {_mean(m['labels']['wake']['samples']):.0f}) | "
                         f"{cell(m, 'plain')} | {cell(m, 'neutral')} | {cell(m, 'wake', 'plain')} | "
                         f"{cell(m, 'wake', 'neutral')} | " + " / ".join(
                             "-" if wt[t]["neutral"] is None else
                             (f"{_mean(wt[t]['neutral']):.2f}") for t in types) + " |")
    return "\n".join(lines)


def gains_table(res: dict, split: str, ref: str = "onboard") -> str:
    """Markdown: 1 - ours / ``ref`` on ``split`` (a name of ``splits``), the four headline
    MSEs, under the labels' masses and relabelled with the other convention (negative:
    ours worse)."""
    g = splits(res)[split]["gains"][ref]
    keys = ("overall_plain", "overall_neutral", "wake_plain", "wake_neutral")
    lines = ["| | overall plain | overall mass-neutral | wake plain | wake mass-neutral |", "|---|---|---|---|---|"]
    for conv, masses, fmt in (("labels", "masses_g", ".1f"), ("other_masses", "other_masses_g", "g")):
        name = ("labels with the hover masses" if conv == "labels" else "labels with the authors' masses")
        m = " / ".join(f"{res[masses][t]:{fmt}}" for t in res["robot_types"])
        lines.append(f"| {name} ({m} g) | " + " | ".join(f"{100 * g[conv][k]:.0f} %" for k in keys) + " |")
    return "\n".join(lines)


def write(res: dict, out: Path) -> None:
    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.results import stamp

    atomic_write_bytes(out, json.dumps(stamp(res), indent=1, sort_keys=True).encode())
    atomic_write_bytes(out.with_suffix(".md"), (table(res) + "\n").encode())


def memory(now: dict, past: dict) -> dict:
    """The wake-memory test (issue 52): ours with each neighbour's past states
    (``past``: ``blind`` of a folder built with ``model.history_ms``) against ours without
    (``now``), per blind split: the mass-neutral and plain MSE in the wake and overall,
    and whether the past lowers the wake MSE beyond the seed-to-seed spread (mean + std
    of one below mean - std of the other)."""
    rows = {}
    a, b = splits(now), splits(past)
    for name in a:
        if name not in b:
            continue
        x, y = a[name]["models"]["ours"]["labels"], b[name]["models"]["ours"]["labels"]
        row = {}
        for key, get in (("wake_neutral", lambda r: r["wake"]["neutral"]), ("wake_plain", lambda r: r["wake"]["plain"]),
                         ("overall_neutral", lambda r: r["neutral"]), ("overall_plain", lambda r: r["plain"])):
            u, v = get(x), get(y)
            row[key] = {"now": u, "with_past": v}
        w = row["wake_neutral"]
        sd = lambda r: r["std"] if isinstance(r, dict) else 0.0  # noqa: E731
        row["wake_lower_beyond_spread"] = bool(_mean(w["with_past"]) + sd(w["with_past"]) < _mean(w["now"]) - sd(w["now"]))
        rows[name] = row
    return rows


def memory_rows(doc: dict) -> dict:
    """The rows (blind split -> row) of ``memory``'s output or of the memory.json that
    ``ns2 real memory`` writes (beside them: lags_ms, provenance)."""
    return {k: v for k, v in doc.items() if isinstance(v, dict) and "wake_neutral" in v}


def memory_table(rows: dict, lags) -> str:
    f = mean_std
    rows = memory_rows(rows)
    lines = [f"| blind split | wake, mass-neutral: now / with the past {lags} ms | wake, plain | overall, mass-neutral "
             "| lower in the wake beyond the seeds' spread |", "|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {f(r['wake_neutral']['now'])} / {f(r['wake_neutral']['with_past'])} | "
                     f"{f(r['wake_plain']['now'])} / {f(r['wake_plain']['with_past'])} | "
                     f"{f(r['overall_neutral']['now'])} / {f(r['overall_neutral']['with_past'])} | "
                     f"{'yes' if r['wake_lower_beyond_spread'] else 'no'} |")
    return "\n".join(lines)
