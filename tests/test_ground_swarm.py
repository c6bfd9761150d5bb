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
    # the type table: radio id 7 is a large robot (type 1), 2 bits per id, 16 ids per word
    assert p["ns2"] == {"selfType": 1} and p["ns2type"] == {f"t{k}": (1 << 14 if k == 0 else 0) for k in range(16)}
    g = default_gains(vehicle(cfg, "large"))
    assert p["ns2gain"]["Kvz"] == pytest.approx(g["Kv"][2]) and p["ns2gain"]["faMaxN"] == pytest.approx(g["fa_max_N"])
    assert len(p["ns2gain"]) == 7 * 3 + 3


def test_swarm_params_changes_only_the_app_groups(swarm_file, exported):
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(swarm_file), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["robots"]["cf7"]["ns2"] == {"selfType": 1} and out["robots"]["cf1"]["ns2type"]["t0"] == 1 << 14
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
    (("[1.0, 0.5, 0]", "[1.0, 0.5]"), "robots.cf9.initial_position: must be three finite numbers"),
    (("E7E7E7E707", "E7E7E7E700"), "robots.cf7.uri: radio id 0 (last address byte 00): crazyflie-firmware's peer "
                                   "localization takes id 0 for a free slot"),
    (("radio://0/80/2M/E7E7E7E707", "radio://0/126/2M/E7E7E7E707"), "robots.cf7.uri: 'radio://0/126/2M/E7E7E7E707': "
                                                                     "channel 126: the radio's channels are 0..125"),
    (("radio://0/80/2M/E7E7E7E707", '"radio://0/80/2M/E7E7E7E707\\n"'), "robots.cf7.uri: 'radio://0/80/2M/E7E7E7E707\\n'"),
    (("radio://0/80/2M/E7E7E7E707", "radio://\u0660/80/2M/E7E7E7E707"), "robots.cf7.uri: 'radio://\u0660/80/2M/"),
    (("radio://0/80/2M/E7E7E7E707", "radio://0/80/2M/E7E7E7E707?$(reboot)"), "robots.cf7.uri: "),
    (("  cf7:\n", "  7cf:\n"), "robots: '7cf': a robot's name is a ROS name"),
    (("  cf7:\n", '  "cf 7\\n":\n'), "robots: 'cf 7\\n': a robot's name is a ROS name"),
    (("[1.0, 0.5, 0]", "[1.0, 0.5, .inf]"), "robots.cf9.initial_position: must be three finite numbers"),
    (("[1.0, 0.5, 0]", "[1.0, 0.5, 1" + "0" * 400 + "]"), "robots.cf9.initial_position: must be three finite numbers"),
    (("robot_types:\n", "robot_types: [1]\nxrobot_types:\n"), "robot_types: not a mapping"),
    (("ns2_type: large", "ns2_type: [large]"), "robot_types.big.ns2_type: ['large'] is not a robot type"),
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


# ------------------------------------------------------------------ issue 56
LAB = """\
robots:
  cf1:
    uri: radio://0/80/2M/E7E7E7E701
    type: cf21
  big40:
    uri: radio://0/80/2M/E7E7E7E728   # radio id 40
    type: big
    firmware_params:
      ns2type: {mask1: 128, mask2: 0}   # written by an older ns2 swarm-params
      ns2: {enable: 1}
  big255:
    uri: radio://0/90/2M/E7E7E7E7FF
    type: big
  cf200:
    uri: radio://0/90/2M/E7E7E7E7C8
    type: cf21
robot_types:
  cf21: {ns2_type: small}
  big: {ns2_type: large}
"""


def _type_of(table: dict, rid: int) -> int:
    """The app's ns2_type_table_get, in Python (the C one: tests/test_peers.py)."""
    return (table[f"t{rid // 16}"] >> (2 * (rid % 16))) & 3


def test_any_radio_id_for_any_robot_type(tmp_path, exported):
    """Large robots with radio ids 40 and 255 (above the 32 bits of the old masks): the
    type table ns2type.t0..t15 names every robot's type under its id, the same on every
    robot; swarm-params writes it and drops the old app's keys of the group."""
    f = tmp_path / "crazyflies.yaml"
    f.write_text(LAB)
    s = sw.load(f, exported.cfg)
    assert [(r.name, r.radio_id, r.ns2_type) for r in s.robots] == [
        ("cf1", 1, "small"), ("big40", 40, "large"), ("big255", 255, "large"), ("cf200", 200, "small")]
    tables = [sw.params(s, exported.cfg, r)["ns2type"] for r in s.robots]
    assert all(t == tables[0] for t in tables) and list(tables[0]) == [f"t{k}" for k in range(16)]
    assert {i: _type_of(tables[0], i) for i in range(256) if _type_of(tables[0], i)} == {40: 1, 255: 1}
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(f), "--json"])
    assert r.exit_code == 0, r.output
    s = sw.load(f, exported.cfg)
    for rob in s.robots:
        assert dict(rob.firmware_params["ns2type"]) == tables[0], rob.name      # mask1/mask2 gone
    assert s.robots[1].firmware_params["ns2"] == {"enable": 1, "selfType": 1}   # the rest of the group stays
    assert "# radio id 40" in f.read_text() and "mask1" not in f.read_text()


