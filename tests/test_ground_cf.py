"""The ground side against the real firmware, without a radio: cflib connects through a
link driver of the tests (tests/cfrobot.py) to robots whose parameter and log tables,
start values and trajectory memory size are those of the built cf2.elf; the
trajectory bytes cflib uploads are evaluated with the firmware's own pptraj.c
compiled on the host; the high-level commander packets are decoded by the
firmware's command numbering; the safety paths land the swarm."""
from __future__ import annotations

import json
import re
import struct

import numpy as np
import pytest

import cfrobot  # the tests' cflib link driver (tests/ is on sys.path, as for conftest)
from conftest import ARM, FIRMWARE, needs
from ns2codegen.errors import Ns2Error
from ns2host import cfapp, crazyflie

pytestmark = needs(ARM, FIRMWARE)


SWARM = """\
robots:
  cf1:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E701
    initial_position: [0.0, -0.5, 0.0]
    type: cf21
  cf7:
    enabled: true
    uri: radio://0/80/2M/E7E7E7E707
    initial_position: [0.0, 0.5, 0.0]
    type: big
robot_types:
  cf21: {ns2_type: small}
  big: {ns2_type: large}
"""
LOG_PACKET_DATA = 26   # CRTP's 30 data bytes less the block id and the 24-bit timestamp


@pytest.fixture(scope="module")
def elf(exported):
    return cfapp.build_app(exported.gen_dir) / "cf2.elf"


def _hl_commands() -> dict[int, str]:
    src = (crazyflie.firmware_dir() / "src/modules/src/crtp_commander_high_level.c").read_text()
    return {int(v): k for k, v in re.findall(r"^\s*(COMMAND_[A-Z0-9_]+)\s*=\s*(\d+)", src, re.M)}


def _swarm(tmp_path, cfg):
    from ns2ground import swarm as sw

    p = tmp_path / "crazyflies.yaml"
    p.write_text(SWARM)
    return sw.load(p, cfg)


START = {1: (0.0, -0.5), 2: (0.0, 0.5)}   # initial_position of cf1, cf7


