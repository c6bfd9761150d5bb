"""Every real collection (issue 52): the 2019 collections' folders and robots mapped to
scenarios and types, read, aligned and labelled on real files from
../shared/neural-swarm-data (extracted into build/test-real, never committed); bad
collections refused in one line; the blind scores' yardsticks (the causal offset, the
relabelling with other masses, the wake)."""
from __future__ import annotations

import shutil
from pathlib import Path
import struct
import zlib

import numpy as np
import pytest

from conftest import REAL_DATA, needs, real_logs
from ns2codegen.data.from_logs import Flight, flights_to_dataset, sample_info
from ns2codegen.logs.align import LogError, logs_to_flights
from ns2paper.collection import BY_KEY, COLLECTIONS, CollectionError, flights, write_collection_manifest
from ns2exp.real import _with_masses
from ns2exp.realscore import causal_offset, relabel, score

DEC = "neural-swarm-2019-12.tar.xz"
C11, C20 = BY_KEY["2019-12-11"], BY_KEY["2019-12-20"]
LSL = [f"{C20.folder}/swap_lsl/cf{n}_06" for n in (50, 101, 102)]
LS = [f"{C11.folder}/swap_large_small/cf{n}_00" for n in (50, 102)]
HOVER_G = {"small": 32.1, "large": 62.5}   # the collections' hover thrust (docs/real-flights.md)
TAKEOFF = [f"{C20.folder}/takeoff_landing_small/cf50_00"]


@pytest.fixture(scope="module")
def dec():
    return real_logs(DEC, LSL + LS + TAKEOFF)


@needs(REAL_DATA)
def test_the_2019_folders_map_to_scenarios_robots_and_types(dec):
    f20 = flights(dec, C20)
    assert [f["name"] for f in f20] == ["swap_sll/06", "takeoff_s/00"]
    assert [(r["id"], r["type"], r["label"]) for r in f20[0]["robots"]] == [
        ("cf50", "small", True), ("cf101", "large", True), ("cf102", "large", True)]
    assert f20[0]["folder"] == "swap_lsl" and f20[1]["folder"] == "takeoff_landing_small"
    f11 = flights(dec, C11)
    assert [f["name"] for f in f11] == ["swap_sl/00"]
    assert [(r["id"], r["type"]) for r in f11[0]["robots"]] == [("cf50", "small"), ("cf102", "large")]


@needs(REAL_DATA)
def test_a_2019_swap_is_read_aligned_and_labelled(dec, cfg):
    path = write_collection_manifest(dec, C20)
    text = path.read_text()
    assert 'file = "swap_lsl/cf50_06", type = "small", id = "cf50"' in text and "label = false" not in text
    fls, reps = logs_to_flights(cfg, path.parent)
    swap = next(r for r in reps if r["name"] == "swap_sll/06")
    # three robots aligned by the broadcast setpoints, to within a few milliseconds
    assert swap["sync"] == "setpoint events" and swap["alignment_error"]["events"] >= 4
    assert swap["alignment_error"]["residual_max_ms"] < 3.0
    ds = flights_to_dataset(_with_masses(cfg, HOVER_G), [f for f in fls if f.name == "swap_sll/06"])
    assert len(ds) > 3 * 1500 and set(ds.scenario_names) == {"{L,L}->S", "{S,L}->L"}
    # the labels of a swap with the hover-weighed masses: about 0 (median), the wake pushes down
    for k in (0, 1):
        assert abs(float(np.median(ds.label_g[ds.robot_type == k]))) < 1.5
    assert float(ds.label_g.min()) < -8.0
    take = next(r for r in reps if r["name"] == "takeoff_s/00")
    assert take["sync"] == "single robot" and "ground touch" in take["cut_s_by_reason_and_robot"]


