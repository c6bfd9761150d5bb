"""The paper's own flights (issue 22): the Neural-Swarm2 authors' uSD logs of the
16 June 2020 collection -> aligned flights -> labels -> data sets, with every step
reported (``make real``, ``ns2 real``; docs/real-flights.md).

* ``unpack``: the three tarballs of ``../shared/neural-swarm-data`` under ``build/``
  (never committed: no licence), and the collection's ``flights.toml``
  (``ns2paper.collection``).
* ``hover_masses``: "hover thrust equals weight": the median thrust through psi_1 (with
  the motor delay) of each robot type in hover stretches far from neighbours and the
  ground is its mass for the labels (f_a = 0 there by definition); both vehicle
  blocks are evaluated, so the data say which block belongs to which type.
* ``build``: the data sets, all flights (the paper's random piece split happens in
  training) and whole flights held out (``HELD_OUT``: every fifth flight of each
  scenario), with a JSON report: alignment per flight, what was cut and why, label
  statistics per type and scenario against the on-board ``ctrlFa.Faz``.
"""
from __future__ import annotations

import copy
import json
import tarfile
from pathlib import Path

import numpy as np

from ns2codegen.config import Config, dump_toml
from ns2codegen.data.from_logs import Flight, flight_queries, flights_to_dataset, labelled_steps, sample_info
from ns2codegen.data.labels import motor_forces
from ns2codegen.errors import Ns2Error
from ns2codegen.fileio import atomic_write_bytes
from ns2codegen.results import stamp
from ns2codegen.logs.align import logs_to_flights
from ns2codegen.queries import Queries
from ns2codegen.vehicle import G
from ns2paper.collection import COLLECTIONS, write_collection_manifest, write_manifest
from ns2paper.flightstats import alone

TARBALLS = tuple(dict.fromkeys(t for c in COLLECTIONS for t in c.tarballs))
HOVER = {"min_z_m": 0.3, "max_speed_mps": 0.1, "min_horizontal_distance_m": 1.0}
HELD_OUT_EVERY, HELD_OUT_PHASE = 5, 2   # flight k of a scenario (sorted) is held out when k % 5 == 2


class RealDataError(Ns2Error, ValueError):
    """The real-flight data are missing or unusable."""


def unpack(shared: str | Path, dest: str | Path) -> Path:
    """Unpack the tarballs into ``dest`` once (a stamp names their sizes) and write the
    manifests: ``dest/flights.toml`` (16 June 2020, the calibration's flights) and one
    ``flights.toml`` in each collection's folder; returns ``dest``."""
    shared, dest = Path(shared), Path(dest)
    missing = [t for t in TARBALLS if not (shared / t).is_file()]
    if missing:
        raise RealDataError(f"{shared}: missing {', '.join(missing)} (../shared/neural-swarm-data beside the checkout)")
    stamp = dest / ".unpacked"
    key = json.dumps({t: (shared / t).stat().st_size for t in TARBALLS}, sort_keys=True)
    if not (stamp.is_file() and stamp.read_text() == key):
        dest.mkdir(parents=True, exist_ok=True)
        for t in TARBALLS:
            with tarfile.open(shared / t) as tar:
                tar.extractall(dest, filter="data")
        stamp.write_text(key)
    write_manifest(dest)
    for c in COLLECTIONS:
        write_collection_manifest(dest, c)
    return dest


def read_collections(cfg: Config, root: str | Path, keys=None) -> tuple[list[Flight], list[dict]]:
    """Every flight of the collections ``keys`` (default all) under ``root``, aligned and
    cut; flight names ``<collection>/<scenario>/<nn>``, each report with its collection."""
    flights, reports = [], []
    for c in COLLECTIONS:
        if keys is not None and c.key not in keys:
            continue
        fls, reps = logs_to_flights(cfg, Path(root) / c.folder)
        for fl in fls:
            fl.name = f"{c.key}/{fl.name}"
        for r in reps:
            r["name"], r["collection"] = f"{c.key}/{r['name']}", c.key
        flights += fls
        reports += reps
    return flights, reports