def _pieces(seed: int, n: int = 3):
    """Smooth poly4d pieces (the planner's layout), a few tenths of a metre of motion,
    starting above robot ``seed``'s initial position."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        c = np.zeros((4, 8))
        c[:3, :4] = rng.normal(0, 0.3, (3, 4))
        c[2, 0] = 0.5 + abs(c[2, 0])
        out.append((0.4, c))
    out[0][1][:2, 0] = START.get(seed, (0.0, 0.5))
    return out


def _connect(elf, swarm, patch=None):
    from ns2ground import cf

    robots = {r.name: cfrobot.Robot(elf, r.name) for r in swarm.enabled}
    if patch:
        patch(robots)
    cfrobot.install({r.uri: robots[r.name] for r in swarm.enabled})
    sw_, links = cf.open_swarm({r.name: r.uri for r in swarm.enabled})
    return robots, sw_, links


def _fast():
    from ns2ground.mission import Settings

    return Settings(takeoff_height_m=0.5, takeoff_s=0.2, land_s=0.2, poll_s=0.01)


def test_every_name_the_ground_side_uses_is_in_the_elf(elf, exported, tmp_path):
    from ns2ground import cf, fingerprint, swarm as sw

    params = {f"{g}.{n}": t for g, n, t, _, _ in cfapp.param_entries(elf)}
    logs = {f"{g}.{n}": t for g, n, t, _, _ in cfapp.log_entries(elf)}
    s = _swarm(tmp_path, exported.cfg)
    used = {f"{g}.{k}": v for r in s.robots for g, vals in sw.params(s, exported.cfg, r).items() for k, v in vals.items()}
    for name, value in used.items():
        assert name in params, name
        assert bool(params[name] & 0x04) == isinstance(value, float), name    # float params get floats
        assert not params[name] & cfrobot.PARAM_RONLY, name
    assert params["ns2.sync"] & 0x0F == 0x0A                                   # uint32
    assert params[fingerprint.PARAM] == 0x0A | cfrobot.PARAM_RONLY              # read-only uint32
    # the dry run's robots know the app's parameters as the built firmware has them
    from ns2ground.sim import app_params
    assert app_params() == {k for k in params if k.split(".")[0] in sw.GROUPS}
    sizes = {1: 1, 2: 2, 3: 4, 4: 1, 5: 2, 6: 4, 7: 4}
    for block, names in cf.LOG_BLOCKS:
        assert all(n in logs for n in names), (block, [n for n in names if n not in logs])
        assert sum(sizes[logs[n] & 0x0F] for n in names) <= LOG_PACKET_DATA, block


def test_fingerprint_read_through_cflib_is_the_exports(elf, exported, tmp_path):
    from ns2ground import fingerprint

    s = _swarm(tmp_path, exported.cfg)
    robots, sw_, links = _connect(elf, s)
    try:
        expected, _ = fingerprint.export_id(exported.gen_dir)
        header = (exported.gen_dir / "ns2_model_config.h").read_text()
        model_id = int(re.search(r"#define NS2_MODEL_ID (0x[0-9a-f]+)", header).group(1), 16)
        assert expected == model_id & 0xFFFF_FFFF
        # the start value in the ELF's initialized data, read by cflib through the link
        assert robots["cf1"].value(fingerprint.PARAM) == expected
        assert int(links["cf1"].param(fingerprint.PARAM)) == expected
        with pytest.raises(AttributeError):   # cflib refuses to write a read-only parameter
            links["cf1"].cf.param.set_value(fingerprint.PARAM, 1)
    finally:
        sw_.close_links()


def _fly_two(elf, exported, tmp_path, log_values: dict):
    """cf1 and cf7 fly _pieces through cflib (ns2ground.mission.fly, radio log
    tmp_path/flight.jsonl), the test robots answering ``log_values``; returns the swarm,
    the pieces and their bytes per robot, the test robots and the mission's report."""
    from ns2ground import mission
    from ns2plan.output import poly4d_bytes

    s = _swarm(tmp_path, exported.cfg)
    pieces = {"cf1": _pieces(1), "cf7": _pieces(2, 4)}
    plans = {n: poly4d_bytes(p) for n, p in pieces.items()}
    robots, sw_, links = _connect(elf, s)
    try:
        for r in robots.values():
            r.log_values.update(log_values)
        rep = mission.fly(links, s, exported.cfg, exported.gen_dir, plans, tmp_path / "flight.jsonl", _fast())
    finally:
        sw_.close_links()
    return s, pieces, plans, robots, rep


