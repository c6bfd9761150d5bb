"""The ablation machinery (benchmarks/ablation.py): model variants, the stopping rule,
the training device."""
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from ns2codegen.data.analytic import downwash_dataset
from ns2codegen.model import HeteroDeepSet, PairwiseSum, TypeAgnostic
from ns2codegen.train import train


def _one(robot_type, nbrs):
    """A batch of one sample: (robot_type, sample_of, nbr_type, nbr_state)."""
    types = torch.tensor([t for t, _ in nbrs])
    state = torch.tensor(np.array([s for _, s in nbrs]), dtype=torch.float32)
    return torch.tensor([robot_type]), torch.zeros(len(nbrs), dtype=torch.long), types, state


def test_variants_are_what_they_claim(cfg):
    torch.manual_seed(0)
    env = cfg.env_index
    a, b, e = np.array([0.1, 0, 0.3, 0, 0, 0]), np.array([-0.2, 0.1, 0.5, 0.3, 0, 0]), np.array([0, 0, -1.0, 0, 0, 0])
    pw = PairwiseSum(cfg)
    both = pw(*_one(0, [(0, a), (1, b), (env, e)]))
    apart = sum(pw(*_one(0, [nb])) for nb in [(0, a), (1, b), (env, e)])
    assert torch.allclose(both, apart, atol=1e-6)                  # a sum of pairs
    hs = HeteroDeepSet(cfg)
    hs.load_state_dict(pw.state_dict())
    assert not torch.allclose(hs(*_one(0, [(0, a), (1, b), (env, e)])), both)
    ag = TypeAgnostic(cfg)
    x = ag(*_one(0, [(0, a), (1, b), (env, e)]))
    assert torch.allclose(x, ag(*_one(1, [(1, a), (0, b), (env, e)])))   # types ignored
    assert not torch.allclose(x, ag(*_one(0, [(0, a), (1, b), (0, e)])))  # but not the environment's


def test_stopping_rule_and_device(cfg):
    ds = downwash_dataset(cfg, 40, seed=0)
    _, rep = train(cfg, ds, epochs=10, patience=1, min_delta=0.99, device="cpu", variant="pairwise")
    assert rep["epochs"] == 2 and rep["stopping"]["best_epoch"] == 1 and rep["device"] == "cpu"
    assert rep["validation"]["mse"] == pytest.approx(rep["stopping"]["validation_mse_history"][0], rel=1e-5)
    # plateau schedule: twice the learning rate is halved, from the best weights, then stop
    _, rep = train(cfg, ds, epochs=10, patience=1, min_delta=0.99, lr_drops=2)
    st = rep["stopping"]
    assert rep["epochs"] == 4 and st["best_epoch"] == 1 and st["lr_drops"] == 2
    assert st["lr_final"] == pytest.approx(rep["lr"] / 4)
    with pytest.raises(ValueError, match="variant"):
        train(cfg, ds, epochs=1, variant="nonsense")


def test_cli_train_refuses_an_unusable_device(tmp_path, cfg):
    from ns2cli import main

    ds = downwash_dataset(cfg, 20, seed=0)
    ds.save(tmp_path / "d.npz")
    res = CliRunner().invoke(main, ["train", "--data", str(tmp_path / "d.npz"), "--out", str(tmp_path / "m.pt"),
                                    "--device", "nonsense-device", "--epochs", "1", "--quiet"])
    assert res.exit_code != 0 and "--device" in res.output and not (tmp_path / "m.pt").exists()


def test_ablation_trainings_side_by_side_give_the_same_results(tmp_path, cfg):
    """benchmarks/ablation.py --workers 2 (make ablation) trains in forked processes: the
    same MSEs, epochs and test scores, bit for bit, in the same order as one at a time."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    downwash_dataset(cfg, 300, seed=0).save(tmp_path / "d.npz")
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "ablation.py"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}

    def run(workers: int) -> dict:
        out = subprocess.run([sys.executable, str(script), "--data", str(tmp_path / "d.npz"), "--test-data",
                              str(tmp_path / "d.npz"), "--axes", "H,V", "--seeds", "2", "--max-epochs", "2",
                              "--workers", str(workers), "--runs", str(tmp_path / f"runs{workers}")],
                             env=env, capture_output=True, text=True, check=True)
        d = json.loads(out.stdout)
        assert d.pop("workers") == workers
        d.pop("wall_s")
        assert d.pop("provenance")["command"].startswith("benchmarks/ablation.py --data")   # its own run's
        for axis in ("H", "V"):
            for r in d[axis].values():
                assert len(r.pop("wall_s")) == 2
        return d

    one, two = run(1), run(2)
    assert one == two and set(one["H"]) == {"10", "20", "40"} and one["V"]["without"]["runs"] != one["H"]["20"]["runs"]
    bad = subprocess.run([sys.executable, str(script), "--data", str(tmp_path / "d.npz"), "--workers", "2",
                          "--device", "cuda"], env=env, capture_output=True, text=True)
    assert bad.returncode != 0 and "--workers 2" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