@needs(REAL_DATA)
def test_a_bad_collection_is_refused_in_one_line(dec, tmp_path):
    root = tmp_path / "r"
    shutil.copytree(dec, root)
    base = root / C20.folder
    (base / "hover_test").mkdir()
    shutil.copy(base / "swap_lsl" / "cf50_06", base / "hover_test" / "cf50_00")
    with pytest.raises(CollectionError) as e:
        flights(root, C20)
    assert "hover_test: unknown scenario folder" in str(e.value) and len(str(e.value).splitlines()) == 1
    shutil.rmtree(base / "hover_test")
    shutil.copy(base / "swap_lsl" / "cf50_06", base / "swap_lsl" / "cf53_06")     # a robot of no known type
    with pytest.raises(CollectionError, match=r"swap_lsl/cf53_06: robot cf53 has no type"):
        flights(root, C20)
    (base / "swap_lsl" / "cf53_06").unlink()
    (base / "swap_sss").mkdir()                                                   # not the folder's team
    shutil.copy(base / "swap_lsl" / "cf101_06", base / "swap_sss" / "cf101_00")
    with pytest.raises(CollectionError, match=r"swap_sss/cf101_00: flight 00 flew robots cf101 \(team l\), "
                                              r"not the folder's team sss"):
        flights(root, C20)


def _fixed_log(names: list[str], rows: list[tuple]) -> bytes:
    """A uSD log of the deck's original format with these variables (another firmware's)."""
    head = bytes([len(names)]) + b"".join(n.encode() + b"," for n in names)
    out = head + struct.pack("<I", ~zlib.crc32(head) & 0xFFFFFFFF)
    rec = struct.Struct("<" + "".join(n[-2] for n in names))
    block = bytes([len(rows)]) + b"".join(rec.pack(*r) for r in rows)
    return out + block + struct.pack("<I", ~zlib.crc32(block) & 0xFFFFFFFF)


@needs(REAL_DATA)
def test_a_log_of_another_firmwares_variables_is_refused_naming_file_and_variables(dec, tmp_path, cfg):
    root = tmp_path / "r"
    shutil.copytree(dec, root)
    other = root / C11.folder / "swap_large_small" / "cf102_00"
    other.write_bytes(_fixed_log(["tick(I)", "acc.x(f)", "acc.z(f)"], [(10000 * k, 0.0, 1.0) for k in range(40)]))
    path = write_collection_manifest(root, C11)
    with pytest.raises(LogError) as e:
        logs_to_flights(cfg, path.parent)
    msg = str(e.value)
    assert len(msg.splitlines()) == 1 and "swap_large_small/cf102_00" in msg and "lacks the variables" in msg
    assert "stateEstimate.x" in msg      # the variables a log needs, by name


def test_every_collection_names_its_robots_and_tarballs():
    assert [c.key for c in COLLECTIONS] == ["2019-12-11", "2019-12-20", "2020-06-16"]
    assert all(c.robots[r] == ("small" if int(r[2:]) < 100 else "large") for c in COLLECTIONS for r in c.robots)
    assert set(BY_KEY["2020-06-16"].not_labelled) == {"cf100"} and not C11.not_labelled
    assert C20.scenario("swap_lsl") == "swap_sll" and C20.scenario("random_walk_small_ground") == "randomwalk_s"
    with pytest.raises(CollectionError, match="swap_xyz: unknown scenario folder"):
        C11.scenario("swap_xyz")


def test_the_causal_offset_removes_a_constant_and_never_looks_ahead():
    t = np.arange(2000) * 0.01
    robot = np.repeat([0, 1], 1000)
    t2 = np.concatenate([t[:1000], t[:1000]])
    res = np.where(robot == 0, 3.0, -2.0)
    sane = np.ones(2000, bool)
    off = causal_offset(res, robot, t2, sane)
    # 0 until the first residual 20 ms old, then the exponential approach (tau 2 s, 100 updates/s)
    assert off[0] == 0.0 and off[1] == 0.0 and off[2] > 0.0 and off[1000] == 0.0
    a = 1.0 - np.exp(-1.0 / 200.0)
    assert off[2] == pytest.approx(3.0 * a) and off[999] == pytest.approx(3.0 * (1 - (1 - a) ** 998))
    assert off[1999] == pytest.approx(-2.0 * (1 - (1 - a) ** 998))
    # a step in the residual does not move the offset of the samples before it, nor 20 ms after
    step = res.copy()
    step[500:1000] += 10.0
    off2 = causal_offset(step, robot, t2, sane)
    assert np.array_equal(off2[:502], off[:502]) and off2[502] > off[502]
    # an insane sample is never used: the offset holds over it
    sane2 = sane.copy()
    sane2[300:400] = False
    wild = res.copy()
    wild[300:400] = 1e4
    off3 = causal_offset(wild, robot, t2, sane2)
    assert np.all(np.abs(off3[:1000]) <= 3.0) and off3[350] == off3[301]
    # samples given out of time order get the same offsets
    perm = np.random.default_rng(0).permutation(2000)
    assert np.array_equal(causal_offset(res[perm], robot[perm], t2[perm], sane[perm]), off[perm])