def test_a_flight_through_cflib(elf, exported, tmp_path):
    from ns2host.cfhost import load_pptraj
    from ns2ground import swarm as sw
    from ns2plan.output import eval_pieces

    s, pieces, plans, robots, rep = _fly_two(elf, exported, tmp_path,
                                             {"pm.vbat": 3.9, "ns2.faHat": 1.5, "stateEstimate.z": 0.5})
    names = _hl_commands()
    ffi, lib = load_pptraj()
    for r in s.enabled:
        rb = robots[r.name]
        writes = dict(rb.param_writes)
        expected = sw.params(s, exported.cfg, r)
        for g, vals in expected.items():
            for k, v in vals.items():
                assert writes[f"{g}.{k}"] == pytest.approx(v, rel=1e-6), (r.name, g, k)
        order = [n for n, _ in rb.param_writes]
        assert order.index("ns2.selfType") < order.index("ns2gain.Lpx") < order.index("ns2.sync")
        assert writes["ns2.sync"] == rep["sync"]
        # the commands in the firmware's numbering, and the definition as the firmware reads it
        cmds = [names[d[0]] for d in rb.hl]
        assert cmds[0] == "COMMAND_DEFINE_TRAJECTORY" and cmds[-1] == "COMMAND_STOP", cmds
        i = {c: cmds.index(c) for c in cmds}
        assert i["COMMAND_TAKEOFF_2"] < i["COMMAND_START_TRAJECTORY_2"] < i["COMMAND_LAND_2"]
        _, traj_id, location, typ, offset, n = struct.unpack("<BBBBIB", rb.hl[0])
        # TRAJECTORY_LOCATION_MEM = 1, TRAJECTORY_TYPE_POLY4D = 0, from the start of the memory
        assert (traj_id, location, typ, offset, n) == (1, 1, 0, 0, len(pieces[r.name]))
        assert bytes(rb.traj[:len(plans[r.name])]) == plans[r.name]
        # the firmware's pptraj.c on the uploaded bytes = the planner's trajectory
        t = np.linspace(0.0, sum(d for d, _ in pieces[r.name]) - 1e-3, 60)
        out = ffi.new("float[7]")
        mem = bytes(rb.traj)
        got = []
        for tk in t:
            assert lib.ns2_pptraj_eval(mem, len(mem), 0, n, float(tk), out) == 0
            got.append(list(out)[:6])
        got = np.array(got)
        p_ref, v_ref = eval_pieces(pieces[r.name], t)
        np.testing.assert_allclose(got[:, :3], p_ref, atol=2e-5)
        np.testing.assert_allclose(got[:, 3:], v_ref, atol=2e-4)
    lines = [json.loads(x) for x in (tmp_path / "flight.jsonl").read_text().splitlines()]
    assert lines[0] == {"flight": {"robots": {"cf1": "small", "cf7": "large"}, "sync": rep["sync"]}}
    lines = lines[1:]
    assert {x["robot"] for x in lines} == {"cf1", "cf7"}
    assert any(x.get("pm.vbat") == pytest.approx(3.9) and x.get("ns2.faHat") == pytest.approx(1.5) for x in lines)


@pytest.fixture(scope="module")
def hl_harness(tmp_path_factory):
    """The firmware's own high-level commander on the host (firmware/app/test_stubs/hl_harness.c)."""
    return cfapp.build_hl_harness(tmp_path_factory.mktemp("hl"))


def _commander(harness, tmp_path, rb, evals=(), drop=()):
    """What the firmware's high-level commander makes of the packets cflib sent to the
    robot ``rb`` (its memory writes, commands and writes of hlCommander parameters, at
    the times they arrived), with the planner evaluated at ``evals``; ``drop``: command
    numbers or parameter names left out.  Returns its JSON lines."""
    import subprocess

    recs = [(t, 0, struct.pack("<BBB", port, ch, len(data)) + data + struct.pack("<d", t))
            for port, ch, data, t in rb.sent
            if (port == cfrobot.PORT_HL and data[0] not in drop) or (port == cfrobot.PORT_MEM and ch == 2)]
    for port, ch, data, t in rb.sent:
        if port == cfrobot.PORT_PARAM and ch == 2:
            g, n, typ, _, _ = rb.params[struct.unpack_from("<H", data)[0]]
            if g == "hlCommander" and n not in drop:
                value = data[2:2 + struct.calcsize(cfrobot.param_fmt(typ))]
                recs.append((t, 2, bytes([len(n)]) + n.encode() + bytes([len(value)]) + value + struct.pack("<d", t)))
    recs += [(t, 1, struct.pack("<d", t)) for t in evals]
    recs.sort(key=lambda r: (r[0], r[1]))
    (tmp_path / "hl.bin").write_bytes(b"".join(bytes([kind]) + body for _, kind, body in recs))
    r = subprocess.run([str(harness), str(tmp_path / "hl.bin")], capture_output=True, text=True, check=True)
    return [json.loads(x) for x in r.stdout.splitlines()]


