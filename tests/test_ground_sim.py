"""`ns2 fly --sim`: the paper's swap (a small and a large robot exchanging places, one
passing under the other) from a Crazyswarm2 swarm file, through the same mission code
as a real flight, flown in the C-in-the-loop simulator; its radio log has what the
real one has, and `ns2 logs-to-data` reads the uSD logs it writes."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import FIRMWARE, needs
from ns2cli import main
from ns2plan.output import poly4d_bytes

pytestmark = needs(FIRMWARE)   # the simulator's EKF and controller come from the firmware

SWARM = """\
# Crazyswarm2 layout; ns2 types through robot_types
robots:
  cf3:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E703
    initial_position: [0.0, -0.5, 0.0]
    type: cf21
  cf4:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E704
    initial_position: [0.0, 0.5, 0.0]
    type: big
  cf5:
    enabled: false
    uri: radio://0/80/2M/E7E7E7E705
    initial_position: [1.0, 0.0, 0.0]
    type: cf21
robot_types:
  cf21: {ns2_type: small}
  big: {ns2_type: large}
"""
SWAP_S = 3.0
TAKEOFF_S = 1.0   # the dry run hovers at the take-off point from the take-off command on


def _swap_piece(a, b, duration):
    """One poly4d piece from rest at a to rest at b (7th-degree rest-to-rest profile)."""
    prof = np.array([0, 0, 0, 0, 35.0, -84.0, 70.0, -20.0]) / duration ** np.arange(8)
    c = np.zeros((4, 8))
    for ax in range(3):
        c[ax] = (b[ax] - a[ax]) * prof
        c[ax, 0] = a[ax]
    return duration, c


def test_fly_sim_flies_the_swap_and_writes_both_logs(exported, tmp_path):
    (tmp_path / "crazyflies.yaml").write_text(SWARM)
    plan = tmp_path / "plan"
    plan.mkdir()
    small_a, small_b = (0.0, -0.5, 0.4), (0.0, 0.5, 0.4)     # the small robot passes under the large one
    large_a, large_b = (0.0, 0.5, 0.8), (0.0, -0.5, 0.8)
    (plan / "robot0_small.bin").write_bytes(poly4d_bytes([_swap_piece(small_a, small_b, SWAP_S)]))
    (plan / "robot1_large.bin").write_bytes(poly4d_bytes([_swap_piece(large_a, large_b, SWAP_S)]))
    log = tmp_path / "flight.jsonl"
    r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(tmp_path / "crazyflies.yaml"), "--plan", str(plan),
                                  "--log", str(log), "--sim", "--takeoff-s", "1", "--land-s", "1.5", "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["pieces"] == {"cf3": 1, "cf4": 1} and rep["simulated_s"] > SWAP_S + 1.0
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    assert lines[0] == {"flight": {"robots": {"cf3": "small", "cf4": "large"}, "sync": rep["sync"]}}
    lines = lines[1:]
    by = {n: [x for x in lines if x["robot"] == n] for n in ("cf3", "cf4")}
    assert all(len(v) > 60 for v in by.values())
    for name, a, b in (("cf3", small_a, small_b), ("cf4", large_a, large_b)):
        rows = by[name]
        t = np.array([x["t_ms"] for x in rows]) / 1000.0
        p = np.array([[x["stateEstimate.x"], x["stateEstimate.y"], x["stateEstimate.z"]] for x in rows])
        assert np.all(np.diff(t) > 0)
        assert np.abs(p[0] - a).max() < 0.1, (name, p[0])                 # hovering at the start
        i_end = np.searchsorted(t, t[0] + TAKEOFF_S + SWAP_S - 0.05)      # the other side, before landing
        assert np.abs(p[i_end, :2] - b[:2]).max() < 0.1, (name, p[i_end])
        assert p[-1, 2] < 0.15 and np.abs(p[-1, :2] - b[:2]).max() < 0.1     # landed there
        e = np.array([[x["ns2.ex"], x["ns2.ey"], x["ns2.ez"]] for x in rows])
        assert np.abs(e).max() < 0.2 and all(x["pm.vbat"] > 3.0 for x in rows)
    # the small robot under the large one feels its downwash, and the model predicts it (g)
    fa_small = np.array([x["ns2.faHat"] for x in by["cf3"]])
    assert fa_small.min() < -1.0, fa_small.min()
    # what the uSD cards would hold goes through the real-flight path
    out = tmp_path / "data.npz"
    r = CliRunner().invoke(main, ["logs-to-data", rep["usd"], "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["samples"] > 100
    # and the radio log itself becomes a labelled data set (20 Hz, the ground's clock)
    radio = tmp_path / "radio.npz"
    r = CliRunner().invoke(main, ["logs-to-data", str(log), "--out", str(radio), "--json"])
    assert r.exit_code == 0, r.output
    rep2 = json.loads(r.output)
    assert rep2["flights"][0]["sync"] == "ground receive time (radio log)" and rep2["flights"][0]["rate_hz"] == 20.0
    from ns2codegen.data.dataset import Dataset
    usd_ds, radio_ds = Dataset.load(out), Dataset.load(radio)
    assert len(radio_ds) > 80 and set(radio_ds.robot_type.tolist()) == {0, 1}
    for ty in (0, 1):   # the same flight's labels from both logs: the small robot's downwash, none above
        a, b = usd_ds.label_g[usd_ds.robot_type == ty], radio_ds.label_g[radio_ds.robot_type == ty]
        assert np.all(np.isfinite(b)) and abs(np.median(a) - np.median(b)) < 0.2, (ty, np.median(a), np.median(b))
        assert (b.min() < 0.5 * a.min()) if ty == 0 else (b.min() > -3.0), (ty, a.min(), b.min())


FAULT_S = 0.9   # after the take-off command: 0.4 s into the trajectories


@pytest.mark.parametrize("fault, cause", [
    (f"lost-link:cf4@{FAULT_S}", "cf4: link lost"), (f"low-battery:cf3@{FAULT_S}", "cf3: battery 3.00 V below 3.3 V"),
    (f"app-status:cf4@{FAULT_S}", "cf4: app status -3"), (f"ctrl-c@{FAULT_S}", "Ctrl-C")])
def test_fly_sim_rehearses_the_safety_paths(exported, tmp_path, fault, cause):
    """A fault during the trajectories of a dry run: the mission's own safety path lands
    every robot it can still reach, and the landing is flown to its end and logged."""
    (tmp_path / "crazyflies.yaml").write_text(SWARM)
    plan = tmp_path / "plan"
    plan.mkdir()
    (plan / "robot0_small.bin").write_bytes(poly4d_bytes([_swap_piece((0.0, -0.5, 0.4), (0.0, 0.5, 0.4), SWAP_S)]))
    (plan / "robot1_large.bin").write_bytes(poly4d_bytes([_swap_piece((0.0, 0.5, 0.8), (0.0, -0.5, 0.8), SWAP_S)]))
    log = tmp_path / "flight.jsonl"
    r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(tmp_path / "crazyflies.yaml"), "--plan", str(plan),
                                  "--log", str(log), "--sim", "--takeoff-s", "0.5", "--land-s", "0.8", "--sim-fault", fault])
    assert r.exit_code == 1, r.output
    last = r.output.strip().splitlines()[-1]
    lost = "cf4" if fault.startswith("lost-link") else None
    assert f"flight ended early ({cause}): landing {'cf3' if lost else 'cf3, cf4'}; log {log}" in last, last
    lines = [json.loads(x) for x in log.read_text().splitlines()[1:]]
    for name in ("cf3", "cf4"):
        rows = [x for x in lines if x["robot"] == name]
        t = np.array([x["t_ms"] for x in rows]) / 1000.0
        z = np.array([x["stateEstimate.z"] for x in rows])
        if name == lost:   # nothing heard from it after the loss
            assert t[-1] < FAULT_S + 0.06 and z[-1] > 0.6
            continue
        assert t[-1] > FAULT_S + 0.8 and z[-1] < 0.15, (name, t[-1], z[-1])   # landed, long before the plan's end
        assert np.abs(z[t < FAULT_S] - (0.4 if name == "cf3" else 0.8)).max() < 0.1      # flying until the fault
    from ns2codegen.logs.usdlog import FIXED_FREQUENCY_NAME, read
    usd = [read(tmp_path / "flight-usd" / "flight" / f"cf{i}.usd").event(FIXED_FREQUENCY_NAME) for i in (0, 1)]
    z_end = [float(u["stateEstimate.z"][-1]) for u in usd]
    # the simulator's own log (uSD): the robot without a link flew on, the others are down
    assert z_end[0] < 0.15 and ((z_end[1] > 0.6) if lost else (z_end[1] < 0.15)), z_end


LAB_SWARM = """\
# a lab's own numbering (issue 56): large robots above radio id 31
robots:
  cf200:
    uri: radio://0/80/2M/E7E7E7E7C8
    initial_position: [0.0, -0.5, 0.0]
    type: cf21
  cf40:
    uri: radio://0/80/2M/E7E7E7E728
    initial_position: [0.0, 0.5, 0.0]
    type: big
  cf255:
    uri: radio://0/80/2M/E7E7E7E7FF
    initial_position: [1.5, 0.0, 0.0]
    type: big
