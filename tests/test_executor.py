"""One executor for many independent jobs (ns2codegen.executor) and the result store of
long runs (ns2codegen.results): the same seeds give the same results, bit for bit, on
this process, on forked workers and on a Dask cluster (a LocalCluster of two
one-thread workers, reached by its address as a remote one is): ablation trainings,
simulated flights, planning trials; a run cut short resumes from its kept units."""
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.data.dataset import Dataset
from ns2codegen.executor import LOCAL_CLUSTER, SCHEDULER_ENV, Executor, scheduler_address
from ns2codegen.results import ResultStore, file_hash

CI = os.environ.get("CI", "").lower() == "true"


@pytest.fixture(scope="module")
def cluster():
    """The address of a Dask LocalCluster (--scheduler local-cluster): two worker processes
    of one thread each."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        msg = "distributed missing (the cluster extra: scripts/install-deps.sh)"
        if CI:
            pytest.fail(f"CI=true: {msg}", pytrace=False)
        pytest.skip(msg)
    with Executor(2, LOCAL_CLUSTER) as ex:
        client = ex._dask()
        assert sorted(w["nthreads"] for w in client.scheduler_info()["workers"].values()) == [1, 1]
        assert ex.map(_square_plus, [(2, 1), (3, 1)]) == [5, 10]
        yield ex._cluster.scheduler_address


def _square_plus(x, y):
    return x * x + y


def test_scheduler_address_from_the_option_or_the_environment(monkeypatch):
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    assert scheduler_address(None) is None and Executor(4).backend == "local" and Executor(1).backend == "inline"
    monkeypatch.setenv(SCHEDULER_ENV, "tcp://10.0.0.1:8786")
    assert scheduler_address(None) == "tcp://10.0.0.1:8786" and Executor(1).backend == "dask"
    assert scheduler_address("local") is None and Executor(2, "local").backend == "local"   # the option wins
    assert scheduler_address(LOCAL_CLUSTER) == LOCAL_CLUSTER


def test_map_keeps_the_order_and_reports_every_job_once(cluster, monkeypatch):
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    args = [(k, 3 * k) for k in range(7)]
    want = [_square_plus(*a) for a in args]
    for ex in (Executor(1), Executor(2), Executor(2, cluster)):
        seen, ticks = {}, []
        with ex:
            got = ex.map(_square_plus, args, progress=ticks.append, on_done=seen.__setitem__)
        assert got == want and seen == dict(enumerate(want)) and ticks == [1] * len(args), ex.backend
    with Executor(2, cluster) as ex, pytest.raises(TypeError):
        ex.map(_square_plus, [(1, 2), ("a", 3)])                      # a worker's error reaches the caller


def _fail_on_two(k):
    if k == 2:
        raise ValueError("job 2")
    return k


def test_a_job_that_fails_keeps_what_finished_before_it(cluster, monkeypatch):
    """An error (or an interrupt) in a run: the jobs finished before it are reported
    (kept by the caller), the caller gets the error, the jobs not started never run."""
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    for ex in (Executor(1), Executor(2), Executor(2, cluster)):
        seen = {}
        with pytest.raises(ValueError, match="job 2"), ex:
            ex.map(_fail_on_two, [(k,) for k in range(4)], on_done=seen.__setitem__)
        assert {0: 0, 1: 1}.items() <= seen.items() and 2 not in seen, ex.backend
        if ex.backend == "inline":
            assert seen == {0: 0, 1: 1}


class _Unpicklable(Exception):
    def __reduce__(self):
        raise TypeError("not picklable")


def _raise_unpicklable():
    raise _Unpicklable("the C said no")


def test_an_error_that_cannot_be_pickled_reaches_the_caller_with_its_message(cluster, monkeypatch):
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    for ex in (Executor(2), Executor(2, cluster)):
        with pytest.raises(RuntimeError, match="_Unpicklable: the C said no"), ex:
            ex.map(_raise_unpicklable, [(), ()])


def _spec(tmp_path, cfg, save_dir=None):
    downwash_dataset(cfg, 60, seed=0).save(tmp_path / "d.npz")
    downwash_dataset(cfg, 40, seed=1).save(tmp_path / "t.npz")
    return {"data": [str(tmp_path / "d.npz")], "test_data": [str(tmp_path / "t.npz")], "config": None,
            "save_dir": save_dir, "test_label": "test",
            "train": {"max_epochs": 2, "patience": 3, "min_delta": 0.01, "lr_drops": 0, "batch_size": None,
                      "lr": None, "device": "cpu"}}


def test_ablation_trainings_are_the_same_here_and_on_a_dask_cluster(cluster, cfg, tmp_path, monkeypatch):
    """benchmarks/ablation.py's trainings (ns2exp.ablation.train_all) on two forked workers
    and on the Dask cluster: the same validation and test MSEs, epochs and weights."""
    from ns2codegen.checkpoint import load_checkpoint
    from ns2exp.ablation import runs, train_all

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    selected = runs("H,V")[:1] + runs("V")[-1:]               # H = 20 and without the relative velocity
    out = {}
    for name, sched in (("local", None), ("dask", cluster)):
        (tmp_path / name).mkdir()
        spec = _spec(tmp_path, cfg, str(tmp_path / name))
        out[name], sizes = train_all(spec, selected, 2, workers=2, scheduler=sched, log=lambda m: None)
        train_set, test_set = (Dataset.load(p) for p in spec["data"] + spec["test_data"])
        assert sizes == {"samples": len(train_set), "label_var": float(np.var(train_set.label_g)),
                         "test_samples": len(test_set)}
    assert len(out["local"]) == 4
    for a, b in zip(out["local"], out["dask"]):
        assert (a["mse"], a["epochs"], a["test_mse"]) == (b["mse"], b["epochs"], b["test_mse"])
        wa = load_checkpoint(tmp_path / "local" / a["checkpoint"]).state_dict
        wb = load_checkpoint(tmp_path / "dask" / b["checkpoint"]).state_dict
        assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)
    assert len({r["mse"] for r in out["local"]}) == 4               # the seeds and the runs differ


def test_simulated_flights_are_the_same_here_and_on_a_dask_cluster(cluster, cfg, exported, monkeypatch):
    """Collection flights (ns2host.sim.collect.fly_many, the C controller in the loop) on two
    forked workers and, with NS2_SCHEDULER, on the Dask cluster: the same logs bit for bit."""
    from ns2host.sim.collect import fly, fly_many

    jobs = [(cfg, ("small", "large"), exported.gen_dir, kind, 1.0, seed) for kind, seed in
            (("swap", 3), ("random", 4), ("swap", 5))]
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    here = fly_many(fly, jobs, exported.gen_dir, workers=2)
    monkeypatch.setenv(SCHEDULER_ENV, cluster)
    there = fly_many(fly, jobs, exported.gen_dir, workers=2)
    assert len(here) == len(there) == 3
    for a, b in zip(here, there):
        for k in ("t", "p", "v", "q", "pwm", "battery_V", "p_d"):
            assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert not np.array_equal(here[0].p, here[2].p)                   # other seeds, other flights


def test_planning_trials_are_the_same_here_and_on_a_dask_cluster(cluster, cfg, exported, monkeypatch):
    """Planning trials (ns2exp.planning.runs: plan, check, fly) on the Dask cluster, each
    worker loading the planning model itself (plan_executor's setup): the same records as
    in this process, bit for bit."""
    from ns2exp.planning import runs
    from ns2plan.problem import RRTParams, SCPParams, SearchParams

    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    rrt, scp = RRTParams(SearchParams(max_samples=6000), ao_iterations=1), SCPParams(max_iterations=3)
    args = [(mode, "SL", 3, 0, 2.0, str(exported.gen_dir), rrt, scp) for mode in ("NN", "BL")]
    out = {}
    for name, sched, workers in (("here", None, 1), ("dask", cluster, 2)):
        with runs.plan_executor(exported.checkpoint, exported.gen_dir, workers, sched) as ex:
            assert ex.backend == ("inline" if sched is None else "dask")
            out[name] = [rec for rec, _, _ in ex.map(runs._experiment_trial, args)]
    for a, b in zip(out["here"], out["dask"]):
        assert a["error"] == b["error"]
        if a["error"] is None:
            assert (a["track"], a["stage1_costs"], a["scp_merit"]) == (b["track"], b["stage1_costs"], b["scp_merit"])
    assert any(a["error"] is None for a in out["here"])


def test_a_rerun_trains_only_what_is_missing(cfg, tmp_path, monkeypatch):
    """train_all keeps every training as it finishes (ns2codegen.results): a rerun says how
    much is done and trains only the missing ones (a lost file, a lost checkpoint), with
    the same results; other options or another VERSION reuse nothing."""
    from ns2exp import ablation

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    (tmp_path / "ck").mkdir()
    spec = _spec(tmp_path, cfg, str(tmp_path / "ck"))
    selected, runs_dir = ablation.runs("H")[:1] + ablation.runs("P")[-1:], tmp_path / "runs"
    trained = []
    real = ablation.train_one
    monkeypatch.setattr(ablation, "train_one", lambda s, run, seed: trained.append((run[0], seed)) or real(s, run, seed))
    logs = []
    first, _ = ablation.train_all(spec, selected, 2, runs_dir=runs_dir, log=logs.append)
    assert len(trained) == 4 and logs[0].endswith(f"0 of 4 done, 4 left ({runs_dir})")
    kept = sorted(runs_dir.glob("training_*.json"))
    assert len(kept) == 4
    doc = json.loads(kept[0].read_text())
    assert doc["experiment"] == "ablation" and doc["version"] == ablation.VERSION and "mse" in doc["result"]
    assert doc["inputs"][0] == [file_hash(tmp_path / "d.npz")] and doc["unit"][1] in (0, 1)
    # cut short: one unit's file lost; one checkpoint lost (its unit is not complete without it)
    kept[0].unlink()
    (tmp_path / "ck" / "H-20-seed1.pt").unlink()
    trained.clear()
    logs.clear()
    again, _ = ablation.train_all(spec, selected, 2, runs_dir=runs_dir, log=logs.append)
    assert logs[0].startswith("ablation trainings: 2 of 4 done, 2 left") and len(trained) == 2
    assert ("H", 1) in trained
    for a, b in zip(first, again):
        assert (a["mse"], a["epochs"], a["test_mse"]) == (b["mse"], b["epochs"], b["test_mse"])
    trained.clear()
    ablation.train_all(spec, selected, 2, runs_dir=runs_dir, log=logs.append)
    assert trained == []
    ablation.train_all({**spec, "train": {**spec["train"], "max_epochs": 1}}, selected[:1], 1, runs_dir=runs_dir,
                       log=logs.append)
    assert trained == [("H", 0)]
    monkeypatch.setattr(ablation, "VERSION", ablation.VERSION + 1)
    ablation.train_all(spec, selected[:1], 1, runs_dir=runs_dir, log=logs.append)
    assert trained == [("H", 0), ("H", 0)]


def test_result_store_keys_on_what_a_result_depends_on(tmp_path):
    a = ResultStore(tmp_path, "exp", 1, ["data-hash"])
    assert a.get("unit", "case", 0) is None
    a.put("unit", {"x": 1.5}, "case", 0, {"p": 2, "q": [1, 2]})
    assert a.get("unit", "case", 0, {"q": [1, 2], "p": 2}) == {"x": 1.5}     # the parameters' order does not matter
    for other in (ResultStore(tmp_path, "exp", 2, ["data-hash"]), ResultStore(tmp_path, "exp", 1, ["other"]),
                  ResultStore(tmp_path, "other", 1, ["data-hash"])):
        assert other.get("unit", "case", 0, {"p": 2, "q": [1, 2]}) is None
    assert a.get("unit", "case", 1, {"p": 2, "q": [1, 2]}) is None and a.get("unit", "case", 0, {"p": 3}) is None
    assert [p.name for p in Path(tmp_path).iterdir()] == [a.path("unit", "case", 0, {"p": 2, "q": [1, 2]}).name]
    msgs = []
    assert a.pending("unit", [("case", 0, {"p": 2, "q": [1, 2]}), ("case", 1, {})], msgs.append) == [("case", 1, {})]
    assert msgs == [f"exp unit: 1 of 2 done, 1 left ({tmp_path})"]