def collection_of(name: str) -> str:
    return name.split("/")[0]


def scenario_of(name: str) -> str:
    """``2020-06-16/swap_sl/03`` -> ``2020-06-16/swap_sl``: the unit of the held-out split."""
    return name.rsplit("/", 1)[0]


def is_held_out(name: str, names: list[str]) -> bool:
    """Whole flights held out: every fifth flight of each scenario of each collection
    (fixed, by number)."""
    same = sorted(n for n in names if scenario_of(n) == scenario_of(name))
    return same.index(name) % HELD_OUT_EVERY == HELD_OUT_PHASE


def _alone(fl: Flight, i: int) -> np.ndarray:
    """Hovering alone (HOVER): flightstats.alone with the hover criteria, and slow."""
    return (alone(fl, i, HOVER["min_z_m"], HOVER["min_horizontal_distance_m"])
            & (np.linalg.norm(fl.v[:, i], axis=1) < HOVER["max_speed_mps"]))


def _median(parts: list) -> dict:
    return {"median_g": round(float(np.median(np.concatenate(parts))), 2), "samples": int(sum(len(a) for a in parts))}


def hover_masses(cfg: Config, flights: list[Flight], ids: dict) -> dict:
    """Median hover thrust (g) of each robot type under each type's vehicle block (every
    collection), per collection and type, and per collection and robot under its own
    type's block (``ids``: flight name -> robot ids)."""
    out = {"criteria": HOVER, "by_type": {}, "by_collection": {}, "by_robot": {}}
    per = {(ty, blk): [] for ty in cfg.robot_types for blk in cfg.robot_types}
    per_coll: dict = {}
    per_robot: dict = {}
    for fl in flights:
        h = float(np.median(np.diff(fl.t)))
        coll = collection_of(fl.name)
        for i, ty in enumerate(fl.types):
            if fl.labelled is not None and not fl.labelled[i]:
                continue
            m = _alone(fl, i)
            if not m.any():
                continue
            for blk in cfg.robot_types:
                veh = cfg.vehicle(blk)
                T = motor_forces(fl.pwm[:, i], fl.battery_V[:, i], veh["psi1"], veh["lambda"], h).sum(1) * 1e3 / G
                per[(ty, blk)].append(T[m])
                if blk == ty:
                    per_coll.setdefault(coll, {}).setdefault(ty, []).append(T[m])
                    per_robot.setdefault(coll, {}).setdefault(ids[fl.name][i], []).append(T[m])
    for ty in cfg.robot_types:
        out["by_type"][ty] = {f"block of {blk}": _median(per[(ty, blk)]) for blk in cfg.robot_types if per[(ty, blk)]}
    out["by_collection"] = {c: {ty: _median(a) for ty, a in sorted(d.items())} for c, d in sorted(per_coll.items())}
    out["by_robot"] = {c: {r: _median(a) for r, a in sorted(d.items(), key=lambda x: int(x[0][2:]))}
                       for c, d in sorted(per_robot.items())}
    return out


AUTHORS_MASSES_G = {"small": 32.0, "large": 67.0}   # learning/training.py of aerorobotics/neural-swarm


def _with_masses(cfg: Config, masses: dict) -> Config:
    raw = copy.deepcopy(cfg.raw)
    for t in raw["robot_types"]:
        t["mass_g"] = float(masses[t["name"]])
    return Config.from_dict(raw)


def real_config(cfg: Config, hover: dict) -> Config:
    """``cfg`` with each robot type's mass set to its measured hover thrust (0.1 g) over
    every collection."""
    masses = {}
    for t in cfg.robot_types:
        got = hover["by_type"].get(t, {}).get(f"block of {t}")
        if got is None:
            raise RealDataError(f"no hover stretch of a {t} robot in the logs: cannot measure its mass")
        masses[t] = round(got["median_g"], 1)
    return _with_masses(cfg, masses)