robot_types:
  cf21: {ns2_type: small}
  big: {ns2_type: large}
"""


def test_fly_sim_flies_large_robots_with_radio_ids_above_31(exported, tmp_path, monkeypatch):
    """`ns2 fly --sim` with large robots numbered 40 and 255 and a small one 200: the
    mission writes the type table ns2type.t0..t15 to every robot, the simulated robots
    fly under those radio ids and look their peers' types up in it as the app does, and
    the small robot passing under large robot 40 predicts its downwash; with the table
    all zero (every peer small) it predicts far less."""
    from ns2ground import sim as gsim

    (tmp_path / "crazyflies.yaml").write_text(LAB_SWARM)
    plan = tmp_path / "plan"
    plan.mkdir()
    small_a, small_b = (0.0, -0.5, 0.4), (0.0, 0.5, 0.4)
    large_a, large_b = (0.0, 0.5, 0.8), (0.0, -0.5, 0.8)
    (plan / "cf200.bin").write_bytes(poly4d_bytes([_swap_piece(small_a, small_b, SWAP_S)]))
    (plan / "cf40.bin").write_bytes(poly4d_bytes([_swap_piece(large_a, large_b, SWAP_S)]))
    (plan / "cf255.bin").write_bytes(poly4d_bytes([_swap_piece((1.5, 0.0, 0.6), (1.5, 0.0, 0.6), SWAP_S)]))
    seen = {}
    real_start = gsim.SimSwarm._start

    def start(self):
        real_start(self)
        seen["ids"] = [int(r.id) for r in self.sim.robots]
        seen["tables"] = [list(r.type_table) for r in self.sim.robots]
    monkeypatch.setattr(gsim.SimSwarm, "_start", start)

    def fly(log):
        r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(tmp_path / "crazyflies.yaml"), "--plan",
                                      str(plan), "--log", str(log), "--sim", "--takeoff-s", "1", "--land-s", "1.5",
                                      "--json"])
        assert r.exit_code == 0, r.output
        rows = [json.loads(x) for x in log.read_text().splitlines()]
        assert rows[0]["flight"]["robots"] == {"cf200": "small", "cf40": "large", "cf255": "large"}
        by = {n: [x for x in rows[1:] if x["robot"] == n] for n in ("cf200", "cf40", "cf255")}
        for name, b in (("cf200", small_b), ("cf40", large_b)):
            t = np.array([x["t_ms"] for x in by[name]]) / 1000.0
            p = np.array([[x["stateEstimate.x"], x["stateEstimate.y"]] for x in by[name]])
            i_end = np.searchsorted(t, t[0] + TAKEOFF_S + SWAP_S - 0.05)
            assert np.abs(p[i_end] - b[:2]).max() < 0.1, (name, p[i_end])        # swapped
        return np.array([x["ns2.faHat"] for x in by["cf200"]])

    fa = fly(tmp_path / "flight.jsonl")
    assert seen["ids"] == [200, 40, 255]
    table = seen["tables"][0]
    assert all(t == table for t in seen["tables"])            # the same table on every robot
    assert {i for i in range(256) if (table[i // 16] >> (2 * (i % 16))) & 3} == {40, 255}
    assert fa.min() < -1.0, fa.min()
    # the same flight with the type table left at the app's boot value (every peer small)
    monkeypatch.setattr(gsim, "TYPE_PARAMS", ("t_unwritten",) * 16)
    fa0 = fly(tmp_path / "untyped.jsonl")
    assert seen["tables"][0] == [0] * 16 and fa0.min() > 0.7 * fa.min(), (fa.min(), fa0.min())   # -4.8 g, -9.7 g


def test_fly_sim_flies_the_adaptation_a_robot_is_given(exported, tmp_path):
    """Issue 53 item 5: a robot whose swarm file turns the on-board adaptation on flies it
    (ns2adapt.* of the swarm file reach the simulated app), and the radio log's block ns2e
    has its bias, trace of P, label and statuses; the other robot's stays off (status OFF,
    bias 0) with its label still logged."""
    swarm = SWARM.replace("    type: cf21\n  cf4:", "    type: cf21\n    firmware_params: {ns2adapt: {enable: 1}}\n  cf4:", 1)
    (tmp_path / "crazyflies.yaml").write_text(swarm)
    plan = tmp_path / "plan"
    plan.mkdir()
    hold = 3.0
    (plan / "robot0_small.bin").write_bytes(poly4d_bytes([_swap_piece((0.0, -0.5, 0.4), (0.0, -0.5, 0.4), hold)]))
    (plan / "robot1_large.bin").write_bytes(poly4d_bytes([_swap_piece((0.0, 0.5, 0.8), (0.0, 0.5, 0.8), hold)]))
    log = tmp_path / "flight.jsonl"
    r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(tmp_path / "crazyflies.yaml"), "--plan", str(plan),
                                  "--log", str(log), "--sim", "--takeoff-s", "1", "--land-s", "1.5", "--json"])
    assert r.exit_code == 0, r.output
    rows = [json.loads(x) for x in log.read_text().splitlines()[1:]]
    on, off = ([x for x in rows if x["robot"] == n] for n in ("cf3", "cf4"))
    updated = 1   # NS2_ADAPT_UPDATED
    assert sum(x["ns2adapt.status"] & updated for x in on) > len(on) // 2
    assert any(x["ns2adapt.bias"] != 0.0 for x in on) and all(0.0 < x["ns2adapt.trP"] <= 20.0 for x in on)
    assert all(x["ns2adapt.bias"] == 0.0 and x["ns2adapt.status"] == 2 for x in off)   # NS2_ADAPT_OFF
    assert any(x["ns2adapt.label"] != 0.0 for x in off)