def _flight(n: int = 400) -> Flight:
    """Two robots: a small one hovering at 1 m, a large one passing 0.3 m above it."""
    t = np.arange(n) * 0.01
    p = np.zeros((n, 2, 3))
    p[:, 0, 2] = 1.0
    p[:, 1] = np.stack([np.linspace(-1.0, 1.0, n), np.zeros(n), np.full(n, 1.3)], 1)
    v = np.zeros_like(p)
    v[:, 1, 0] = 2.0 / ((n - 1) * 0.01)
    v[:, 0, 2] = 0.05 * np.sin(t * 7.0)   # some vertical acceleration: load factor != 1
    q = np.zeros((n, 2, 4))
    q[..., 0] = 1.0
    return Flight(["small", "large"], t, p, v, q, np.full((n, 2, 4), 0.6), np.full((n, 2), 3.9),
                  fa_onboard_g=np.full((n, 2), 1.5), name="x/swap_sl/00", robots=["cf50", "cf102"])


def test_sample_info_finds_the_wake_and_relabels_exactly(cfg):
    fl = _flight()
    ds = flights_to_dataset(cfg, [fl])
    info = sample_info(cfg, [fl])
    assert len(info["t_s"]) == len(ds) and info["robot_ids"] == ["x/swap_sl/00#cf50", "x/swap_sl/00#cf102"]
    small = info["robot"] == 0
    xy = info["above_xy_m"][small]
    # the large robot passes over x = 0 halfway: within 0.15 m for 0.3 m of its 2 m path
    inside = xy <= 0.15
    assert 0.12 < inside.mean() < 0.18 and np.all(np.isinf(info["above_xy_m"][~small]))
    assert np.all(info["onboard_g"] == 1.5)
    masses = {t: cfg.vehicle(t)["mass_g"] for t in cfg.robot_types}
    other = {"small": masses["small"] + 1.7, "large": masses["large"] - 2.9}
    ds2 = flights_to_dataset(_with_masses(cfg, other), [fl])
    got = relabel(ds.label_g, info, ds.robot_type, masses, other, cfg.robot_types)
    assert np.abs(got - ds2.label_g).max() < 2e-5 * np.abs(ds2.label_g).max() + 1e-5
    s = score(ds.label_g, np.zeros(len(ds)), info, ds.robot_type, cfg.robot_types, ds.scenario, ds.scenario_names)
    assert s["wake"]["samples"] == int((info["above_xy_m"] <= 0.15).sum())
    assert s["wake_by_type"]["large"]["samples"] == 0 and s["wake_by_type"]["small"]["samples"] > 0
    assert s["plain"] == pytest.approx(float(np.mean(ds.label_g.astype(float) ** 2)), rel=1e-3)


def _history_cfg(cfg, lags):
    import copy

    from ns2codegen.config import Config
    raw = copy.deepcopy(cfg.raw)
    raw["model"]["history_ms"] = lags
    return Config.from_dict(raw)