CALIBRATION_COLLECTION = "2020-06-16"   # the flights the simulator is calibrated on (make calibrate)


def collection_config(data_dir: str | Path, key: str = CALIBRATION_COLLECTION) -> tuple[Config, dict]:
    """``real.toml`` of ``ns2 real data``'s folder with each type's mass set to its hover
    thrust in collection ``key`` alone (0.1 g; 16 June 2020: 32.5 g, 63.1 g), and the
    collection's hover medians per robot (``data_report.json``): the labels of one day's
    flights as that day weighed them."""
    d = Path(data_dir)
    for need in (d / "real.toml", d / "data_report.json"):
        if not need.is_file():
            raise RealDataError(f"{need} missing: run `ns2 real data` first")
    try:
        hover = json.loads((d / "data_report.json").read_text())["hover"]
        masses = {t: round(v["median_g"], 1) for t, v in hover["by_collection"][key].items()}
        by_robot = hover["by_robot"][key]
    except (KeyError, ValueError, TypeError, AttributeError) as e:
        raise RealDataError(f"{d / 'data_report.json'}: no hover.by_collection/by_robot of {key} ({e}): "
                            "run `ns2 real data` again") from None
    cfg = Config.load(d / "real.toml")
    return _with_masses(cfg, {t: masses.get(t, cfg.vehicle(t)["mass_g"]) for t in cfg.robot_types}), by_robot


def label_report(cfg: Config, flights: list[Flight]) -> dict:
    """f_a,z label statistics per robot type and scenario, against the on-board prediction."""
    from ns2codegen.data.dataset import scenario_name

    acc: dict = {}
    for fl, i, steps, fa in labelled_steps(cfg, flights):
        ty = fl.types[i]
        sc = scenario_name(cfg.robot_types, ty, [fl.types[j] for j in range(len(fl.types)) if j != i])
        for key in (("type", ty), ("scenario", sc), ("collection", collection_of(fl.name))):
            a = acc.setdefault(key, {"label": [], "onboard": []})
            a["label"].append(fa[steps, 2] * 1e3 / G)
            a["onboard"].append(fl.fa_onboard_g[steps, i])
    out: dict = {"type": {}, "scenario": {}, "collection": {}}
    every = np.concatenate([np.concatenate(a["label"]) for (kind, _), a in acc.items() if kind == "type"])
    out["all"] = {"samples": int(every.size), "rms_g": round(float(np.sqrt(np.mean(every ** 2))), 3),
                  "sqrt_std_of_squares_g": round(float(np.sqrt(np.std(every ** 2))), 3),
                  "mean_g": round(float(every.mean()), 3), "variance_g2": round(float(every.var()), 3)}
    for (kind, name), a in sorted(acc.items()):
        lab, ob = np.concatenate(a["label"]), np.concatenate(a["onboard"])
        both = np.isfinite(ob) & (ob != 0.0)   # 0: no network flown (2019), or before it started
        d = lab[both] - ob[both]
        out[kind][name] = {"samples": int(lab.size), "mean_g": round(float(lab.mean()), 3),
                           "std_g": round(float(lab.std()), 3), "rms_g": round(float(np.sqrt(np.mean(lab ** 2))), 3),
                           "sqrt_std_of_squares_g": round(float(np.sqrt(np.std(lab ** 2))), 3),
                           "onboard_rms_g": round(float(np.sqrt(np.mean(ob[both] ** 2))), 3) if both.any() else None,
                           "label_minus_onboard_rms_g": round(float(np.sqrt(np.mean(d ** 2))), 3) if both.any() else None,
                           "corr_label_onboard": round(float(np.corrcoef(lab[both], ob[both])[0, 1]), 3)
                           if both.sum() > 2 and ob[both].std() > 0 else None}
    return out


