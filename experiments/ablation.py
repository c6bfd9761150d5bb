"""The paper's ablations (benchmarks/ablation.py is their command): the runs of each
axis, one training of a run and seed (a unit: kept as it finishes, ns2codegen.results),
every training of a selection on an executor (ns2codegen.executor: forked processes
here or the workers of a Dask cluster, each loading the data sets itself)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from ns2codegen.config import ONBOARD_WIDTHS, Config
from ns2codegen.data.dataset import Dataset
from ns2codegen.executor import Executor, ensure_setup
from ns2codegen.results import ResultStore, file_hash

# the meaning of a kept training (its validation and test MSE, epochs, checkpoint): bump it when a
# change to the training, the models or the stopping rule changes what the same inputs give
VERSION = 1

PAPER = {"hidden": 20, "layers": 4}
# (axis, value, model overrides, variant, drop relative velocity); H = 20 at L = 4 is
# also L = 4, W = 40/25 and the full model of V, P, T
RUNS = [("H", h, {"hidden": h, "layers": 4}, "hetero", False) for h in (10, 20, 40)] + \
       [("L", n, {"hidden": 20, "layers": n}, "hetero", False) for n in (3, 5)] + \
       [("W", "24/16", dict(PAPER, **ONBOARD_WIDTHS), "hetero", False),
        ("V", "without", PAPER, "hetero", True),
        ("P", "pairwise sum", PAPER, "pairwise", False),
        ("T", "type-agnostic", PAPER, "agnostic", False)]
SAME_AS_PAPER = (("L", "4"), ("W", "40/25"), ("V", "with"), ("P", "deep set"), ("T", "heterogeneous"))
# the options of a training (the keys of ``spec["train"]``), all of them in a unit's key
TRAIN_OPTIONS = ("max_epochs", "patience", "min_delta", "lr_drops", "batch_size", "lr", "device")


def runs(axes: str) -> list:
    """The runs of the axes named (a comma list of H, L, W, V, P, T; "paper": the paper's network alone);
    the paper's network once, first."""
    order = axes.split(",")
    sel = sorted((r for r in RUNS if r[0] in order), key=lambda r: order.index(r[0]))
    paper = ("H", 20, PAPER, "hetero", False)     # the reference runs first
    if set(order) - {"H"} or paper in sel:
        sel = [paper] + [r for r in sel if r != paper]
    return sel


def table(results: dict, axes: str) -> dict:
    """results[(axis, value)] -> {axis: {value: result}} with the paper's network under each axis."""
    out = {a: {} for a in axes.split(",")}
    for (axis, value), r in results.items():
        out.setdefault(axis, {})[str(value)] = r
    for axis, value in SAME_AS_PAPER:
        if axis in out and "20" in out.get("H", {}):
            out[axis][value] = out["H"]["20"]
    return out


def without_velocity(ds: Dataset) -> Dataset:
    """The data set with the relative velocities (and the environment's -v_i) zeroed."""
    state = ds.nbr_state.copy()
    state[:, 3:] = 0.0
    return Dataset(**{**ds.__dict__, "nbr_state": state})


# a worker's data (load_data): the config, the training and test sets by whether the relative
# velocity is dropped; loaded once per worker process (forked workers inherit the parent's)
_DATA: dict = {}


def load_data(spec: dict, drops: tuple) -> None:
    """A worker's setup (ns2codegen.executor): the config and the data sets of ``spec``
    (their files' hashes in it: other bytes under the same name are loaded again), with
    the relative velocities zeroed for the ``drops`` that ask it."""
    ds = Dataset.concat([Dataset.load(p) for p in spec["data"]])
    test = Dataset.concat([Dataset.load(p) for p in spec["test_data"]]) if spec["test_data"] else None
    _DATA.clear()
    _DATA.update(cfg=Config.load(spec["config"]), samples=len(ds), label_var=float(ds.label_g.var()),
                 test_samples=len(test) if test is not None else 0,
                 data={d: without_velocity(ds) if d else ds for d in drops},
                 test={d: without_velocity(test) if d and test is not None else test for d in drops})


def train_one(spec: dict, run: tuple, seed: int) -> dict:
    """One training of the ablation on the worker's data (load_data): validation MSE,
    epochs, wall s, test MSE (None without test data), the checkpoint saved (hetero runs
    with ``spec["save_dir"]``: its file name and sha256)."""
    from ns2codegen.checkpoint import save_checkpoint
    from ns2codegen.train import evaluate, train

    cfg, opt = _DATA["cfg"], spec["train"]
    axis, value, over, variant, drop_v = run
    data, test_run = _DATA["data"][drop_v], _DATA["test"][drop_v]
    t0 = time.perf_counter()
    model, rep = train(cfg.with_overrides(**over), data, epochs=opt["max_epochs"], seed=seed,
                       batch_size=opt["batch_size"], lr=opt["lr"], device=opt["device"], variant=variant,
                       patience=opt["patience"], min_delta=opt["min_delta"], lr_drops=opt["lr_drops"])
    wall = time.perf_counter() - t0
    tested = evaluate(model, test_run)["mse"] if test_run is not None else None  # the model is on the CPU
    out = {"mse": rep["validation"]["mse"], "epochs": rep["epochs"], "wall_s": wall, "test_mse": tested,
           "checkpoint": None, "checkpoint_sha256": None}
    if spec["save_dir"] and variant == "hetero":
        path = Path(spec["save_dir"]) / checkpoint_name(run, seed)
        save_checkpoint(path, model, cfg.with_overrides(**over), {"seed": seed, "data_hash": data.content_hash(),
                                                                  "report": rep, "relative_velocity": not drop_v})
        out.update(checkpoint=path.name, checkpoint_sha256=file_hash(path))
    return out


def checkpoint_name(run: tuple, seed: int) -> str:
    return f"{run[0]}-{run[1]}-seed{seed}.pt".replace("/", "_")


def _complete(spec: dict, run: tuple, rec) -> bool:
    """A kept training, with its checkpoint there with its bytes when one is asked for."""
    if rec is None:
        return False
    if not (spec["save_dir"] and run[3] == "hetero"):
        return True
    if not rec.get("checkpoint_sha256"):        # kept by a run without --save-dir
        return False
    p = Path(spec["save_dir"]) / rec["checkpoint"]
    return p.is_file() and file_hash(p) == rec["checkpoint_sha256"]


def train_all(spec: dict, selected: list, seeds: int, workers: int = 1, scheduler: str | None = None,
              runs_dir=None, log=None) -> tuple[list, dict]:
    """Every run of ``selected`` with seeds 0 .. ``seeds`` - 1 (train_one) on an executor
    (``workers`` forked processes, or the Dask cluster of ``scheduler`` / NS2_SCHEDULER);
    with ``runs_dir`` each training is kept there as it finishes and a rerun trains only
    those missing.  The trainings' results in the order of the jobs (run by run, seed by
    seed) and the data's sizes (samples, label_var, test_samples)."""
    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    jobs = [(run, seed) for run in selected for seed in range(seeds)]
    inputs = [[file_hash(p) for p in spec["data"]], [file_hash(p) for p in spec["test_data"]],
              Config.load(spec["config"]).raw]
    store = ResultStore(runs_dir, "ablation", VERSION, inputs) if runs_dir is not None else None
    unit = lambda run, seed: (list(run), seed, spec["train"])  # noqa: E731
    kept = [store.get("training", *unit(*j)) if store is not None else None for j in jobs]
    kept = [r if _complete(spec, run, r) else None for (run, _), r in zip(jobs, kept)]
    todo = [j for j, r in zip(jobs, kept) if r is None]
    if store is not None:
        store.report("trainings", len(jobs), len(todo), log)
    drops = tuple(sorted({run[4] for run in selected}))
    data_spec = {k: spec[k] for k in ("data", "test_data", "config")}
    setup = (load_data, (dict(data_spec, hashes=inputs[:2]), drops))

    def done(i, rec) -> None:               # kept and said as soon as it finishes, in any order
        (axis, value, *_), seed = todo[i]
        if store is not None:
            store.put("training", rec, *unit(*todo[i]))
        log(f"  {axis}={value} seed {seed}: {rec['mse']:.3f} g^2 after {rec['epochs']} epochs ({rec['wall_s']:.0f} s)"
            + (f", {spec['test_label']} {rec['test_mse']:.3f} g^2" if rec["test_mse"] is not None else ""))

    with Executor(workers, scheduler, setup=setup, setup_here=True) as ex:
        new = iter(ex.map(train_one, [(spec, run, seed) for run, seed in todo], on_done=done))
    ensure_setup(setup)                     # the data here too (loaded already unless on a cluster)
    return [r if r is not None else next(new) for r in kept], {k: _DATA[k] for k in ("samples", "label_var",
                                                                                        "test_samples")}