def test_history_inputs_are_the_same_neighbours_states_that_long_ago(cfg):
    fl = _flight()
    now = flights_to_dataset(cfg, [fl])
    hcfg = _history_cfg(cfg, [50, 100, 200])
    ds = flights_to_dataset(hcfg, [fl])
    assert hcfg.input_dim == 24 and hcfg.phi_dims()[0] == 24 and ds.nbr_state.shape[1] == 24
    assert np.array_equal(ds.nbr_offsets, now.nbr_offsets) and np.array_equal(ds.nbr_type, now.nbr_type)
    assert np.array_equal(ds.nbr_state[:, :6], now.nbr_state) and np.array_equal(ds.label_g, now.label_g)
    # the small robot's row of its large neighbour: sample k's lag-50 ms block is sample k-5's present state
    rows = np.flatnonzero((np.repeat(now.robot_type, np.diff(now.nbr_offsets)) == 0) & (now.nbr_type == 1))
    assert len(rows) > 300
    for lag, col in ((5, 6), (10, 12), (20, 18)):
        assert np.array_equal(ds.nbr_state[rows[lag:], col:col + 6], now.nbr_state[rows[:-lag], :6])
    # less than 200 ms into the piece, the piece's first state: the large robot starts at x = -1 m
    assert ds.nbr_state[rows[0], 18] == np.float32(-1.0) and now.nbr_state[rows[0], 0] > -1.0


def test_history_is_validated_trained_and_exported(cfg, tmp_path):
    from ns2codegen.checkpoint import load_checkpoint, save_checkpoint
    from ns2codegen.config import ConfigError
    from ns2codegen.data.dataset import DatasetError
    from ns2codegen.model import HeteroDeepSet
    from ns2codegen.quantize import from_checkpoint
    from ns2codegen.train import train

    for bad in ([100, 50], [0], [50, 50], "50", [3000], [1.5]):
        with pytest.raises(ConfigError, match="model.history_ms"):
            _history_cfg(cfg, bad)
    hcfg = _history_cfg(cfg, [50])
    with pytest.raises(DatasetError, match="phi takes 12"):
        train(hcfg, flights_to_dataset(cfg, [_flight()]), epochs=1)
    model, rep = train(hcfg, flights_to_dataset(hcfg, [_flight()]), epochs=1)
    assert model.phi[0].layers[0].in_features == 12 and np.isfinite(rep["validation"]["mse"])
    save_checkpoint(tmp_path / "h.pt", model, hcfg, {"seed": 0, "data_hash": None})
    em = from_checkpoint(load_checkpoint(tmp_path / "h.pt"))   # the C export (tests/test_c_inference.py)
    assert em.phi[0][0][0].shape[1] == 12 and em.q15.phi[0].layers[0].n_in == 12
    assert em.phi_box(0).shape == (12, 2) and np.array_equal(em.phi_box(0)[6:], em.boxes[0])
    assert HeteroDeepSet(cfg).phi[0].layers[0].in_features == 6


def test_the_memory_verdict_needs_more_than_the_seeds_spread():
    from ns2exp.blind import memory, memory_table

    def res(wake_mean, wake_std):
        m = {"labels": {"plain": 3.0, "neutral": 2.0, "wake": {"plain": 9.0,
                        "neutral": {"mean": wake_mean, "std": wake_std}}}}
        return {"leave_one_collection_out": {"2020-06-16": {"models": {"ours": m}}}}

    now = res(10.0, 0.5)
    assert memory(now, res(8.9, 0.5))["collection 2020-06-16 left out"]["wake_lower_beyond_spread"]
    rows = memory(now, res(9.1, 0.5))
    assert not rows["collection 2020-06-16 left out"]["wake_lower_beyond_spread"]
    assert "| collection 2020-06-16 left out | 10.00 +- 0.50 / 9.10 +- 0.50 |" in memory_table(rows, [50, 100, 200])


def test_a_blind_split_is_a_collection_left_out_or_the_held_out_flights(tmp_path):
    """`ns2 real blind --collection` names any blind split, the held-out flights (heldout)
    included; a split without its trained networks, or an unknown name, is one line."""
    from ns2exp.blind import HELDOUT, blind
    from ns2exp.real import RealDataError

    shutil.copy(Path(__file__).resolve().parent.parent / "ns2codegen" / "default.toml", tmp_path / "real.toml")
    with pytest.raises(RealDataError, match=r"heldout: no trained network"):
        blind(tmp_path, collections=[HELDOUT])
    with pytest.raises(RealDataError, match=r"loco-2019-12-11: no trained network"):
        blind(tmp_path, collections=["2019-12-11", HELDOUT])
    with pytest.raises(RealDataError, match=r"collection 2019-12-31: not one of 2019-12-11, .*, heldout"):
        blind(tmp_path, collections=["2019-12-31"])