def _save_set(out_dir: Path, key: str, cfg: Config, flights: list[Flight], source: str) -> dict:
    """``key.npz`` (the data set) and ``key_samples.npz`` (``sample_info``, for the scores)."""
    import io

    ds = flights_to_dataset(cfg, flights)
    ds.extra = dict(ds.extra, generator="usd-logs", source=source, flights=sorted({f.name for f in flights}))
    ds.save(out_dir / f"{key}.npz")
    info = sample_info(cfg, flights)
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: (np.array(v) if isinstance(v, list) else v) for k, v in info.items()})
    atomic_write_bytes(out_dir / f"{key}_samples.npz", buf.getvalue())
    return {"samples": len(ds), "flights": len({f.name for f in flights})}


def build(root: str | Path, out_dir: str | Path, cfg: Config | None = None) -> dict:
    """Data sets and report from the unpacked collections under ``root`` (see the module
    docstring): out_dir/{all,train,heldout}.npz, per collection ``c-<key>.npz`` and
    ``without-<key>.npz`` (the leave-one-collection-out splits), each with its
    ``_samples.npz``; real.toml (the config with the measured masses), data_report.json.
    Returns the report."""
    cfg = cfg or Config.load(None)
    root, out_dir = Path(root), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    flights, reports = read_collections(cfg, root)
    names = [r["name"] for r in reports]
    ids = {r["name"]: r["robots"] for r in reports}
    hover = hover_masses(cfg, flights, ids)
    rcfg = real_config(cfg, hover)
    atomic_write_bytes(out_dir / "real.toml", dump_toml(rcfg.raw, "ns2codegen config for the real flights: "
                       "default.toml with each robot type's mass measured in hover (experiments/real.py)").encode())
    held = {n for n in names if is_held_out(n, names)}
    sets = {"all": flights, "train": [f for f in flights if f.name not in held],
            "heldout": [f for f in flights if f.name in held]}
    for c in COLLECTIONS:
        sets[f"c-{c.key}"] = [f for f in flights if collection_of(f.name) == c.key]
        sets[f"without-{c.key}"] = [f for f in flights if collection_of(f.name) != c.key]
    save_queries(out_dir / "heldout_queries.npz", flight_queries(rcfg, sets["heldout"]))
    save_queries(out_dir / "all_queries.npz", flight_queries(rcfg, sets["all"]))
    sizes = {key: _save_set(out_dir, key, rcfg, fls, f"aerorobotics/neural-swarm collections ({key})")
             for key, fls in sets.items()}
    report = {"source": "aerorobotics/neural-swarm 48b18511, data/training/ (" +
              ", ".join(c.folder.split("/")[-1] for c in COLLECTIONS) + ")",
              "collections": {c.key: {"folder": c.folder, "robots": c.robots, "not_labelled": c.not_labelled,
                                      "folders": c.folders or "the 2020 naming"} for c in COLLECTIONS},
              "flights": reports, "hover": hover,
              "masses_g": {t: rcfg.vehicle(t)["mass_g"] for t in rcfg.robot_types},
              "authors_masses_g": AUTHORS_MASSES_G,
              "labels": label_report(rcfg, flights), "held_out_flights": sorted(held), "data_sets": sizes,
              "alignment": alignment_summary(reports), "cuts": cut_summary(reports)}
    atomic_write_bytes(out_dir / "data_report.json", json.dumps(stamp(report), indent=1, sort_keys=True).encode())
    return report


def alignment_summary(reports: list[dict]) -> dict:
    """Per method: flights, and for the setpoint events the residual error (ms)."""
    out: dict = {}
    for r in reports:
        m = out.setdefault(r["sync"], {"flights": 0})
        m["flights"] += 1
        e = r.get("alignment_error") or {}
        if e:
            m.setdefault("residual_max_ms", []).append(e["residual_max_ms"])
            m.setdefault("residual_rms_ms", []).append(e["residual_rms_ms"])
            m.setdefault("log_start_error_max_ms", []).append(e["raw_max_ms"])
    for m in out.values():
        for k in ("residual_max_ms", "residual_rms_ms", "log_start_error_max_ms"):
            if k in m:
                a = np.array(m[k])
                m[k] = {"median": round(float(np.median(a)), 2), "max": round(float(a.max()), 2)}
    return out


