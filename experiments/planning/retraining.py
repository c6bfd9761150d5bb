"""The planning model retrained on its own flown plans (data aggregation, as DAgger):
plan with the model, fly the plans, add the drones' logs to its training data,
train the next model."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_bytes
from ns2plan.forces import load_force_model
from ns2plan.problem import PlanningError, RRTParams, SCPParams

from .. import margin
from .cases import LIMITS_3D
from .runs import fly_plans, plan_executor, trial_rows


# the planning model trained on its own flown plans too (plan_trained_checkpoint): seeds 2000 + 100 r
# in round r, never an experiment or calibration seed
PLAN_DATA_SEEDS = (2000, 2001, 2002, 2003)
PLAN_DATA_ROUNDS = 2


def training_data_files(checkpoint) -> list:
    """The data sets a checkpoint was trained on (its ``data_files``, kept beside it,
    as default_checkpoint writes them); PlanningError naming the checkpoint and the
    field when they are not there."""
    from ns2codegen.checkpoint import load_checkpoint

    names = load_checkpoint(checkpoint).meta.get("data_files")
    if not isinstance(names, list) or not names:
        raise PlanningError(f"{checkpoint}: data_files: the checkpoint does not list the data it was trained on "
                            "(train it with ns2 plan's default planning model, or plan without --plan-data-rounds)")
    missing = [f for f in names if not (Path(checkpoint).parent / str(f)).is_file()]
    if missing:
        raise PlanningError(f"{checkpoint}: data_files: {missing[0]} is not beside the checkpoint")
    return list(names)


def _trained_on(path: Path, names: list) -> bool:
    """``path`` is a checkpoint trained on exactly the data ``names``."""
    from ns2codegen.checkpoint import load_checkpoint

    return path.is_file() and load_checkpoint(path).meta.get("data_files") == names


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dst, src.read_bytes())


def plan_trained_checkpoint(cfg: Config, checkpoint, gen_dir, held_out: list, scenarios, dims,
                            seeds=PLAN_DATA_SEEDS, rounds: int = PLAN_DATA_ROUNDS, rrt: RRTParams = RRTParams(),
                            scp_params: SCPParams = SCPParams(), workers: int = 2, log=print, keep=None) -> Path:
    """The planning model trained on its own plans too (data aggregation, as DAgger):
    round r measures model r's margin on the held-out flights (ns2exp.margin), plans
    every scenario x dims with it for the round's training seeds (``seeds`` + 100 r,
    never an experiment or calibration seed), flies the plans and adds the drones'
    logs (estimated states, labelled as every simulated flight) to the training data
    of ``checkpoint`` (its ``data_files`` in its folder); model r + 1 is trained on it
    all.  The planner drives each robot to where the model reads lowest; these are
    the states its training flights lacked.  The models and the plans' data sets are
    kept beside ``checkpoint`` (``model_r<r>_<tag>.pt``, ``data_plans_r<r>_<tag>.npz``
    with the round's margin and trials in ``.json`` beside it, the tag a hash of the
    data before the round, the round's scenarios, dims and seeds and its margin) and reused;
    ``keep``: a folder where each round's model and record are also kept the moment they
    are made (the run's ``--runs`` folder: small files, committed for the runs behind
    docs/) and taken from when not beside the checkpoint, so a run continued on another
    machine flies and trains only the rounds after the last kept model (a round's data
    is flown again only when a later model must be trained on it); returns the last model."""
    from ns2codegen.checkpoint import save_checkpoint
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.data.from_logs import flights_to_dataset
    from ns2codegen.train import train

    folder = Path(checkpoint).parent
    keep = Path(keep) if keep is not None else None
    names = training_data_files(checkpoint)
    todo = []                  # (round, model, tasks, margin, data file) of each round, its data flown when needed

    def fly_round(r, ck, tasks, m, data):
        log(f"plan data round {r}: {len(tasks)} NN plans of {ck.name} with its held-out margin {m}")
        with plan_executor(ck, gen_dir, workers) as ex:
            done = fly_plans(ck, gen_dir, tasks, m, rrt, scp_params, ex)
        rows = trial_rows(cfg, tasks, done)
        ok = [t for t in rows if t["planned"]]
        log(f"  planned {len(ok)}/{len(rows)}, {sum(t['over_limit'] for t in ok)} over a limit in flight")
        flights = [f for _, _, f in done if f is not None]
        if not flights:
            raise PlanningError(f"plan data round {r}: no plan of {ck.name} in {len(tasks)} trials to train on")
        flights_to_dataset(cfg, flights).save(data)
        record = data.with_suffix(".json")
        atomic_write_bytes(record, (json.dumps(
            {"round": r, "model": ck.name, "margin_g": m, "trials": rows}, indent=1, default=float) + "\n").encode())

    ck = Path(checkpoint)
    for r in range(rounds):
        tasks = [(n, d, s + 100 * r) for d in dims for n in scenarios for s in seeds]
        fm = load_force_model(cfg, ck)
        m = margin.planning_margin(cfg, fm, held_out, LIMITS_3D)     # what the plans are planned with
        tag = hashlib.sha256(json.dumps([names, tasks, m]).encode()).hexdigest()[:10]
        nxt = folder / f"model_r{r + 1}_{tag}.pt"
        data = folder / f"data_plans_r{r}_{tag}.npz"
        todo.append((r, ck, tasks, m, data))
        names = [*names, data.name]
        if not _trained_on(nxt, names) and keep is not None and _trained_on(keep / nxt.name, names):
            log(f"plan data round {r}: {nxt.name} kept in {keep}")
            _copy(keep / nxt.name, nxt)
        if not _trained_on(nxt, names):
            for rr, rck, rtasks, rm, rdata in todo:     # every round's data so far (flown again if not here)
                if not rdata.is_file():
                    fly_round(rr, rck, rtasks, rm, rdata)
            ds = Dataset.concat([Dataset.load(folder / f, cfg.neighbor_types) for f in names])
            model, rep = train(cfg, ds)
            save_checkpoint(nxt, model, cfg, {"seed": rep["seed"], "data_hash": ds.content_hash(), "report": rep,
                                              "data_files": names, "plan_data_of": str(ck)})
        if keep is not None:
            for f in (nxt, data.with_suffix(".json")):
                if f.is_file() and not (keep / f.name).is_file():
                    _copy(f, keep / f.name)
        ck = nxt
    return ck