def test_the_firmwares_commander_flies_what_cflib_sent(elf, exported, tmp_path, hl_harness):
    """The packets of a flight through cflib, decoded by the firmware's own
    crtp_commander_high_level.c (and its planner and pptraj.c) compiled on the host:
    the trajectory memory written, every command accepted, each robot in the ns2 group
    (its parameter hlCommander.groupmask, written as param_logic.c writes it) before
    the take-off, and the take-off and start addressed to that group, the planner flying the planner's polynomials from
    the start on, landing after; the starts of all robots left in one burst.  Without
    the group, the firmware ignores the start: the group mask is what starts it."""
    from ns2ground import cf
    from ns2plan.output import eval_pieces

    _, pieces, _, robots, _ = _fly_two(elf, exported, tmp_path, {"pm.vbat": 3.9})
    names = {v: k for k, v in _hl_commands().items()}
    start = names["COMMAND_START_TRAJECTORY_2"]
    starts = [i for i, (_, port, _, d) in enumerate(cfrobot.SENT) if port == cfrobot.PORT_HL and d[0] == start]
    assert len(starts) == 2 and starts[1] == starts[0] + 1      # one burst: nothing between the two starts
    for name, rb in robots.items():
        ts = next(t for port, _, d, t in rb.sent if port == cfrobot.PORT_HL and d[0] == start)
        dur = sum(d for d, _ in pieces[name])
        tt = np.linspace(0.0, dur - 1e-3, 40)
        out = _commander(hl_harness, tmp_path, rb, ts + tt)
        mem = [x for x in out if "mem" in x]
        cmds = [x for x in out if "cmd" in x]
        ev = [x for x in out if "t" in x]
        assert mem and all(x["ok"] == 1 for x in mem)
        assert all(x["ret"] == 0 for x in cmds), cmds
        # this firmware has the parameter hlCommander.groupmask (its COMMAND_SET_GROUP_MASK is deprecated)
        joined = [x for x in out if x.get("param") == "groupmask"]
        assert len(joined) == 1 and joined[0]["ret"] == 0 and joined[0]["group_mask"] == cf.GROUP
        assert out.index(joined[0]) < next(i for i, x in enumerate(out) if x.get("cmd") == names["COMMAND_TAKEOFF_2"])
        by = {x["cmd"]: x for x in cmds}
        assert by[start]["state"] == 1 and by[names["COMMAND_LAND_2"]]["state"] == 3   # FLYING, then LANDING
        assert struct.unpack_from("<B", next(d for p, _, d, _ in rb.sent if p == cfrobot.PORT_HL and d[0] == start),
                                  1)[0] == cf.GROUP
        p_ref, v_ref = eval_pieces(pieces[name], tt)
        np.testing.assert_allclose([x["pos"] for x in ev], p_ref, atol=1e-4)
        np.testing.assert_allclose([x["vel"] for x in ev], v_ref, atol=1e-3)
        # the same packets without the group: the firmware neither takes off nor starts
        out2 = _commander(hl_harness, tmp_path, rb, ts + tt, drop=("groupmask",))
        assert all(x["state"] == 0 and x["pos"] is None for x in out2 if "t" in x)


