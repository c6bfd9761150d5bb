"""The swarm file (Crazyswarm2's crazyflies.yaml): one loader, one-line errors naming the
robot and key, and `ns2 swarm-params` writing the app's parameters without touching the
rest of the user's file."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from ns2cli import main
from ns2codegen.vehicle import default_gains, vehicle
from ns2ground import swarm as sw

SWARM = """\
# my lab's swarm (Crazyswarm2 layout)
fileversion: 3

robots:
  cf1:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E701   # the small one
    initial_position: [0.0, -0.5, 0.0]
    type: cf21
    firmware_params:
      stabilizer: {estimator: 2, controller: 5}  # OOT
  cf7:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E707
    initial_position: [0.0, 0.5, 0]
    type: big
  cf9:
    enabled: false
    uri: radio://0/90/2M/E7E7E7E709
    initial_position: [1.0, 0.5, 0]
    type: cf21

robot_types:
  cf21:
    motion_capture: {enabled: true, marker: default_single_marker}
    big_quad: false
    ns2_type: small
  big:
    ns2_type: large   # parrot motors

all:
  firmware_logging:
    enabled: false
  broadcasts:
    num_repeats: 15
"""


@pytest.fixture
def swarm_file(tmp_path):
    p = tmp_path / "crazyflies.yaml"
    p.write_text(SWARM)
    return p


def test_loader_reads_crazyswarm2_layout(swarm_file, cfg):
    s = sw.load(swarm_file, cfg)
    assert [(r.name, r.ns2_type, r.radio_id, r.enabled) for r in s.robots] == [
        ("cf1", "small", 1, True), ("cf7", "large", 7, True), ("cf9", "small", 9, False)]
    assert [r.name for r in s.enabled] == ["cf1", "cf7"]
    assert s.robots[1].initial_position == [0.0, 0.5, 0.0]
    p = sw.params(s, cfg, s.robots[1])
    assert p["ns2"] == {"selfType": 1} and p["ns2type"] == {"mask1": 1 << 7, "mask2": 0}
    g = default_gains(vehicle(cfg, "large"))
    assert p["ns2gain"]["Kvz"] == pytest.approx(g["Kv"][2]) and p["ns2gain"]["faMaxN"] == pytest.approx(g["fa_max_N"])
    assert len(p["ns2gain"]) == 7 * 3 + 3


def test_swarm_params_changes_only_the_app_groups(swarm_file, exported):
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(swarm_file), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["robots"]["cf7"]["ns2"] == {"selfType": 1} and out["robots"]["cf1"]["ns2type"]["mask1"] == 128
    text = swarm_file.read_text()
    # every line of the user's file is still there, in order, comments included
    old = SWARM.splitlines()
    it = iter(text.splitlines())
    assert all(any(line == new for new in it) for line in old), text
    s = sw.load(swarm_file, exported.cfg)
    assert s.robots[0].firmware_params["stabilizer"] == {"estimator": 2, "controller": 5}
    assert s.robots[0].firmware_params["ns2gain"] == sw.params(s, exported.cfg, s.robots[0])["ns2gain"]
    # a second run changes nothing (idempotent)
    before = swarm_file.read_bytes()
    assert CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(swarm_file)]).exit_code == 0
    assert swarm_file.read_bytes() == before


def test_swarm_params_keeps_the_users_gains(swarm_file, exported):
    """Gains the user set in a robot's firmware_params.ns2gain stay; the others are the defaults."""
    swarm_file.write_text(SWARM.replace("stabilizer: {estimator: 2, controller: 5}", "ns2gain: {Lpx: 9.5}"))
    assert CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(swarm_file)]).exit_code == 0
    s = sw.load(swarm_file, exported.cfg)
    g = default_gains(vehicle(exported.cfg, "small"))
    assert s.robots[0].firmware_params["ns2gain"]["Lpx"] == 9.5
    assert s.robots[0].firmware_params["ns2gain"]["Lpy"] == pytest.approx(g["Lp"][1])
    assert s.robots[2].firmware_params["ns2gain"]["Lpx"] == pytest.approx(g["Lp"][0])


@pytest.mark.parametrize("edit, message", [
    (("type: big\n", "type: huge\n"), "robots.cf7.type: 'huge' is not a robot type"),
    (("ns2_type: large", "ns2_type: tiny"), "robot_types.big.ns2_type: 'tiny'"),
    (("E7E7E7E707", "E7E7E7E701"), "robots.cf7.uri: radio id 1 (last address byte) is also robots.cf1's"),
    (("radio://0/80/2M/E7E7E7E707", "usb://0"), "robots.cf7.uri: 'usb://0': not a radio uri"),
    (("enabled: false", "enabled: maybe"), "robots.cf9.enabled: must be true or false"),
    (("[1.0, 0.5, 0]", "[1.0, 0.5]"), "robots.cf9.initial_position: must be three numbers"),
    (("E7E7E7E707", "E7E7E7E740"), "robots.cf7.uri: radio id 64 of a large robot must be below 32"),
    (("robots:", "robotz:"), "robots: missing or empty"),
    (("fileversion: 3", "fileversion: [3"), "not YAML"),
    (("stabilizer: {estimator: 2, controller: 5}", "ns2gain: {Lpw: 3.0}"),
     "robots.cf1.firmware_params.ns2gain.Lpw: not a gain of the app"),
    (("stabilizer: {estimator: 2, controller: 5}", "ns2gain: {Lpx: .nan}"),
     "robots.cf1.firmware_params.ns2gain.Lpx: nan is not a finite number"),
])
def test_bad_swarm_file_is_one_line_naming_robot_and_key(swarm_file, exported, edit, message):
    swarm_file.write_text(SWARM.replace(*edit))
    before = swarm_file.read_bytes()
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(swarm_file)])
    assert r.exit_code == 1, r.output
    line = r.output.strip()
    assert "\n" not in line and str(swarm_file) in line and message in line, line
    assert swarm_file.read_bytes() == before      # nothing written