def cut_summary(reports: list[dict]) -> dict:
    """Seconds cut per reason over the collection, and the flights with ground touches or impacts."""
    total: dict = {}
    flights: dict = {}
    for r in reports:
        for reason, robots in r["cut_s_by_reason_and_robot"].items():
            total[reason] = round(total.get(reason, 0.0) + sum(robots.values()), 2)
            if reason in ("ground touch", "impact"):
                flights.setdefault(reason, []).append(r["name"])
    return {"seconds_by_reason": total, "flights_by_reason": flights,
            "duration_s": round(sum(r["duration_s"] for r in reports), 2),
            "used_s": round(sum(r["used_samples"] for r in reports) / 100.0, 2)}


QUERY_FIELDS = ("robot_type", "p", "v", "n", "nbr_type", "nbr_rel", "past")


def save_queries(path: Path, q: Queries) -> None:
    """The held-out samples as the C API receives them (``flight_queries``), for the C in
    the loop; with ``model.history_ms`` the lagged states and the robots' own past too."""
    import io

    buf = io.BytesIO()
    np.savez(buf, **{k: getattr(q, k) for k in QUERY_FIELDS})
    atomic_write_bytes(path, buf.getvalue())


def load_queries(path: str | Path) -> Queries:
    """A query file of ``save_queries`` (one written before the wake memory has no
    ``past``: a present-state query set)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return Queries(*(z[k] for k in QUERY_FIELDS[:-1]), z["past"] if "past" in z.files else None)
    except (OSError, KeyError, ValueError) as e:
        raise RealDataError(f"{path}: not a query file of `ns2 real data` ({e})") from None


def same_history(queries: Queries, cfg: Config, what) -> None:
    """The queries carry the lags the model sees (``model.history_ms``), else a one-line error."""
    if queries.lags != len(cfg.history_ms) or queries.nbr_rel.shape[-1] != cfg.input_dim:
        raise RealDataError(f"{what}: model.history_ms {cfg.history_ms} but the queries have {queries.lags} history "
                            f"lags: make the data with the same lags (`ns2 real data --history-ms "
                            f"{','.join(map(str, cfg.history_ms)) or '<none>'}`)")


def c_in_the_loop(gen_dir: str | Path, checkpoint: str | Path, queries: Queries, labels_g: np.ndarray) -> dict:
    """Every held-out sample through the exported C (host build), float and fixed point,
    against the Python references bit for bit; |fixed - float| on the real
    distribution; the fixed-point output range against the labels' range."""
    from ns2codegen import reference as ref
    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.quantize import from_checkpoint
    from ns2host.cbuild import CModel

    em = from_checkpoint(load_checkpoint(checkpoint))
    same_history(queries, em.cfg, checkpoint)
    cm = CModel(gen_dir)
    c_f, info_f = cm.predict(queries, fixed=False)
    c_q, info_q = cm.predict(queries, fixed=True)
    r_f, _ = ref.predict_f32(em, queries)
    r_q, _ = ref.predict_q15(em, queries)
    f_bits = np.ascontiguousarray(c_f, np.float32).view(np.uint32) != np.ascontiguousarray(r_f, np.float32).view(np.uint32)
    fixed_g = c_q.astype(np.float64) / 2.0 ** em.q15.out_frac
    d = np.abs(fixed_g - c_f.astype(np.float64))
    lo, hi = -(2.0 ** 15) / 2.0 ** em.q15.out_frac, (2.0 ** 15 - 1) / 2.0 ** em.q15.out_frac
    return {"samples": len(queries), "float_mismatches": int(f_bits.sum()),
            "fixed_mismatches": int((c_q != r_q).sum()),
            "status_nonzero": int((info_f["status"] != 0).sum() + (info_q["status"] != 0).sum()),
            "abs_fixed_minus_float_g": {"mean": float(d.mean()), "p99": float(np.percentile(d, 99)), "max": float(d.max())},
            "fixed_output_range_g": [lo, hi], "label_range_g": [float(labels_g.min()), float(labels_g.max())],
            "float_output_range_g": [float(c_f.min()), float(c_f.max())],
            "labels_inside_fixed_range": bool(labels_g.min() >= lo and labels_g.max() <= hi),
            "neighbours_used_histogram": np.bincount(info_f["n_used"]).tolist()}