def test_another_model_or_no_app_is_refused_before_anything_is_sent(elf, exported, tmp_path):
    from ns2ground import fingerprint, mission
    from ns2plan.output import poly4d_bytes

    s = _swarm(tmp_path, exported.cfg)
    plans = {"cf1": poly4d_bytes(_pieces(1)), "cf7": poly4d_bytes(_pieces(2))}

    def other_model(robots):
        robots["cf7"].values[robots["cf7"].index(fingerprint.PARAM)] ^= 1

    def no_app(robots):
        rb = robots["cf1"]
        i = rb.index(fingerprint.PARAM)
        del rb.params[i], rb.values[i]

    big = dict(plans, cf7=poly4d_bytes(_pieces(2, 4096 // 132 + 1)))
    cases = [(other_model, plans, r"^cf7: flies model 0x[0-9a-f]{8}, the export is 0x[0-9a-f]{8}"),
             (no_app, plans, r"^cf1: no parameter ns2.modelId: the ns2 app is not on this robot"),
             # a plan that does not fit the robot's trajectory memory (its size read from the robot)
             (None, big, r"^cf7: its plan has 32 pieces \(4224 bytes\), the robot's trajectory memory holds 31 ")]
    for patch, p, message in cases:
        robots, sw_, links = _connect(elf, s, patch)
        try:
            with pytest.raises(Ns2Error, match=message):
                mission.fly(links, s, exported.cfg, exported.gen_dir, p, tmp_path / "f.jsonl", _fast())
        finally:
            sw_.close_links()
        for rb in robots.values():
            assert rb.param_writes == [] and rb.hl == [] and not any(rb.traj)
            assert not [q for q in rb.sent if q[0] == cfrobot.PORT_MEM and q[1] == 2]
        assert not (tmp_path / "f.jsonl").exists()


@pytest.mark.parametrize("fault", ["lost link", "low battery", "app status", "ctrl-c"])
def test_safety_paths_land_the_swarm(elf, exported, tmp_path, fault):
    from ns2ground import mission
    from ns2plan.output import poly4d_bytes

    s = _swarm(tmp_path, exported.cfg)
    plans = {"cf1": poly4d_bytes(_pieces(1, 20)), "cf7": poly4d_bytes(_pieces(2, 20))}   # 8 s: ended early
    robots, sw_, links = _connect(elf, s)
    for r in robots.values():
        r.log_values["pm.vbat"] = 3.9
    calls = {"n": 0}

    def status(last):
        calls["n"] += 1
        if calls["n"] == 30:          # during the trajectories
            if fault == "lost link":
                robots["cf7"].lose()
            elif fault == "low battery":
                robots["cf1"].log_values["pm.vbat"] = 3.1
            elif fault == "app status":
                robots["cf7"].log_values["ns2.status"] = -3
            else:
                raise KeyboardInterrupt

    try:
        with pytest.raises(mission.Abort) as e:
            mission.fly(links, s, exported.cfg, exported.gen_dir, plans, tmp_path / "f.jsonl", _fast(), status)
    finally:
        sw_.close_links()
    msg = str(e.value)
    names = _hl_commands()
    landed = {n for n, rb in robots.items() if "COMMAND_LAND_2" in [names[d[0]] for d in rb.hl]}
    if fault == "lost link":
        assert "cf7: link lost" in msg and landed == {"cf1"}     # the lost one cannot be told
    else:
        assert landed == {"cf1", "cf7"}, msg
        assert {"low battery": "cf1: battery 3.10 V below 3.3 V", "app status": "cf7: app status -3",
                "ctrl-c": "Ctrl-C"}[fault] in msg
    for rb in robots.values():
        assert "COMMAND_START_TRAJECTORY_2" in [names[d[0]] for d in rb.hl]
    lines = (tmp_path / "f.jsonl").read_text().splitlines()[1:]
    assert lines and all(json.loads(x)["robot"] in robots for x in lines)   # the log up to then is on disk


def test_ns2_fly_command(elf, exported, tmp_path):
    """`ns2 fly` end to end through cflib and the driver: the planner's file names, in order."""
    from click.testing import CliRunner

    from ns2cli import main
    from ns2plan.output import poly4d_bytes

    s = _swarm(tmp_path, exported.cfg)
    plan = tmp_path / "plan"
    plan.mkdir()
    (plan / "robot0_small.bin").write_bytes(poly4d_bytes(_pieces(1, 2)))
    (plan / "robot1_large.bin").write_bytes(poly4d_bytes(_pieces(2, 2)))
    robots = {r.name: cfrobot.Robot(elf, r.name) for r in s.enabled}
    for r in robots.values():
        r.log_values["pm.vbat"] = 3.9
    cfrobot.install({r.uri: robots[r.name] for r in s.enabled})
    r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(s.path), "--plan", str(plan), "--log",
                                  str(tmp_path / "f.jsonl"), "--takeoff-s", "0.1", "--land-s", "0.1", "--json"])
    assert r.exit_code == 0, r.output
    assert bytes(robots["cf7"].traj[:2 * 132]) == (plan / "robot1_large.bin").read_bytes()
    (plan / "robot1_large.bin").rename(plan / "robot1_small.bin")
    r = CliRunner().invoke(main, ["fly", str(exported.gen_dir), str(s.path), "--plan", str(plan), "--log",
                                  str(tmp_path / "f.jsonl")])
    assert r.exit_code == 1 and "a small robot's plan for robots.cf7 (large)" in r.output, r.output


def test_a_start_far_from_the_initial_position_is_refused(elf, exported, tmp_path):
    from ns2ground import mission
    from ns2plan.output import poly4d_bytes

    s = _swarm(tmp_path, exported.cfg)
    plans = {"cf1": poly4d_bytes(_pieces(2)), "cf7": poly4d_bytes(_pieces(2))}   # cf1 would start at cf7's place
    robots, sw_, links = _connect(elf, s)
    try:
        with pytest.raises(Ns2Error, match=r"robots.cf1.initial_position: \(0, -0.5\) but its plan starts at "
                                           r"\(0.00, 0.50\)"):
            mission.fly(links, s, exported.cfg, exported.gen_dir, plans, tmp_path / "f.jsonl", _fast())
    finally:
        sw_.close_links()
    assert all(rb.param_writes == [] and rb.hl == [] for rb in robots.values())


def test_the_gains_the_user_set_survive_the_robot_type(elf, exported, tmp_path, tmp_path_factory):
    """Gains set in the swarm file (firmware_params.ns2gain) go to the robot through
    cflib after its ns2.selfType; replayed in the order they arrived into the app
    (ns2_app.c on the host, each write as param_logic.c does it, with no controller
    tick or one between the writes), the app flies the user's gains and the new type's
    defaults for the rest.  The other order would lose them: a new type loads its
    defaults when it is written."""
    import subprocess

    from ns2ground import mission, swarm as sw
    from ns2plan.output import poly4d_bytes

    user = {"Lpx": 9.5, "Kvz": 4.25, "faMaxN": 0.07}
    (tmp_path / "crazyflies.yaml").write_text(SWARM.replace(
        "    type: big\n", "    type: big\n    firmware_params:\n      ns2gain: {Lpx: 9.5, Kvz: 4.25, faMaxN: 0.07}\n"))
    s = sw.load(tmp_path / "crazyflies.yaml", exported.cfg)
    robots, sw_, links = _connect(elf, s)
    try:
        for r in robots.values():
            r.log_values["pm.vbat"] = 3.9
        mission.fly(links, s, exported.cfg, exported.gen_dir, {"cf1": poly4d_bytes(_pieces(1)),
                                                                "cf7": poly4d_bytes(_pieces(2))},
                    tmp_path / "f.jsonl", _fast())
    finally:
        sw_.close_links()
    writes = [(n, v) for n, v in robots["cf7"].param_writes if n.split(".")[0] in sw.GROUPS]
    assert writes[0] == ("ns2.selfType", 1) and dict(writes)["ns2gain.Lpx"] == pytest.approx(9.5)
    harness = cfapp.build_harness(exported.gen_dir, tmp_path_factory.mktemp("harness"))

    def app(steps):
        r = subprocess.run([str(harness), "params", "tick:3", *steps, "tick:20"], capture_output=True, text=True,
                           check=True)
        return json.loads(r.stdout)

    fields = [f"{n}{ax}" for n in sw.GAIN3 for ax in "xyz"] + list(sw.GAIN1)   # ns2_gains_t's order
    for between in ([], ["tick:1"]):
        out = app([x for n, v in writes for x in [f"{n}={v!r}", *between]])
        expected = list(out["default_1"])
        for k, v in user.items():
            expected[fields.index(k)] = v
        assert out["ctrl_type"] == 1
        np.testing.assert_allclose(out["gains"], expected, rtol=1e-6)
        np.testing.assert_allclose(out["controller_gains"], expected, rtol=1e-6)   # what the controller flies
    assert out["default_1"][fields.index("Lpx")] != 9.5 and out["default_1"] != out["default_0"]
    # the type written after the gains: the new type's defaults replace them (why the order matters)
    late = app([f"{n}={v!r}" for n, v in writes[1:]] + ["ns2.selfType=1"])
    np.testing.assert_allclose(late["gains"], late["default_1"], rtol=1e-6)