def test_radio_id_0_alone_or_with_the_others_disabled(tmp_path, cfg):
    """Id 0 is a radio address like any other for a robot that flies alone; in a swarm
    no other robot's firmware would see it (docs/flying.md), so it is refused there."""
    f = tmp_path / "crazyflies.yaml"
    f.write_text(LAB.replace("E7E7E7E701", "E7E7E7E700").replace("type: big\n", "type: big\n    enabled: false\n")
                 .replace("type: cf21\nrobot_types", "type: cf21\n    enabled: false\nrobot_types"))
    s = sw.load(f, cfg)
    assert [(r.name, r.radio_id) for r in s.enabled] == [("cf1", 0)]
    f.write_text(LAB.replace("E7E7E7E701", "E7E7E7E700"))
    with pytest.raises(sw.SwarmFileError, match=r"robots\.cf1\.uri: radio id 0 .* no other robot would see robots\.cf1"):
        sw.load(f, cfg)


NOT_UTF8 = {
    "binary": bytes(range(256)) * 4,
    "utf16-bom": SWARM.encode("utf-16"),
    "utf16-be-bom": b"\xfe\xff" + SWARM.encode("utf-16-be"),
    "utf32-bom": SWARM.encode("utf-32"),
    "utf16-no-bom": SWARM.encode("utf-16-le"),
    "latin1": SWARM.replace("the small one", "the small one, r\u00e9par\u00e9").encode("latin-1"),
    "nul": SWARM.encode().replace(b"cf21:\n", b"cf21:\x00\n"),
}


@pytest.mark.parametrize("kind", sorted(NOT_UTF8))
@pytest.mark.parametrize("command", ["swarm-params", "flash", "fly"])
def test_a_swarm_file_that_is_not_utf8_is_one_line(tmp_path, exported, kind, command):
    """Issue 56: a binary file, UTF-16/32 with or without a byte-order mark, Latin-1, a
    NUL byte: one line naming the file in ns2 swarm-params, ns2 flash --swarm, ns2 fly;
    no traceback, nothing written."""
    f = tmp_path / "crazyflies.yaml"
    f.write_bytes(NOT_UTF8[kind])
    args = {"swarm-params": ["swarm-params", exported.gen_dir, f],
            "flash": ["flash", tmp_path / "cf2.bin", "--swarm", f],
            "fly": ["fly", exported.gen_dir, f, "--plan", tmp_path, "--log", tmp_path / "f.jsonl"]}[command]
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), (r.output, r.exception)
    line, = r.output.strip().splitlines()
    assert line.startswith("Error: ") and str(f) in line and "Traceback" not in r.output, line
    assert ("UTF-16" in line or "UTF-32" in line) if "bom" in kind else ("UTF-8" in line or "NUL" in line), line
    assert f.read_bytes() == NOT_UTF8[kind] and sorted(p.name for p in tmp_path.iterdir()) == ["crazyflies.yaml"]


def test_utf8_with_a_byte_order_mark_is_read_and_kept(tmp_path, exported):
    f = tmp_path / "crazyflies.yaml"
    f.write_bytes(b"\xef\xbb\xbf" + SWARM.encode())
    assert [r.name for r in sw.load(f, exported.cfg).robots] == ["cf1", "cf7", "cf9"]
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(f)])
    assert r.exit_code == 0, r.output
    assert f.read_bytes().startswith(b"\xef\xbb\xbf# my lab's swarm") and sw.load(f, exported.cfg).robots[0].firmware_params