def _fmt(r: dict | None, key: str = "mean") -> str:
    return "-" if not r else f"{r[key]:.2f} +- {r['std']:.2f}"


PAPER_TABLE = {"H=20": "6.42 +- 0.18", "H=10": "6.70 +- 0.05", "H=40": "6.63 +- 0.35", "L=3": "6.52 +- 0.17",
               "L=5": "7.21 +- 0.28", "V=without": "7.60"}


def ablation_rows(held: dict, ablations) -> list[tuple]:
    """(key, label, result) of the paper's network without the held-out flights and of every
    ablation (``make real``'s heldout.json and ablation-*.json)."""
    rows = [("H=20", "H = 20, L = 4 (the paper's network)", held["H"]["20"])]
    names = {"H": "H = {}", "L": "L = {}", "V": "{} relative velocity", "P": "{}", "T": "{} deep set", "W": "widths {}"}
    same = {("L", "4"), ("W", "40/25"), ("V", "with"), ("P", "deep set"), ("T", "heterogeneous")}
    for doc in ablations:
        for axis, vals in doc.items():
            if axis in names and isinstance(vals, dict):
                rows += [(f"{axis}={v}", names[axis].format(v), r) for v, r in vals.items() if (axis, v) not in same]
    return rows


def ablation_table(paper: dict, held: dict, *ablations: dict, authors: dict | None = None) -> str:
    """docs/real-flights.md's Table-ablation: the paper's protocol, the ablations scored on the
    held-out flights, the authors' network (training scores)."""
    key = "held_out_flights"
    lines = ["| model | paper (g^2) | validation, paper's random split (g^2) | held-out flights (g^2) |",
             "|---|---|---|---|",
             f"| H = 20, L = 4, every flight, the paper's protocol | 6.42 +- 0.18 | {_fmt(paper['H']['20'])} | - |"]
    for k, label, r in ablation_rows(held, ablations):
        lines.append(f"| {label}, without the held-out flights | {PAPER_TABLE.get(k, '-')} | {_fmt(r)} | "
                     f"{_fmt(r.get(key))} |")
    if authors:
        lines.append(f"| the authors' published network (trained on all their collections, these flights included: "
                     f"training scores), our labels | - | {authors['all_mse']:.2f} (every flight) | "
                     f"{authors['heldout_mse']:.2f} |")
        if "heldout_authors_masses_mse" in authors:
            lines.append(f"| the same, labels with the authors' masses (32 g, 67 g) | - | - | "
                         f"{authors['heldout_authors_masses_mse']:.2f} |")
    return "\n".join(lines)


