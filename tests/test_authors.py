"""The authors' published networks (../shared/neural-swarm-data) as a project model:
imported unchanged, their logged on-board prediction recomputed from real flights,
exported to C and checked bit for bit like our own models."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from conftest import REAL_DATA, needs, real_logs
from ns2codegen import reference as ref
from ns2paper.authors import AuthorsModelError, load_authors, load_net
from ns2codegen.checkpoint import load_checkpoint
from ns2codegen.export import export
from ns2paper.collection import COLLECTION
from ns2codegen.queries import Queries, random_queries
from ns2codegen.quantize import from_checkpoint

pytestmark = needs(REAL_DATA)

OUT = "models/models/output"
Y19 = "training/datacollection19_12_11_2019"
STEMS = ("phi_S", "phi_L", "phi_G", "rho_S", "rho_L")
C20 = COLLECTION
# a few real flights: two robots of each type mix, and a take-off (ground effect)
FLIGHTS = {"swap_ss": ("00", ["50", "51"]), "swap_sl": ("03", ["51", "101"]),
           "swap_ll": ("01", ["101", "102"]), "takeoff_s": ("00", ["50", "51", "52"])}


@pytest.fixture(scope="module")
def data():
    files = [f"{OUT}/{s}.pth" for s in STEMS] + [f"{Y19}/{s}{x}.pth" for s in STEMS if s != "phi_G" for x in ("", "_rw")]
    files += [f"{C20}/{sc}/cf{cf}_{num}" for sc, (num, cfs) in FLIGHTS.items() for cf in cfs]
    return real_logs("neural-swarm-2020-06-16-swaps.tar.xz", files)  # all of them are in this one


@pytest.fixture(scope="module")
def authors(data, tmp_path_factory):
    from cli import main

    out = tmp_path_factory.mktemp("authors") / "authors.pt"
    res = CliRunner().invoke(main, ["real", "import-authors", str(data / OUT), "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out


def test_import_carries_the_published_weights_bit_for_bit(data, authors):
    ck = load_checkpoint(authors)
    assert ck.cfg.phi_dims() == [6, 25, 40, 40, 20] and ck.cfg.rho_dims() == [20, 40, 40, 40, 1]
    assert ck.cfg.neighbor_types == ["small", "large", "env"]
    where = {"phi_S": ("phi", 0), "phi_L": ("phi", 1), "phi_G": ("phi", 2), "rho_S": ("rho", 0), "rho_L": ("rho", 1)}
    for stem in STEMS:
        sd = torch.load(data / OUT / f"{stem}.pth", weights_only=True)
        kind, i = where[stem]
        ours = ck.net_weights(kind, i)
        assert len(ours) == 4
        for l, (w, b) in enumerate(ours):
            theirs_w, theirs_b = sd[f"fc{l + 1}.weight"], sd[f"fc{l + 1}.bias"]
            assert theirs_w.dtype == torch.float32
            if stem == "phi_G" and l == 0:  # 4 inputs [-z, -v] -> env input [-p; -v]
                assert theirs_w.shape == (25, 4)
                assert torch.equal(w[:, :2], torch.zeros(25, 2))
                w = w[:, 2:]
            assert torch.equal(w.view(torch.int32), theirs_w.view(torch.int32)), (stem, l)
            assert torch.equal(b.view(torch.int32), theirs_b.view(torch.int32)), (stem, l)
    # not renormalized: the published nets are far beyond the meta's gamma^(1/L) per layer
    lip = ck.meta["authors"]["lipschitz_per_net"]
    assert lip["phi_L"] > 70 and ck.cfg.model["gamma"] >= max(lip.values())


def test_model_equals_the_published_nets_run_directly(data, authors):
    """Our HeteroDeepSet with the imported weights == the authors' MLPs composed by hand
    (float64 reference), on random inputs, neighbours of both types plus the ground."""
    m = load_checkpoint(authors).model()
    nets = {s: load_net(data / OUT / f"{s}.pth") for s in STEMS}

    def run(net, x):
        for l, (w, b) in enumerate(net):
            x = x @ w.double().T + b.double()
            x = torch.relu(x) if l + 1 < len(net) else x
        return x

    g = torch.Generator().manual_seed(0)
    n = 500
    p, v = torch.rand(n, 3, generator=g) * 2, torch.randn(n, 3, generator=g)
    rel = [torch.randn(n, 6, generator=g) * 0.4 for _ in range(2)]
    h = run(nets["phi_S"], rel[0].double()) + run(nets["phi_L"], rel[1].double()) \
        + run(nets["phi_G"], torch.cat([-p[:, 2:], -v], 1).double())
    rt = torch.arange(n) % 2
    want = torch.where(rt == 0, run(nets["rho_S"], h)[:, 0], run(nets["rho_L"], h)[:, 0])
    rows = torch.cat([rel[0], rel[1], torch.cat([-p, -v], 1)])
    got = m(rt, torch.arange(n).repeat(3), torch.tensor([0, 1, 2]).repeat_interleave(n), rows)
    np.testing.assert_allclose(got.detach().double().numpy(), want.numpy(), rtol=1e-5, atol=1e-4)


def test_2019_sets_import_without_ground(data, tmp_path):
    for suffix in ("", "_rw"):
        model, cfg, meta = load_authors(data / Y19, suffix)
        assert meta["ground"] is None and meta["dtype"] == ["float64"]
        sd = model.state_dict()
        assert all(not sd[f"phi.2.layers.{l}.{k}"].any() for l in range(4) for k in ("weight", "bias"))
        theirs = torch.load(data / Y19 / f"rho_L{suffix}.pth", weights_only=True)["fc2.weight"]
        assert torch.equal(sd["rho.1.layers.1.weight"], theirs.to(torch.float32))  # rounded once to float32


def test_bad_network_files_name_the_file(data, tmp_path):
    with pytest.raises(AuthorsModelError, match="phi_S.pth: network file not found"):
        load_authors(tmp_path)
    bad = tmp_path / "phi_S.pth"
    bad.write_bytes(b"not a zip")
    with pytest.raises(AuthorsModelError, match="phi_S.pth: not a loadable state_dict"):
        load_net(bad)
    torch.save(torch.nn.Linear(6, 25), bad)  # a pickled module: refused by weights_only
    with pytest.raises(AuthorsModelError, match="phi_S.pth: not a loadable state_dict"):
        load_net(bad)
    sd = torch.load(data / OUT / "phi_S.pth", weights_only=True)
    sd["fc2.weight"] = sd["fc2.weight"][:, :24]
    torch.save(sd, bad)
    with pytest.raises(AuthorsModelError, match="phi_S.pth: layer 2 takes 24 inputs"):
        load_net(bad)
    from cli import main

    res = CliRunner().invoke(main, ["real", "import-authors", str(tmp_path), "--out", str(tmp_path / "a.pt")])
    assert res.exit_code == 1 and "phi_S.pth" in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "a.pt").exists()


# measured on these flights with the conventions of ns2exp.onboard_faz (ground included,
# every other robot a neighbour; `ns2 real authors-faz`): rms |prediction - Faz| in g
FAZ_RMS = {("swap_ss", 0): 0.78, ("swap_sl", 0): 0.55, ("swap_sl", 1): 2.64,
           ("swap_ll", 1): 1.94, ("takeoff_s", 0): 0.51}


def test_onboard_faz_reproduced_from_the_logged_states(data, authors):
    from ns2exp.onboard_faz import flights, predict_flight, robot_type

    m = load_checkpoint(authors).model()
    for sc, (num, cfs) in FLIGHTS.items():
        files = {cf: f for cf, f in flights(data / C20 / sc)[num].items() if cf in cfs}
        for ground in (True, False):
            res = predict_flight(m, files, ground)
            for t in {robot_type(cf) for cf in res}:
                e = np.concatenate([r["pred"] - r["faz"] for cf, r in res.items() if robot_type(cf) == t])
                rms = float(np.sqrt(np.mean(e ** 2)))
                if ground:
                    assert rms < 1.25 * FAZ_RMS[(sc, t)] + 0.05, (sc, t, rms)
                    faz = np.concatenate([r["faz"] for cf, r in res.items() if robot_type(cf) == t])
                    if faz.std() > 1.0:  # the prediction follows the logged one where it moves
                        pred = np.concatenate([r["pred"] for cf, r in res.items() if robot_type(cf) == t])
                        assert np.corrcoef(pred, faz)[0, 1] > 0.7, (sc, t)
    # the ground input matters where the ground does: take-off, about 2x closer with phi_G (0.51 vs 1.05 g)
    files = flights(data / C20 / "takeoff_s")["00"]
    with_g = np.concatenate([r["pred"] - r["faz"] for r in predict_flight(m, files, True).values()])
    without = np.concatenate([r["pred"] - r["faz"] for r in predict_flight(m, files, False).values()])
    assert np.sqrt(np.mean(with_g ** 2)) * 1.8 < np.sqrt(np.mean(without ** 2))


def test_export_bit_exact_with_the_references(data, authors, tmp_path):
    """`ns2 export` of the authors' nets: float C == float32 reference and fixed C ==
    integer reference bit for bit on random queries over the whole input box (NaN, Inf
    and bad types included) and on every sample of two real flights."""
    from ns2exp.onboard_faz import flight_queries, flights
    from ns2host.cbuild import CModel

    man = export(authors, tmp_path / "gen")
    em = from_checkpoint(load_checkpoint(authors))
    cm = CModel(tmp_path / "gen")
    real = [flight_queries(flights(data / C20 / sc)[FLIGHTS[sc][0]])[0] for sc in ("swap_sl", "takeoff_s")]
    sets = [random_queries(em.cfg, 10_000, seed=s, wild=w) for s, w in ((1, 0.0), (2, 0.08))] + real
    total = 0
    for q in sets:
        c, info = cm.predict(q, fixed=False)
        r, sel = ref.predict_f32(em, q)
        assert np.array_equal(np.float32(c).view(np.uint32), np.float32(r).view(np.uint32))
        assert np.array_equal(info["status"], sel.status)
        ci, _ = cm.predict(q, fixed=True)
        ri, _ = ref.predict_q15(em, q)
        assert np.array_equal(ci, ri)
        total += len(q)
    assert total > 25_000
    q = Queries.concat(real)
    f, _ = cm.predict(q, fixed=False)
    i, _ = cm.predict(q, fixed=True)
    assert np.abs(i * 2.0 ** -em.q15.out_frac - f).max() < 0.5  # grams, on real states
    assert man["fixed_vs_float_error_g"]["typical"]["max_abs_g"] < 0.5


def test_authors_faz_command_reports_per_scenario_and_type(data, authors, tmp_path):
    """`ns2 real authors-faz` on a folder of two real flights: the JSON's numbers are
    those of predict_flight, per scenario and robot type, with and without the ground."""
    import json

    from cli import main
    from ns2exp.onboard_faz import flights, predict_flight

    root = tmp_path / "collection"
    for sc in ("swap_sl", "takeoff_s"):
        (root / sc).mkdir(parents=True)
        for f in flights(data / C20 / sc)[FLIGHTS[sc][0]].values():
            (root / sc / f.name).symlink_to(f)
    out = tmp_path / "faz.json"
    res = CliRunner().invoke(main, ["real", "authors-faz", str(authors), "--data", str(root), "--out", str(out)])
    assert res.exit_code == 0, res.output
    r = json.loads(out.read_text())
    assert set(r["with_ground"]["per_scenario"]) == {"swap_sl", "takeoff_s"}
    assert set(r["with_ground"]["per_scenario"]["swap_sl"]) == {"small", "large"}
    m = load_checkpoint(authors).model()
    got = predict_flight(m, flights(root / "swap_sl")[FLIGHTS["swap_sl"][0]], True)["101"]
    e = got["pred"] - got["faz"]
    large = r["with_ground"]["per_scenario"]["swap_sl"]["large"]
    assert large["samples"] == e.size and abs(large["rms_g"] - np.sqrt(np.mean(e ** 2))) < 1e-9
    assert 0.5 < large["corr"] < 1.0 and large["rms_g"] < 1.25 * FAZ_RMS[("swap_sl", 1)] + 0.05
    small = r["without_ground"]["per_scenario"]["takeoff_s"]["small"]
    assert small["rms_g"] > 1.8 * r["with_ground"]["per_scenario"]["takeoff_s"]["small"]["rms_g"]