@pytest.mark.parametrize("text, message", [
    ("robots: {cf1: {uri: 'radio://0/80/2M/E7E7E7E701', type: cf21}}\nall: " + "[" * 100_000 + "]" * 100_000 + "\n",
     "flow collections ([...], {...}) nested deeper than 32 levels"),
    ("robots: {cf1: {uri: 'radio://0/80/2M/E7E7E7E701', type: cf21}}\nall: " + "[" * 100_000 + "\n",
     "flow collections ([...], {...}) nested deeper than 32 levels"),
    ("robots: {cf1: {uri: 'radio://0/80/2M/E7E7E7E701', type: cf21}}\nall: " + "[" * 40 + "]" * 40 + "\n",
     "nested deeper than 32 levels"),
    ("robots: {cf1: {uri: 'radio://0/80/2M/E7E7E7E701', type: cf21}}\n" + "".join(" " * i + "k:\n" for i in range(40)),
     "nested deeper than 32 levels"),
    ("robots: {cf1: {uri: 'radio://0/80/2M/E7E7E7E701', type: cf21}}\n" + "".join(" " * i + "k:\n" for i in range(2000)),
     "not YAML: nested too deep"),
])
def test_deep_and_recursive_yaml_is_one_line(tmp_path, exported, text, message):
    f = tmp_path / "crazyflies.yaml"
    f.write_text(text)
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(f)])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), (r.output, r.exception)
    line, = r.output.strip().splitlines()
    assert str(f) in line and message in line, line


def test_shared_firmware_params_stay_each_robots_own(tmp_path, exported):
    """firmware_params shared by a YAML alias (&fp ... *fp): swarm-params gives each robot
    its own copy, so the small robot keeps its type and gains (written into the shared
    node, the last robot's would have been every robot's) and `all` keeps the shared keys."""
    f = tmp_path / "crazyflies.yaml"
    f.write_text("robots:\n"
                 "  cf1:\n    uri: radio://0/80/2M/E7E7E7E701\n    type: small\n"
                 "    firmware_params: &fp\n      stabilizer: {controller: 5}\n"
                 "  cf40:\n    uri: radio://0/80/2M/E7E7E7E728\n    type: large\n    firmware_params: *fp\n"
                 "all:\n  firmware_params: *fp\n")
    r = CliRunner().invoke(main, ["swarm-params", str(exported.gen_dir), str(f)])
    assert r.exit_code == 0, r.output
    s = sw.load(f, exported.cfg)
    assert [r.firmware_params["ns2"]["selfType"] for r in s.robots] == [0, 1]
    assert [r.firmware_params["stabilizer"] for r in s.robots] == [{"controller": 5}] * 2
    g = [default_gains(vehicle(exported.cfg, t))["Kv"][2] for t in ("small", "large")]
    assert [r.firmware_params["ns2gain"]["Kvz"] for r in s.robots] == pytest.approx(g)
    doc = sw._read(f)
    assert doc["all"]["firmware_params"] == {"stabilizer": {"controller": 5}}


def test_adaptation_params_defaults_user_values_and_absurd_ones(swarm_file, cfg):
    """Issue 53: ns2adapt is one of the app's groups; its defaults are the C's (off), a
    robot's own values stay, an absurd forgetting factor is refused in one line."""
    from ns2codegen.onboard import AdaptCfg

    s = sw.load(swarm_file, cfg)
    p = sw.params(s, cfg, s.robots[0])["ns2adapt"]
    d = {**AdaptCfg().as_dict(), "enable": 0}
    assert p == {k: d[f] for k, f in sw.ADAPT.items()} and p["enable"] == 0 and p["forget"] == 0.995
    assert p["gateNbr"] == 0 and type(p["gateNbr"]) is int          # the neighbour gate off (docs/adaptation.md)
    swarm_file.write_text(SWARM.replace("stabilizer: {estimator: 2, controller: 5}",
                                        "ns2adapt: {enable: 1, forget: 0.99, gateNbr: 1.0}"))
    s = sw.load(swarm_file, cfg)
    p = sw.params(s, cfg, s.robots[0])["ns2adapt"]
    assert p["gateNbr"] == 1 and type(p["gateNbr"]) is int
    assert p["enable"] == 1 and p["forget"] == 0.99 and sw.params(s, cfg, s.robots[1])["ns2adapt"]["forget"] == 0.995
    for bad, msg in (("{forget: 7.0}", "out of range"), ("{enable: 3}", "out of range"),
                     ("{gateNbr: 2}", "out of range"), ("{gateNbr: 0.5}", "out of range"),
                     ("{forget: .nan}", "not a finite number"), ("{gain: 1.0}", "not a parameter of the adaptation")):
        swarm_file.write_text(SWARM.replace("stabilizer: {estimator: 2, controller: 5}", f"ns2adapt: {bad}"))
        s = sw.load(swarm_file, cfg)
        with pytest.raises(sw.SwarmFileError, match=f"robots.cf1.firmware_params.ns2adapt.*{msg}"):
            sw.params(s, cfg, s.robots[0])