def summary(out_dir: str | Path) -> dict:
    """The tables of docs/real-flights.md from the JSON of ``make real`` (data_report,
    paper, heldout, ablation, authors, c_check) as summary.json and summary.md."""
    d = Path(out_dir)
    load = lambda n: json.loads((d / n).read_text()) if (d / n).is_file() else None  # noqa: E731
    data, paper, held, authors, cchk = (load(n) for n in ("data_report.json", "paper.json", "heldout.json",
                                                          "authors.json", "c_check.json"))
    abl = [json.loads(f.read_text()) for f in sorted(d.glob("ablation-*.json"))]
    if data is None or paper is None or held is None:
        raise RealDataError(f"{d}: run `make real` first (data_report.json, paper.json, heldout.json)")
    table_md = ablation_table(paper, held, *abl, authors=authors)
    out = {"label_variance_g2": {"all": paper.get("label_variance_g2"), "train": held.get("label_variance_g2")},
           "paper_protocol": paper["H"]["20"], "held_out": {k: r for k, _, r in ablation_rows(held, abl)},
           "authors": authors, "c_check": cchk,
           "data": {k: data[k] for k in ("data_sets", "masses_g", "alignment", "cuts")},
           "labels_all": data["labels"].get("all"), "table_md": table_md}
    out["flights_md"] = flights_table(data["flights"])
    extra = [(d / f).read_text() for f in ("blind.md", "memory.md") if (d / f).is_file()]   # ns2 real blind, memory
    out["blind_md"] = extra
    atomic_write_bytes(d / "summary.json", json.dumps(stamp(out), indent=1).encode())
    atomic_write_bytes(d / "summary.md", (table_md + "\n\n" + "\n".join(extra) + "\n" + out["flights_md"]
                                          + "\n").encode())
    return out


def flights_table(reports: list[dict]) -> str:
    """Per flight: alignment method, clock offsets and measured error, what was cut and why."""
    lines = ["| flight | robots | alignment | offsets (ms) | event residual max (ms) | cut (s): reason robot | used (s) |",
             "|---|---|---|---|---|---|---|"]
    for r in reports:
        e = r.get("alignment_error") or {}
        cuts = "; ".join(f"{why}: " + ", ".join(f"{rid} {sec:g}" for rid, sec in rob.items())
                         for why, rob in sorted(r["cut_s_by_reason_and_robot"].items())) or "-"
        robots = ", ".join(x + (" (not labelled)" if x in r.get("not_labelled", []) else "") for x in r["robots"])
        lines.append(f"| {r['name']} | {robots} | {r['sync']} | "
                     f"{', '.join(f'{o * 1e3:+.1f}' for o in r['clock_offsets_s'])} | "
                     f"{e['residual_max_ms']:.1f}" if e else
                     f"| {r['name']} | {robots} | {r['sync']} | "
                     f"{', '.join(f'{o * 1e3:+.1f}' for o in r['clock_offsets_s'])} | -")
        lines[-1] += f" | {cuts} | {r['used_samples'] / 100.0:.1f} |"
    return "\n".join(lines)


