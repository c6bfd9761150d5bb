"""On-board adaptation judged on real flights, causally, on the blind splits (issue 53
item 4; docs/adaptation.md, "Judged on real flights").

Every robot of every flight of a blind split (the held-out flights with the networks
trained without them; each collection left out with the networks trained without it)
is replayed in time order through the **host C build** of the on-board label and
adaptation (``ns2host.onboard.run_host``: ``ns2_label_step`` then ``ns2_adapt_step``
at every 100 Hz tick, exactly the app's calls), from its logged sensors (vertical
velocity and position, attitude, motor PWM, battery: the label and its sanity flags
as the app computes them, with the vehicle file's mass of the labels' convention,
``real.toml``).  The law's other inputs at each tick:

* **NN**: the split's checkpoint's prediction for that sample in float32 (torch, the
  very predictions of ``ns2 real blind``; the export equals it within float32
  rounding, docs/real-flights.md section 8);
* **wake flag**: the app's ``n_used > 0`` (a robot neighbour inside the interaction
  volume: the data set's robot neighbour rows of the sample).

A robot's flight is one sequence from its first sample (the take-off reset: the app
resets the adaptation on the ground).  The cuts of the data set (ground touches,
impacts, log gaps: docs/real-flights.md section 4) split a flight into pieces; between
two pieces one tick with non-finite inputs is replayed: the label's history and the NN
history restart (label BAD_INPUT, NN BAD_INPUT), theta and P are held, as the app holds
them through a stretch it cannot learn from.  Ticks of a piece that are not samples
(the label stencil's two ticks at either end) carry a non-finite NN (no pairing, no
update).

Scores (``realscore.score``, the blind tables' yardsticks, on the samples the blind
tables score): static (NN alone) and adapted (the C's output f = NN + term), plain and
mass-neutral, overall, in the wake (``realscore.WAKE``), per receiving type and per
scenario, with the labels' masses (``real.toml``, 32.1 / 62.5 g).

Laws (``variants``, every one the C with its parameters; the app's wake flag
``n_used > 0`` is always passed, as the pilot passes it): the default (bias alone, the
app's parameters: only |NN| > wakeG stops updates, ``gate_neighbours`` 0), the
neighbour gate (``gate_neighbours`` 1: the flag stops updates too, the default before
this judgement), bias + scale (``scale_max`` ``SCALE_MAX``), the forgetting factor
(``FORGETS``), wakeG (``WAKE_G``), and Neural-Fly's last-layer basis psi = [1, rho's last
hidden layer] (``rls_last_layer``: float64 RLS in Python only, gated exactly as the C's
default run; ``LAST_LAYER``).  Every law runs on the held-out flights; the best bias law
and the best last-layer law there (plain overall MSE) are judged on the collections left
out beside the default, the neighbour gate and bias + scale: nothing is chosen on the
split it is judged on.

The mass test (``mass_offset``): each robot's config 3 g lighter than the robot (the
label cfg's mass - 3 g: every on-board label moves by -3 g times the load factor, the
scores' labels relabelled exactly alike), from take-off (C) and as a step in the middle
of each robot's flight (the float32 reference, bit for bit the C): the time until the
adapted term differs from the unperturbed run's by -3 +- ``RECOVER_G`` g for good.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ns2codegen.onboard import ADAPT_UPDATED, AdaptCfg, LabelCfg, adapt_f32
from ns2paper.collection import COLLECTIONS

from .blind import ONBOARD_COLLECTION, load_samples, predictions
from .real import AUTHORS_MASSES_G, RealDataError
from .realscore import gain, relabel, score

SCALE_MAX = 0.5
FORGETS = (0.98, 0.99, 0.995, 0.998, 0.999)
WAKE_G = (5.0, 2.0)            # wakeG other than the default's 15 g
NEIGHBOUR_GATE = "bias, neighbour gate (gateNbr 1)"   # the app's wake flag stops updates too
LAST_LAYER = ((0.995, 1.0), (0.999, 1.0), (0.999, 0.1), (0.999, 0.01), (0.9995, 0.01))   # (forget, p0)
OFFSET_G, RECOVER_G = 3.0, 0.5
GOAL = {"held_out_flights": 0.15, "collection_left_out": 0.30}


@dataclass
class Track:
    """One robot of one flight, its pieces joined in time order with one separator tick
    of non-finite inputs between pieces: the raw tick arrays, which tick each of its
    samples is (``tick``) and their indices in the data set (``samples``)."""
    name: str
    robot_type: str
    h_s: float
    vz: np.ndarray
    z: np.ndarray
    q: np.ndarray
    pwm: np.ndarray
    battery_V: np.ndarray
    tick: np.ndarray
    samples: np.ndarray
    t_s: np.ndarray        # flight clock of each tick (NaN on separators)

    def __len__(self) -> int:
        return len(self.vz)


def tracks(cfg, flights: list, info: dict) -> list[Track]:
    """Every robot track of ``flights`` (the data set's flights, in its order); the samples'
    times must equal ``info``'s (else the flights are not the data set's)."""
    from ns2codegen.data.from_logs import labelled_steps

    parts: dict = {}
    n = 0
    for fl, i, steps, _ in labelled_steps(cfg, flights):
        rid = f"{fl.name}#{fl.robots[i] if fl.robots else i}"
        k = len(steps)
        if not np.allclose(fl.t[steps], info["t_s"][n:n + k]):
            raise RealDataError(f"{fl.name}: the flights read are not those of the data set (times differ)")
        parts.setdefault(rid, []).append((fl, i, steps, np.arange(n, n + k)))
        n += k
    if n != len(info["t_s"]):
        raise RealDataError(f"{n} samples in the flights read, {len(info['t_s'])} in the data set")
    out = []
    nan4 = np.full((1, 4), np.nan)
    for rid, ps in parts.items():
        ps.sort(key=lambda p: p[0].t[0])
        cols: dict = {k: [] for k in ("vz", "z", "q", "pwm", "battery_V", "t_s")}
        tick, samples, base = [], [], 0
        for j, (fl, i, steps, idx) in enumerate(ps):
            if j:
                for k, v in (("vz", [np.nan]), ("z", [np.nan]), ("q", nan4), ("pwm", nan4), ("battery_V", [np.nan]),
                             ("t_s", [np.nan])):
                    cols[k].append(np.asarray(v))
                base += 1
            for k, v in (("vz", fl.v[:, i, 2]), ("z", fl.p[:, i, 2]), ("q", fl.q[:, i]), ("pwm", fl.pwm[:, i]),
                         ("battery_V", fl.battery_V[:, i]), ("t_s", fl.t)):
                cols[k].append(np.asarray(v, float))
            tick.append(base + steps)
            samples.append(idx)
            base += len(fl.t)
        fl0 = ps[0][0]
        out.append(Track(rid, fl0.types[ps[0][1]], float(np.median(np.diff(fl0.t))),
                         *(np.concatenate(cols[k]) for k in ("vz", "z", "q", "pwm", "battery_V")),
                         np.concatenate(tick), np.concatenate(samples), np.concatenate(cols["t_s"])))
    return out


def robot_neighbours(ds) -> np.ndarray:
    """Per sample, the robot neighbours the prediction uses (the app's ``n_used``)."""
    robot = ds.nbr_type < len(ds.neighbor_types) - 1     # robot types first, the environment last (Config)
    sample_of = np.repeat(np.arange(len(ds)), np.diff(ds.nbr_offsets))
    return np.bincount(sample_of[robot], minlength=len(ds))


def label_cfg(cfg, tr: Track, mass_delta_g: float | dict = 0.0) -> LabelCfg:
    """The on-board label's config of the track's robot type, its mass moved by
    ``mass_delta_g`` (g, or a dict by robot type)."""
    veh = dict(cfg.vehicle(tr.robot_type))
    veh["mass_g"] = veh["mass_g"] + (mass_delta_g[tr.robot_type] if isinstance(mass_delta_g, dict) else mass_delta_g)
    return LabelCfg.of_vehicle(veh, h_s=tr.h_s)


def track_ticks(tr: Track, nn_g: np.ndarray, wake: np.ndarray, acfg: AdaptCfg):
    """The track's ticks for the host C (``ns2host.onboard.Ticks``): ``nn_g``, ``wake``
    per sample of the data set at the samples' ticks (NN non-finite elsewhere), the
    reset at take-off."""
    from ns2host import onboard as host

    nn = np.full(len(tr), np.nan)
    nn[tr.tick] = nn_g[tr.samples]
    wk = np.zeros(len(tr), bool)
    wk[tr.tick] = wake[tr.samples]
    reset = np.zeros(len(tr), bool)
    reset[0] = True
    return host.ticks(tr.vz, tr.z, tr.q, tr.pwm, tr.battery_V, nn, acfg, reset, wk)


def replay(gen_dir, cfg, tr: Track, nn_g: np.ndarray, wake: np.ndarray, acfg: AdaptCfg,
           mass_delta_g: float | dict = 0.0) -> dict:
    """One track through the host C (label and adaptation); returns the C's outputs per
    tick (``ns2host.onboard.run_host``)."""
    from ns2host import onboard as host

    return host.run_host(gen_dir, label_cfg(cfg, tr, mass_delta_g), track_ticks(tr, nn_g, wake, acfg))


def rls_last_layer(tr: Track, nn_g: np.ndarray, feats: np.ndarray, c: dict, forget: float, p0: float,
                   fa_max_g: float = AdaptCfg().fa_max_g) -> np.ndarray:
    """Neural-Fly's last-layer basis: f = NN + sat(theta^T [1, h]), h rho's last hidden
    layer, theta by float64 RLS with forgetting ``forget`` on the C's label, updated
    exactly where the C's run ``c`` updated (the same gating: sane label, no wake,
    history), P = p0 I at take-off (p0: how far from the trained last layer it may move),
    its trace capped at 10 p0 per parameter (scaled down as a whole: P stays positive
    definite).  Returns f per sample of the track (in ``tr.samples`` order)."""
    T = len(tr)
    n = feats.shape[1] + 1
    psi = np.zeros((T, n))
    psi[tr.tick, 0] = 1.0
    psi[tr.tick, 1:] = feats[tr.samples]
    nn = np.full(T, np.nan)
    nn[tr.tick] = nn_g[tr.samples]
    theta, P = np.zeros(n), np.eye(n) * p0
    lam, cap = float(forget), 10.0 * p0 * n
    upd = np.flatnonzero((c["adapt_status"] & ADAPT_UPDATED) != 0)
    thetas = np.zeros((len(upd), n))
    for j, t in enumerate(upd):
        x = psi[t - 2]
        Px = P @ x
        k = Px / (lam + x @ Px)
        theta = theta + k * (float(c["label_g"][t]) - nn[t - 2] - theta @ x)
        P = (P - np.outer(k, Px)) / lam
        P = 0.5 * (P + P.T)
        tr_p = np.trace(P)
        if tr_p > cap:
            P *= cap / tr_p
        thetas[j] = theta
    # theta in use at each tick: that of the last update at or before it
    last = np.searchsorted(upd, np.arange(T), side="right") - 1
    th = np.where((last >= 0)[:, None], thetas[np.maximum(last, 0)] if len(upd) else 0.0, 0.0)
    term = np.clip(np.einsum("ij,ij->i", th, psi), -fa_max_g, fa_max_g)
    return (nn + term)[tr.tick]


def last_hidden(checkpoint: Path, ds, nn: np.ndarray) -> np.ndarray:
    """rho's last hidden layer (after its ReLU) of every sample, float32 [N, width]; its
    last linear layer of these equals the checkpoint's predictions ``nn`` (checked)."""
    import torch

    from ns2codegen.checkpoint import load_checkpoint
    from ns2codegen.train import Batched

    ck = load_checkpoint(checkpoint)
    model = ck.model()
    b = Batched.of(ds)
    b.nbr_state = torch.from_numpy(np.ascontiguousarray(ds.nbr_state[:, :ck.cfg.input_dim]))
    width = model.rho[0].layers[-1].in_features
    out, pred = np.zeros((len(ds), width), np.float32), np.zeros(len(ds), np.float32)
    with torch.no_grad():
        for s in range(0, len(ds), 8192):
            idx = torch.arange(s, min(s + 8192, len(ds)))
            rt, so, nt, ns, _ = b.batch(idx)
            h = ns.new_zeros((len(idx), model.hidden))
            for k in range(model.num_neighbor_types):
                rows = torch.nonzero(nt == k).squeeze(1)
                if rows.numel():
                    h = h.index_add(0, so[rows], model.phi[k](ns[rows]))
            for r in range(model.num_robot_types):
                rows = torch.nonzero(rt == r).squeeze(1)
                x = h[rows]
                for layer in model.rho[r].layers[:-1]:
                    x = torch.relu(layer(x))
                out[s + rows.numpy()] = x.numpy()
                pred[s + rows.numpy()] = model.rho[r].layers[-1](x).squeeze(1).numpy()
    if not np.allclose(pred, nn, atol=1e-4):
        raise AssertionError(f"{checkpoint}: rho's last layer of its last hidden layer is not its prediction "
                             f"({float(np.abs(pred - nn).max())} g apart)")
    return out


def recovery_times(tr: Track, d_term: np.ndarray, start_tick: int, target_g: float, tol_g: float) -> float | None:
    """Seconds from ``start_tick`` until the difference of the adapted terms ``d_term``
    (per tick) is within ``tol_g`` of ``target_g`` at every later sample tick of the
    track; None if it never is for good."""
    ticks = tr.tick[tr.tick >= start_tick]
    bad = np.abs(d_term[ticks] - target_g) > tol_g
    if bad[-1]:
        return None
    last_bad = np.flatnonzero(bad)
    first_ok = ticks[last_bad[-1] + 1] if last_bad.size else ticks[0]
    return round(float(tr.t_s[first_ok] - tr.t_s[start_tick]), 3)


def _stats(xs: list) -> dict:
    got = np.array([x for x in xs if x is not None], float)
    return {"robots": len(xs), "never": int(sum(x is None for x in xs)),
            **({"median_s": round(float(np.median(got)), 2), "p90_s": round(float(np.percentile(got, 90)), 2),
                "max_s": round(float(got.max()), 2)} if got.size else {})}


class Split:
    """A blind split's data: the data set, its sample table, the scored samples (those
    of ``ns2 real blind``), the robot tracks, the wake flag."""

    def __init__(self, ds, info: dict, robot_tracks: list[Track], onboard: bool):
        self.ds, self.info, self.tracks = ds, info, robot_tracks
        self.wake = robot_neighbours(ds) > 0
        ob = info["onboard_g"]
        self.keep = np.isfinite(ob) & (ob != 0.0) if onboard else np.ones(len(ds), bool)

    @classmethod
    def load(cls, d: Path, key: str, cfg, flights: list, onboard: bool) -> "Split":
        """``key.npz`` of ``ns2 real data``'s folder ``d``, its sample table, and its robots'
        tracks from ``flights`` (every flight read; those of the data set are taken)."""
        from ns2codegen.data.dataset import Dataset

        ds, info = Dataset.load(d / f"{key}.npz"), load_samples(d / f"{key}_samples.npz")
        names = set(info["flight_names"])
        return cls(ds, info, tracks(cfg, [f for f in flights if f.name in names], info), onboard)

    def score(self, pred: np.ndarray, label: np.ndarray | None = None, types=None) -> dict:
        k = self.keep
        lab = self.ds.label_g if label is None else label
        sub = {n: (v[k] if isinstance(v, np.ndarray) and len(v) == len(k) else v) for n, v in self.info.items()}
        return score(lab[k], pred[k], sub, self.ds.robot_type[k], types, self.ds.scenario[k],
                     self.ds.scenario_names)

    def run(self, gen_dir, cfg, nn: np.ndarray, acfg: AdaptCfg,
            mass_delta_g: float | dict = 0.0) -> tuple[np.ndarray, list]:
        """The C's adapted prediction per sample and its outputs per track (the app's wake
        flag passed; whether it stops updates is the law's ``gate_neighbours``)."""
        out, runs = np.zeros(len(self.ds)), []
        for tr in self.tracks:
            c = replay(gen_dir, cfg, tr, nn, self.wake, acfg, mass_delta_g)
            out[tr.samples] = c["out_g"][tr.tick]
            runs.append(c)
        return out, runs

    def last_layer(self, nn: np.ndarray, feats: np.ndarray, runs: list, forget: float, p0: float) -> np.ndarray:
        out = np.zeros(len(self.ds))
        for tr, c in zip(self.tracks, runs):
            out[tr.samples] = rls_last_layer(tr, nn, feats, c, forget, p0)
        return out


def mass_offset(gen_dir, cfg, sp: Split, nn: np.ndarray, base_runs: list, acfg: AdaptCfg, types) -> dict:
    """The 3 g test on a split (module docstring) of the law ``acfg`` (``base_runs`` its
    unperturbed runs): scores with the offset, and
    recovery times from take-off (C) and from a step in the middle of each robot's flight."""
    masses = {t: cfg.vehicle(t)["mass_g"] for t in types}
    lighter = {t: m - OFFSET_G for t, m in masses.items()}
    label = relabel(sp.ds.label_g, sp.info, sp.ds.robot_type, masses, lighter, types)
    adapted, runs = sp.run(gen_dir, cfg, nn, acfg, mass_delta_g=-OFFSET_G)
    takeoff, step = [], []
    for tr, c0, c1 in zip(sp.tracks, base_runs, runs):
        takeoff.append(recovery_times(tr, c1["term_g"] - c0["term_g"], int(tr.tick[0]), -OFFSET_G, RECOVER_G))
        mid = int(tr.tick[len(tr.tick) // 2])
        lab = c0["label_g"].copy()
        valid = np.flatnonzero(np.arange(len(tr)) >= mid + 2)       # labels of samples from the step on
        lab[valid] = (lab[valid] - np.float32(OFFSET_G)).astype(np.float32)
        t = track_ticks(tr, nn, sp.wake, acfg)
        r = adapt_f32(acfg, t.nn_g, t.wake, lab, c0["label_status"], t.reset)
        if not np.array_equal(r["term_g"][:mid + 2].view(np.uint32), c0["term_g"][:mid + 2].view(np.uint32)):
            raise AssertionError(f"{tr.name}: the float32 reference differs from the C before the step")
        step.append(recovery_times(tr, r["term_g"] - c0["term_g"], mid, -OFFSET_G, RECOVER_G))
    share = [float(sp.wake[tr.samples].mean()) for tr in sp.tracks]
    some = [i for i, w in enumerate(share) if w < 0.5]
    return {"offset_g": -OFFSET_G, "tolerance_g": RECOVER_G,
            "static": sp.score(nn, label, types), "adapted": sp.score(adapted, label, types),
            "recovery_from_takeoff": _stats(takeoff), "recovery_from_step_mid_flight": _stats(step),
            "flag_under_half_the_time": {"recovery_from_takeoff": _stats([takeoff[i] for i in some]),
                                         "recovery_from_step_mid_flight": _stats([step[i] for i in some])},
            "per_robot": {tr.name: {"from_takeoff_s": a, "from_step_s": b, "wake_flag_share": round(w, 3),
                                    "updates": int(((c["adapt_status"] & ADAPT_UPDATED) != 0).sum())}
                          for tr, a, b, w, c in zip(sp.tracks, takeoff, step, share, base_runs)}}


def last_layer_cost(width: int) -> dict:
    """What the last-layer law would add on board, counted (no C exists): n = width + 1
    parameters; per update P x (n^2 multiply-adds), x^T P x, the gain, the error and theta
    (4 n), P's symmetric half (n (n + 1) / 2 multiply-adds and as many scalings by
    1 / lambda); per tick the term (n); memory P's half, theta and three ticks of psi
    (the label's delay), float32.  The bias law's own update: a handful of operations."""
    n = width + 1
    half = n * (n + 1) // 2
    return {"parameters": n, "multiply_adds_per_update": n * n + 4 * n + 2 * half, "multiply_adds_per_tick": n,
            "memory_bytes": 4 * (half + n + 3 * n), "P_floats_symmetric_half": half}


def variants() -> dict:
    """name -> ("c", AdaptCfg overrides) or ("last_layer", forget, p0): every law tried on
    the held-out flights."""
    v = {"bias": ("c", {}), NEIGHBOUR_GATE: ("c", {"gate_neighbours": 1}),
         "bias + scale": ("c", {"scale_max": SCALE_MAX})}
    v.update({f"bias, wakeG {g}": ("c", {"wake_g": g}) for g in WAKE_G})
    v.update({f"bias, forget {f}": ("c", {"forget": f}) for f in FORGETS if f != AdaptCfg().forget})
    v.update({f"last layer, forget {f}, p0 {p}": ("last_layer", f, p) for f, p in LAST_LAYER})
    return v


def adaptation(data_dir, gen_dir, root, seeds: int = 3, collections=None, held_out: bool = True,
               choose_on: str | None = None, progress=None) -> dict:
    """The experiment (module docstring) on ``ns2 real data``'s folder ``data_dir`` with
    the blind splits' networks, the logs unpacked under ``root`` and the host build of
    the export ``gen_dir`` (any export: the adaptation's C does not depend on the
    network).  Every variant runs on the held-out flights; on the collections left out
    the default, bias + scale, and the best other bias law and last-layer law of the
    held-out flights (chosen there, judged here).  Without the held-out flights, with
    ``choose_on`` (a collection key) that collection left out takes their place (every
    law and the 3 g test there, the laws chosen there judged on the others)."""
    from ns2codegen.config import Config

    from .real import read_collections

    d = Path(data_dir)
    cfg = Config.load(d / "real.toml")
    types = cfg.robot_types
    say = progress or (lambda s: None)
    keys = [c.key for c in COLLECTIONS if collections is None or c.key in collections]
    unknown = sorted((set(collections or ()) | ({choose_on} if choose_on else set())) - {c.key for c in COLLECTIONS})
    if unknown:
        raise RealDataError(f"collection {unknown[0]}: not one of {', '.join(c.key for c in COLLECTIONS)}")
    flights, _ = read_collections(cfg, root)
    base = AdaptCfg()
    every = variants()
    masses = {t: cfg.vehicle(t)["mass_g"] for t in types}
    out = {"masses_g": masses, "other_masses_g": AUTHORS_MASSES_G, "robot_types": types,
           "last_layer_cost": last_layer_cost(cfg.model["width"]),
           "law": base.as_dict(), "variants": {k: list(v[1:]) for k, v in every.items()}, "goal": GOAL,
           "nn": "the checkpoint in float32 (torch), the predictions of ns2 real blind",
           "labels": "the host C's on-board label from the logged sensors, masses of real.toml; "
                     "scored against the data set's labels (the pipeline's, same masses)", "splits": {}}

    def one_split(name, key, ckdir, names, onboard, mass_test):
        ckpts = sorted((d / ckdir).glob("H-20-seed*.pt"))[:seeds]
        if not ckpts:
            raise RealDataError(f"{d / ckdir}: no trained network (make real trains them)")
        sp = Split.load(d, key, cfg, flights, onboard)
        res = {"samples": int(len(sp.ds)), "scored": int(sp.keep.sum()), "robots": len(sp.tracks),
               "wake_flag_share": round(float(sp.wake.mean()), 4),
               "checkpoints": [str(c) for c in ckpts], "seeds": []}
        for ck in ckpts:
            say(f"{name}: {ck.name}")
            nn = predictions(ck, sp.ds).astype(np.float32).astype(np.float64)
            row = {"static": sp.score(nn, types=types), "variants": {}}
            adapted, runs = sp.run(gen_dir, cfg, nn, base)
            row["updates"] = sum(int(((c["adapt_status"] & ADAPT_UPDATED) != 0).sum()) for c in runs)
            feats = None
            for v in names:
                kind, *par = every[v]
                if v == "bias":
                    pred = adapted
                elif kind == "c":
                    pred = sp.run(gen_dir, cfg, nn, replace(base, **par[0]))[0]
                else:
                    feats = last_hidden(ck, sp.ds, nn) if feats is None else feats
                    pred = sp.last_layer(nn, feats, runs, *par)
                row["variants"][v] = sp.score(pred, types=types)
            # the authors' masses (32 / 67 g): the on-board label and the scores' labels alike
            other = relabel(sp.ds.label_g, sp.info, sp.ds.robot_type, masses, AUTHORS_MASSES_G, types)
            delta = {t: AUTHORS_MASSES_G[t] - masses[t] for t in types}
            moved = sp.run(gen_dir, cfg, nn, base, mass_delta_g=delta)[0]
            row["other_masses"] = {"static": sp.score(nn, other, types), "bias": sp.score(moved, other, types)}
            if mass_test:
                row["mass_offset"] = mass_offset(gen_dir, cfg, sp, nn, runs, base, types)
                for v in [NEIGHBOUR_GATE] + [f"bias, wakeG {g}" for g in WAKE_G]:   # the other gates
                    law = replace(base, **every[v][1])
                    row[f"mass_offset, {v}"] = mass_offset(gen_dir, cfg, sp, nn, sp.run(gen_dir, cfg, nn, law)[1],
                                                           law, types)
            row["gain"] = {v: gain(s, row["static"]) for v, s in row["variants"].items()}
            res["seeds"].append(row)
        return res

    chosen = []
    if held_out:
        info = load_samples(d / "heldout_samples.npz")
        june = all(n.startswith(ONBOARD_COLLECTION) for n in info["flight_names"])
        held = one_split("held-out flights", "heldout", "heldout", list(every), june, True)
        out["splits"]["held_out_flights"] = held
        out["chosen_on"] = "held_out_flights"
        chosen = choose(held, every)
    elif choose_on is not None:        # no held-out networks: the laws chosen on one collection left out
        name = f"collection {choose_on} left out"
        out["splits"][name] = one_split(name, f"c-{choose_on}", f"loco-{choose_on}", list(every),
                                        choose_on == ONBOARD_COLLECTION, True)
        out["chosen_on"] = name
        chosen = choose(out["splits"][name], every)
    out["chosen"] = chosen
    for key in keys:
        if not held_out and key == choose_on:
            continue
        names = list(dict.fromkeys(["bias", NEIGHBOUR_GATE, "bias + scale"] + chosen))
        out["splits"][f"collection {key} left out"] = one_split(
            f"{key} left out", f"c-{key}", f"loco-{key}", names, key == ONBOARD_COLLECTION, False)
    out["verdict"] = verdict(out)
    return out


def choose(split: dict, every: dict) -> list[str]:
    """On this split (the held-out flights: never the one it is judged on), the bias law
    and the last-layer law with the lowest mean plain overall MSE over the seeds."""
    def mean_of(v):
        return float(np.mean([r["variants"][v]["plain"] for r in split["seeds"]]))
    return [min((v for v in every if every[v][0] == kind), key=mean_of) for kind in ("c", "last_layer")]


def verdict(res: dict) -> dict:
    """Per split, law (the default and those chosen) and seed: the gain on plain overall
    MSE against the goal (``GOAL``), and whether it is never worse in the wake (plain and
    mass-neutral)."""
    out = {}
    for name, s in res["splits"].items():
        need = GOAL["held_out_flights"] if name == "held_out_flights" else GOAL["collection_left_out"]
        out[name] = {}
        for law in dict.fromkeys(["bias", NEIGHBOUR_GATE] + res.get("chosen", [])):
            rows = []
            for r in s["seeds"]:
                g = r["gain"][law]
                rows.append({"overall_plain_gain": g["overall_plain"], "goal": need,
                             "met": bool(g["overall_plain"] >= need),
                             "wake_not_worse": bool(g["wake_plain"] >= 0 and g["wake_neutral"] >= 0)})
            out[name][law] = rows
    return out


def _m(xs) -> str:
    a = np.array([x for x in xs if x is not None], float)
    return "-" if not a.size else (f"{a.mean():.2f} +- {a.std():.2f}" if a.size > 1 else f"{a[0]:.2f}")


def _pct(xs) -> str:
    a = 100 * np.array(xs, float)
    return f"{a.mean():+.0f} %" + (f" ({', '.join(f'{x:+.0f}' for x in a)})" if a.size > 1 else "")


def table(res: dict) -> str:
    """Markdown: per split, static and each law's MSE (mean +- std over seeds) and how
    much lower than static it is (mean, and per seed)."""
    names = {"held_out_flights": "whole held-out flights"}
    lines = ["| split | law | overall plain | overall mass-neutral | wake plain | wake mass-neutral | "
             "lower than static: overall plain (per seed) | wake plain | wake mass-neutral |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, s in res["splits"].items():
        rows = s["seeds"]
        for v in ["static"] + list(rows[0]["variants"]):
            sc = [r["static"] if v == "static" else r["variants"][v] for r in rows]
            cells = [_m([x["plain"] for x in sc]), _m([x["neutral"] for x in sc]),
                     _m([x["wake"]["plain"] for x in sc]), _m([x["wake"]["neutral"] for x in sc])]
            gains = ["", "", ""] if v == "static" else \
                [_pct([r["gain"][v][k] for r in rows]) for k in ("overall_plain", "wake_plain", "wake_neutral")]
            label = {"static": "static (NN alone)", "bias": "bias (the default law)"}.get(v, v)
            lines.append(f"| {names.get(name, name)} | {label} | " + " | ".join(cells + gains) + " |")
    return "\n".join(lines)


def by_type_table(res: dict) -> str:
    """Markdown: static / adapted (default law) MSE plain, in the wake per receiving type
    and per scenario, mean over seeds."""
    types = res["robot_types"]
    lines = ["| split | " + " | ".join(f"wake {t}: static / adapted" for t in types) +
             " | per scenario (overall plain): static / adapted |", "|---" * (len(types) + 2) + "|"]
    for name, s in res["splits"].items():
        rows = s["seeds"]
        cells = []
        for t in types:
            st = np.mean([r["static"]["wake_by_type"][t]["plain"] or np.nan for r in rows])
            ad = np.mean([r["variants"]["bias"]["wake_by_type"][t]["plain"] or np.nan for r in rows])
            cells.append(f"{st:.2f} / {ad:.2f}")
        sc = rows[0]["static"]["scenario"]
        per = ", ".join(f"{k} {np.mean([r['static']['scenario'][k]['plain'] for r in rows]):.1f} / "
                        f"{np.mean([r['variants']['bias']['scenario'][k]['plain'] for r in rows]):.1f}" for k in sc)
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {per} |")
    return "\n".join(lines)


def other_masses_table(res: dict) -> str:
    """Markdown: static and the default law with the authors' masses (the on-board label and
    the scores' labels alike), mean +- std over seeds."""
    lines = ["| split | static: overall plain | adapted | static: wake plain | adapted | "
             "lower than static, overall plain (per seed) |", "|---|---|---|---|---|---|"]
    for name, s in res["splits"].items():
        rows = [r["other_masses"] for r in s["seeds"]]
        g = [gain(r["bias"], r["static"])["overall_plain"] for r in rows]
        lines.append(f"| {name} | " + " | ".join(
            _m([r[v][k] if k == "plain" else r[v]["wake"]["plain"] for r in rows])
            for k in ("plain", "wake") for v in ("static", "bias")) + f" | {_pct(g)} |")
    return "\n".join(lines)


def mass_table(res: dict) -> str:
    """Markdown: the 3 g test of each seed: MSE with the offset, static / adapted, and the
    recovery times (all robots; robots whose wake flag is up less than half the time)."""
    def rec(x):
        return (f"median {x.get('median_s', '-')} s, 90 % {x.get('p90_s', '-')} s, max {x.get('max_s', '-')} s; "
                f"never {x['never']} of {x['robots']}")
    lines = ["| split, seed, law | overall plain with the offset: static / adapted | recovery from take-off | "
             "from a step mid-flight | the same, robots flagged < 50 % of the time: take-off | step |",
             "|---|---|---|---|---|---|"]
    for name, s in res["splits"].items():
        for k, r in enumerate(s["seeds"]):
            for key in [x for x in r if x.startswith("mass_offset")]:
                m, law = r[key], "the default law" if key == "mass_offset" else key.split(", ", 1)[1]
                h = m["flag_under_half_the_time"]
                lines.append(f"| {name}, seed {k}, {law} | {m['static']['plain']:.2f} / {m['adapted']['plain']:.2f} | "
                             f"{rec(m['recovery_from_takeoff'])} | {rec(m['recovery_from_step_mid_flight'])} | "
                             f"{rec(h['recovery_from_takeoff'])} | {rec(h['recovery_from_step_mid_flight'])} |")
    return "\n".join(lines)


def tables(res: dict) -> str:
    return "\n\n".join((table(res), by_type_table(res), other_masses_table(res), mass_table(res)))


def write(res: dict, out: Path) -> None:
    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.results import stamp

    atomic_write_bytes(out, json.dumps(stamp(res), indent=1, sort_keys=True).encode())
    atomic_write_bytes(out.with_suffix(".md"), (tables(res) + "\n").encode())
