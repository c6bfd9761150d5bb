import torch

from ns2codegen.data.analytic import max_dataset
from ns2codegen.train import Batched, train


def test_learns_analytic_downwash(exported):
    v = exported.report["validation"]
    # validation error far below the label variance, for every scenario
    assert v["mse"] < 0.1 * v["label_var"], v
    assert len(v["mse_per_scenario"]) == 12
    assert max(v["mse_per_scenario"].values()) < 0.3 * v["label_var"]


def test_learns_two_group_max_example(cfg):
    ds = max_dataset(cfg, 6000, seed=1)
    _, report = train(cfg, ds, epochs=6, seed=1, lr=3e-3)
    v = report["validation"]
    assert v["mse"] < 0.05 * v["label_var"], v


def test_spectral_normalization_is_exact(exported, cfg):
    layers = cfg.model["layers"]
    target = cfg.model["gamma"] ** (1.0 / layers)
    for name, p in exported.model.state_dict().items():
        if name.endswith("weight"):
            s = torch.linalg.matrix_norm(p.double(), ord=2).item()
            assert abs(s - target) < 1e-5 * target, (name, s, target)
    lip = exported.manifest["lipschitz"]
    for b in lip["phi"] + lip["rho"]:
        assert abs(b - cfg.model["gamma"]) < 1e-4 * cfg.model["gamma"]


def test_batched_forward_equals_per_sample(exported):
    """The CSR-batched forward equals evaluating each sample on its own."""
    from ns2codegen.data.analytic import downwash_dataset

    ds = downwash_dataset(exported.cfg, 20, seed=9)
    m = exported.model
    data = Batched.of(ds)
    rt, so, nt, ns, _ = data.batch(torch.arange(len(ds)))
    batched = m(rt, so, nt, ns)
    for i in range(len(ds)):
        a, b = ds.nbr_offsets[i], ds.nbr_offsets[i + 1]
        h = sum(m.phi[int(ds.nbr_type[r])](torch.from_numpy(ds.nbr_state[r])) for r in range(a, b))
        single = m.rho[int(ds.robot_type[i])](h)[0]
        assert torch.allclose(batched[i], single, atol=1e-5, rtol=1e-5)


def test_checkpoint_metadata(exported):
    from ns2codegen.checkpoint import load_checkpoint

    ck = load_checkpoint(exported.checkpoint)
    meta = ck.meta
    for key in ("config", "phi_dims", "rho_dims", "gamma", "normalization", "data_hash", "seed", "report"):
        assert key in meta
    assert meta["phi_dims"] == [6, 25, 40, 40, 20] and len(meta["data_hash"]) == 64
    assert ck.model_hash() == exported.manifest["model_hash"]


def test_training_is_seeded(cfg):
    from ns2codegen.data.analytic import downwash_dataset

    ds = downwash_dataset(cfg, 100, seed=0)
    a, _ = train(cfg, ds, epochs=1, seed=5)
    b, _ = train(cfg, ds, epochs=1, seed=5)
    for (ka, va), (_, vb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(va, vb), ka


def test_a_retrained_checkpoint_has_the_same_bytes(cfg, tmp_path):
    """Two trainings of one data set, config and seed write byte-identical checkpoints: the
    report's timing (TIMING_KEYS, different on every run) is not in the file, so a model made
    again on another day or machine is recognised by its bytes (the planning rounds kept in
    docs/results/runs/planning/models/ are reused only then)."""
    from ns2codegen.checkpoint import TIMING_KEYS, load_checkpoint, save_checkpoint
    from ns2codegen.data.analytic import downwash_dataset

    ds = downwash_dataset(cfg, 100, seed=0)
    files = []
    for run in range(2):
        model, report = train(cfg, ds, epochs=1, seed=5)
        assert all(report[k] is not None for k in TIMING_KEYS)
        report["train_seconds"] += run  # as if the second run were a second slower
        files.append(tmp_path / f"m{run}.pt")
        save_checkpoint(files[-1], model, cfg, {"seed": 5, "data_hash": ds.content_hash(), "report": report})
    assert files[0].read_bytes() == files[1].read_bytes()
    report = load_checkpoint(files[0]).meta["report"]
    assert not set(TIMING_KEYS) & set(report) and report["epochs"] == 1 and "validation" in report