def plots(out_dir: str | Path, checkpoint: str | Path, root: str | Path) -> list[Path]:
    """labels vs the on-board prediction and ours over one real swap; held-out MSE per
    scenario; prediction vs label on the held-out flights."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.train import Batched, evaluate, predict

    d = Path(out_dir)
    ck = load_checkpoint(checkpoint)
    model = ck.model()
    held = Dataset.load(d / "heldout.npz")
    with torch.no_grad():
        pred = predict(model, Batched.of(held)).numpy()
    ev = evaluate(model, held)
    paths = []
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.scatter(held.label_g, pred, s=1, alpha=0.2)
    lim = [float(min(held.label_g.min(), pred.min())), float(max(held.label_g.max(), pred.max()))]
    ax.plot(lim, lim, "k--", lw=1)
    ax.set(xlabel="label f_a,z (g)", ylabel="prediction (g)", title=f"held-out flights: MSE {ev['mse']:.2f} g^2")
    paths.append(d / "pred_vs_label.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    names = sorted(ev["mse_per_scenario"])
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar(names, [ev["mse_per_scenario"][n] for n in names])
    ax.set(ylabel="MSE (g^2)", title="held-out flights: MSE per scenario")
    ax.tick_params(axis="x", rotation=45)
    fig.tight_layout()
    paths.append(d / "mse_per_scenario.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    # one held-out swap: the bottom robot's label, the network flown on board and ours
    rcfg = Config.load(d / "real.toml")
    flights, reports = read_collections(rcfg, root, keys=("2020-06-16",))
    name = next(n for n in json.loads((d / "data_report.json").read_text())["held_out_flights"]
                if n.startswith("2020-06-16/swap_sl/"))
    pieces = [f for f in flights if f.name == name]
    fig, ax = plt.subplots(figsize=(10, 4))
    for fl in pieces:
        i = int(np.argmin(fl.p[:, :, 2].mean(0)))             # the bottom robot
        ds = flights_to_dataset(rcfg, [Flight(**{**fl.__dict__, "labelled": [k == i for k in range(len(fl.types))]})])
        with torch.no_grad():
            ours = predict(model, Batched.of(ds)).numpy()
        t = fl.t[2:-2]
        ax.plot(t, ds.label_g, "k", lw=0.8, label="label" if fl is pieces[0] else None)
        ax.plot(t, fl.fa_onboard_g[2:-2, i], "tab:orange", lw=1, label="on board (authors' network)" if fl is pieces[0] else None)
        ax.plot(t, ours, "tab:blue", lw=1, label="ours (held out)" if fl is pieces[0] else None)
    ax.set(xlabel="t (s)", ylabel="f_a,z (g)", title=f"{name}: the bottom robot")
    ax.legend()
    fig.tight_layout()
    paths.append(d / "swap_labels.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    return paths


def score(checkpoint: str | Path, data_dir: str | Path) -> dict:
    """MSE (g^2) of a checkpoint on every flight, on the held-out flights, and on the
    held-out flights labelled with the authors' masses (for their network)."""
    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.train import evaluate

    model = load_checkpoint(checkpoint).model()
    d = Path(data_dir)
    out = {"checkpoint": str(checkpoint)}
    for key, name in (("all", "all.npz"), ("heldout", "heldout.npz"), ("heldout_authors_masses", "heldout_authors_masses.npz")):
        if (d / name).is_file():
            ev = evaluate(model, Dataset.load(d / name))
            out[f"{key}_mse"] = ev["mse"]
            out[f"{key}_mse_per_scenario"] = ev["mse_per_scenario"]
    return out


def selection_mismatches(gen_dir: str | Path, queries: Queries, ds) -> dict:
    """Issue 29 on the whole collection: the data set's neighbour count of every sample
    against the C's selection (host build, ``info.n_used``) for the same sample; and the
    data set's rows (with ``model.history_ms`` the lagged states too) against the inputs
    the C feeds to phi (``reference.phi_rows``), bit for bit."""
    from ns2codegen.export import export_config
    from ns2codegen.reference import phi_rows
    from ns2host.cbuild import CModel

    cfg = export_config(gen_dir)
    same_history(queries, cfg, gen_dir)
    _, info = CModel(gen_dir).predict(queries, fixed=True)
    ours = np.diff(ds.nbr_offsets) - 1
    if len(ours) != len(queries):
        raise RealDataError(f"{len(queries)} queries for {len(ours)} samples: not the same flights")
    bad = info["n_used"].astype(np.int64) != ours
    sample, types, x = phi_rows(cfg, queries)
    same_rows = np.array_equal(sample, np.repeat(np.arange(len(ours)), np.diff(ds.nbr_offsets))) and \
        np.array_equal(types, ds.nbr_type) and x.shape == ds.nbr_state.shape
    rows_bad = int((x.view(np.uint32) != ds.nbr_state.view(np.uint32)).any(1).sum()) if same_rows \
        else len(ds.nbr_type)
    return {"samples": len(queries), "mismatches": int(bad.sum()),
            "neighbours_used": int(ours.sum()), "status_nonzero": int((info["status"] != 0).sum()),
            "input_rows": len(ds.nbr_type), "input_row_mismatches": rows_bad}
