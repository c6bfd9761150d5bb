"""The app inside bitcraze's real crazyflie-firmware (the pinned tarball of ../shared):
built with README's command (``make -C firmware/app``), checked on the ELF (the
out-of-tree controller, PARAM/LOG groups, the ns2Sync event trigger), on the final
.config, against the flash budget; and the app glue on the host against the
firmware's real headers (firmware/app/test_stubs/app_harness.c)."""
import json
import subprocess

import numpy as np
import pytest

from conftest import ARM, FIRMWARE, needs
from ns2host import cfapp
from ns2host.cbuild import REPO, flags

pytestmark = needs(ARM, FIRMWARE)

PARAM_UINT8, PARAM_UINT16, PARAM_UINT32, PARAM_FLOAT, PARAM_RONLY = 0x08, 0x09, 0x0A, 0x06, 0x40
LOG_UINT8, LOG_UINT32, LOG_INT32, LOG_FLOAT = 1, 3, 6, 7
EVENT_UINT32 = 3


@pytest.fixture(scope="module")
def app(exported):
    """The default app (fixed point) with the session's paper-sized network, cached by content."""
    return cfapp.build_app(exported.gen_dir)


@pytest.fixture(scope="module")
def stock():
    return cfapp.build_stock()


def _symbols(elf):
    im = cfapp.Image(elf)
    try:
        return {n: (s["st_info"]["type"], s["st_size"]) for n, s in im.symbols.items()}
    finally:
        im.close()


def test_app_builds_cf2_outside_the_source_tree(app):
    assert (app / "cf2.elf").stat().st_size > 0 and (app / "cf2.bin").stat().st_size > 300_000
    assert not [p for p in (REPO / "firmware/app").rglob("*") if p.suffix in (".o", ".cmd", ".elf", ".bin")]
    assert not (REPO / "firmware/app/build").exists()
    r = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--ignored", "firmware/app"],
                       capture_output=True, text=True, check=True)
    assert not [line for line in r.stdout.splitlines() if line.startswith("!!")]  # no ignored build output


def test_cload_from_any_folder_flashes_the_built_image(app, tmp_path):
    """README's `make -C firmware/app cload`, started elsewhere (dry run: no radio here):
    the firmware's cload target runs in the app's build folder on its cf2.bin."""
    r = subprocess.run(["make", "-n", "-C", str(REPO / "firmware/app"), "cload", f"APP_BUILD={app}"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"Entering directory '{app}'" in r.stdout and "-m cfloader  flash  cf2.bin stm32-fw" in r.stdout


def test_the_firmware_calls_the_apps_out_of_tree_controller(app):
    syms = _symbols(app / "cf2.elf")
    for fn in ("controllerOutOfTreeInit", "controllerOutOfTreeTest", "controllerOutOfTree", "appMain"):
        assert syms[fn][0] == "STT_FUNC" and syms[fn][1] > 0, fn
    assert syms["controllerOutOfTree"][1] > 100  # the glue, not an empty default
    # the library is linked in: the fixed-point path only (NS2_INFER=fixed)
    assert "ns2_job_step_q15" in syms and "ns2_ctrl_attitude" in syms
    assert "ns2_job_step_f32" not in syms and "ns2_predict_f32" not in syms


def test_param_and_log_groups_in_the_elf(app):
    elf = app / "cf2.elf"
    params, logs = cfapp.param_groups(elf), cfapp.log_groups(elf)
    im = cfapp.Image(elf)
    try:
        where = lambda addr: im.address_of(addr)  # noqa: E731
        ns2 = {n: (t, where(a)) for n, t, a in params["ns2"]}
        assert ns2 == {"enable": (PARAM_UINT8, "cfg"), "fixed": (PARAM_UINT8, "cfg"),
                       "selfType": (PARAM_UINT8, "cfg"), "phiPerTick": (PARAM_UINT8, "cfg"),
                       "maxAgeMs": (PARAM_UINT16, "cfg"), "faLimit": (PARAM_FLOAT, "cfg"),
                       "sync": (PARAM_UINT32, "syncSeq"), "modelId": (PARAM_UINT32 | PARAM_RONLY, "modelId")}
        # the type table: the robot type of every radio id 0..255, 2 bits each (ns2_peers.h)
        table = params["ns2type"]
        assert [n for n, _, _ in table] == [f"t{k}" for k in range(16)]
        assert all(t == PARAM_UINT32 and where(a) == "typeTable" for _, t, a in table)
        assert [a - table[0][2] for _, _, a in table] == [4 * k for k in range(16)]   # t<k> is word k
        gains = params["ns2gain"]
        assert [n for n, _, _ in gains[:3]] == ["Lpx", "Lpy", "Lpz"] and len(gains) == 7 * 3 + 3
        assert all(t == PARAM_FLOAT and where(a) == "gains" for _, t, a in gains)
        adapt = {n: (t, where(a)) for n, t, a in params["ns2adapt"]}
        assert adapt == {"enable": (PARAM_UINT8, "adaptCfg"), "gateNbr": (PARAM_UINT8, "adaptCfg"),
                     "reset": (PARAM_UINT8, "adaptReset"),
                         **{n: (PARAM_FLOAT, "adaptCfg") for n in ("forget", "p0", "pMax", "biasMax", "scaleMax",
                                                                   "faMax", "labelMax", "wakeG", "trackGain")}}
        assert [n for n, _, _ in logs["ns2adapt"]] == ["bias", "scale", "trP", "label", "term", "status", "lstatus"]
        log = {n: (t, where(a)) for n, t, a in logs["ns2"]}
        assert log == {"faHat": (LOG_FLOAT, "faHat"), "inferUs": (LOG_UINT32, "inferUs"),
                       "nUsed": (LOG_UINT8, "nUsed"), "status": (LOG_INT32, "status"),
                       "ctrlStatus": (LOG_UINT32, "ctrlStatus"), "ex": (LOG_FLOAT, "ex"),
                       "ey": (LOG_FLOAT, "ey"), "ez": (LOG_FLOAT, "ez")}
    finally:
        im.close()
    # the firmware's own groups are read the same way (the parser is not tailored to ours)
    assert "stabilizer" in params and "stabilizer" in logs and "pm" in logs


def test_ns2sync_event_trigger_in_the_elf(app):
    events = cfapp.event_triggers(app / "cf2.elf")
    assert events["ns2Sync"] == {"variables": [("seq", EVENT_UINT32)], "payload_size": 4,
                                 "payload_symbol": "eventTrigger_ns2Sync_payload"}
    assert events["estPosition"]["variables"] == [("source", 1)]  # a firmware event, for comparison


def test_final_config_has_the_oot_controller_and_no_battery_compensation(app):
    cfg = cfapp.kconfig(app)
    assert cfg["CONFIG_CONTROLLER_OOT"] == "y" and cfg["CONFIG_APP_ENABLE"] == "y"
    assert cfg["CONFIG_ENABLE_THRUST_BAT_COMPENSATED"] == "n"  # psi_2 of the controller uses the voltage


def test_size_report_is_stamped_and_refuses_a_folder_that_is_not_an_export(monkeypatch, capsys, tmp_path):
    """`python -m ns2host.cfapp` prints its report with the commit and command that made it
    (docs/app.md's tables are made of such files); a folder without an export is one line."""
    from ns2codegen.results import commit

    monkeypatch.setattr(cfapp, "report", lambda gen, infer, out, tables: {"infer": infer, "tables": tables})
    cfapp.main(["some/gen", "--infer", "float"])
    doc = json.loads(capsys.readouterr().out)
    assert doc["infer"] == "float" and doc["provenance"]["commit"] == commit()
    assert doc["provenance"]["command"] == "python -m ns2host.cfapp some/gen --infer float"
    monkeypatch.undo()
    with pytest.raises(SystemExit) as e:
        cfapp.main([str(tmp_path)])
    assert str(tmp_path) in str(e.value) and "\n" not in str(e.value)


def test_flash_budget_and_ram_of_the_default_app(app, stock, exported):
    """The default app (fixed point) with the paper-sized network costs at most 72 KB
    of flash over stock cf2 and fits the RAM and CCM the stock firmware leaves free."""
    assert exported.cfg.model["max_neighbors"] == 16  # the paper's network (ns2codegen/default.toml)
    s, a = cfapp.sizes(stock / "cf2.elf"), cfapp.sizes(app / "cf2.elf")
    assert s["flash"] > 250_000  # a real cf2, not an empty image
    assert 0 < a["flash"] - s["flash"] <= cfapp.FLASH_BUDGET
    assert 0 < a["ram"] - s["ram"] < s["ram_free"] and a["ram_free"] > 0 and a["ccm_free"] >= 0
    stack = int(cfapp.kconfig(app)["CONFIG_APP_STACKSIZE"]) * 4
    assert a["bss"] - s["bss"] >= stack  # the app task's static stack is in the RAM it adds


def test_phi_tables_in_sram_fit_the_real_firmware(app, stock, exported):
    """NS2_TABLES=ram: every fixed-point phi table of the paper-sized network lies in
    SRAM (section .data, copied from flash at start-up by the firmware's own .data
    copy), its start-up image holds the same bytes as the flash build's table, and the
    firmware with the app still leaves SRAM free."""
    ram = cfapp.build_app(exported.gen_dir, tables="ram")
    a, r = cfapp.Image(app / "cf2.elf"), cfapp.Image(ram / "cf2.elf")
    try:
        names = sorted(n for n in r.symbols if n.startswith("ns2_q15_phi_") and not n.endswith("_layers"))
        assert len(names) == (len(exported.cfg.phi_dims()) - 1) * len(exported.cfg.neighbor_types), names
        total = 0
        for n in names:
            addr, size = r.symbols[n]["st_value"], r.symbols[n]["st_size"]
            assert 0x2000_0000 <= addr < 0x2002_0000, (n, hex(addr))        # SRAM
            seg = next(g for g in r.elf.iter_segments() if g["p_type"] == "PT_LOAD"
                       and g["p_vaddr"] <= addr < g["p_vaddr"] + g["p_filesz"])
            assert 0x0800_0000 <= seg["p_paddr"] < 0x0810_0000                # its start-up image in flash
            flash_addr = a.symbols[n]["st_value"]
            assert 0x0800_0000 <= flash_addr < 0x0810_0000                    # the default build: flash
            assert r.read(addr, size) == a.read(flash_addr, size), n
            total += size
    finally:
        a.close()
        r.close()
    s, d = cfapp.sizes(stock / "cf2.elf"), cfapp.sizes(ram / "cf2.elf")
    assert d["ram"] - cfapp.sizes(app / "cf2.elf")["ram"] >= total > 20_000
    assert d["ram_free"] > 0 and d["ram"] - s["ram"] < s["ram_free"]


def test_size_report_of_make_app(app, stock, exported):
    """`make app`'s report (python -m ns2host.cfapp): stock, with the app, what it adds."""
    import sys

    r = json.loads(subprocess.run([sys.executable, "-m", "ns2host.cfapp", str(exported.gen_dir)],
                                  capture_output=True, text=True, check=True).stdout)
    assert r["stock"] == cfapp.sizes(stock / "cf2.elf") and r["app"] == cfapp.sizes(app / "cf2.elf")
    assert r["delta"]["flash"] == r["app"]["flash"] - r["stock"]["flash"] and r["within_flash_budget"]
    added = r["ram_added"]
    assert added["app_task_stack"] == 1400 and added["app_bss"] > 1000
    assert added["bytes"] >= added["app_task_stack"] + added["app_bss"]
    assert r["network"] == {"phi": exported.cfg.phi_dims(), "rho": exported.cfg.rho_dims(),   # what it was built with
                            "history_ms": exported.cfg.history_ms, "input_dim": exported.cfg.input_dim}
    assert r["provenance"]["command"] == f"python -m ns2host.cfapp {exported.gen_dir}"


def _compile_lib(tmp_path, infer):
    f = flags()
    defs = {"fixed": ("1", "0"), "float": ("0", "1"), "both": ("1", "1"), "none": ("0", "0")}[infer]
    obj = tmp_path / f"lib-{infer}.o"
    return obj, subprocess.run(
        ["arm-none-eabi-gcc", *f["NS2_ARM_FLAGS"], "-std=gnu11", "-Os", "-ffp-contract=off", *f["NS2_WARN_FLAGS"],
         "-Wno-pedantic", f"-DNS2_APP_FIXED={defs[0]}", f"-DNS2_APP_FLOAT={defs[1]}",
         *[f"-I{REPO / i}" for i in f["NS2_INCLUDES"]], f"-I{tmp_path}", "-c",
         str(REPO / "firmware/app/src/ns2_lib.c"), "-o", str(obj)], capture_output=True, text=True)


@pytest.mark.parametrize("infer", ["fixed", "float", "both"])
def test_inference_paths_are_a_build_option(exported, tmp_path, infer):
    import shutil

    for p in exported.gen_dir.iterdir():
        shutil.copy(p, tmp_path / p.name)
    obj, r = _compile_lib(tmp_path, infer)
    assert r.returncode == 0, r.stderr
    nm = subprocess.run(["arm-none-eabi-nm", str(obj)], capture_output=True, text=True, check=True).stdout
    assert (" T ns2_job_step_q15" in nm) == (infer in ("fixed", "both"))
    assert (" T ns2_job_step_f32" in nm) == (infer in ("float", "both"))
    assert " T ns2_ctrl_attitude" in nm and " T ns2_peers_update" in nm


def test_no_inference_path_and_a_bad_option_are_refused(exported, tmp_path):
    _, r = _compile_lib(tmp_path, "none")
    assert r.returncode != 0 and "no inference path" in r.stderr
    r = subprocess.run(["make", "-C", str(REPO / "firmware/app"), "NS2_INFER=fast", f"APP_BUILD={tmp_path / 'b'}",
                        f"NS2_GEN={exported.gen_dir}", "CRAZYFLIE_BASE=/nonexistent"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode != 0 and "NS2_INFER=fast: must be fixed, float or both" in r.stderr
    assert not (tmp_path / "b").exists()


def test_missing_generated_headers_are_named(tmp_path):
    r = subprocess.run(["make", "-C", str(REPO / "firmware/app"), f"APP_BUILD={tmp_path / 'b'}",
                        f"NS2_GEN={tmp_path / 'nogen'}", "CRAZYFLIE_BASE=/nonexistent"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode != 0 and f"{tmp_path / 'nogen'}/ns2_model_config.h: missing" in r.stderr


# ------------------------------------------------------------------ host harness


@pytest.fixture(scope="module")
def harness(exported, tmp_path_factory):
    return cfapp.build_harness(exported.gen_dir, tmp_path_factory.mktemp("harness"))


def _run(exe, *args):
    return json.loads(subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True,
                                     check=True).stdout)


def test_app_flies_the_ns2_controller_against_the_real_headers(harness, exported):
    """One second of 1 kHz stabilizer ticks, a small robot hovering with a large peer
    0.3 m above, its position told through the firmware's peer localization.  The
    sliced prediction of the app equals the direct one-shot prediction bit for bit
    (fixed and float), the motors get PWM ratios in controlModeForce, the baseline
    hovers at psi_2 of the hover force, the learned downwash asks for more thrust,
    no position setpoint means motors off, and a write of ns2.sync logs one ns2Sync."""
    from ns2host.sim.vehicle import G, vehicle

    runs = {}
    for fixed, enable in ((1, 1), (0, 1), (1, 0)):
        runs[fixed, enable] = res = _run(harness, fixed, enable)
        assert res["mode"] == 2 and res["n"] == 1  # controlModeForce, the peer is a neighbour
        assert np.float32(res["fa_hat_g"]) == np.float32(res["direct_g"])
        assert all(0.0 < u < 1.0 for u in res["mean_pwm"]) and res["off_pwm"] == [0, 0, 0, 0]
        assert res["sync"] == [1, 42]  # one ns2Sync event for the one write of ns2.sync
    veh = vehicle(exported.cfg, "small")
    f_g, v = veh.mass * G / 4 / G * 1000.0, 3.9 / 4.2
    c = veh.psi2
    hover_pwm = c[0] + c[1] * f_g + c[2] * v + c[3] * f_g ** 2 + c[4] * f_g * v
    assert runs[1, 0]["mean_pwm"] == pytest.approx([hover_pwm] * 4, abs=2e-3)
    fa = runs[1, 1]["fa_hat_g"]
    assert fa != 0.0
    # f_a,z < 0 (downwash) asks for more PWM than the baseline, and the reverse
    assert np.sign(runs[1, 1]["mean_pwm"][0] - runs[1, 0]["mean_pwm"][0]) == -np.sign(fa)


@pytest.mark.parametrize("robots,per_ms,seen", [(16, 4, 15), (16, 2, 15), (16, 10, 15), (16, 15, 10), (8, 7, 7)])
def test_sixteen_robot_swarm_through_the_firmware_peer_table(harness, robots, per_ms, seen):
    """The firmware's peer localization (real peer_localization.c) keeps 10 robots
    and never frees a slot; the app drains it every millisecond into its own table
    of 16.  Mocap frames at 100 Hz in packets of per_ms positions per millisecond:
    all 15 peers of a 16-robot swarm reach the network as long as at most 10 arrive
    in one millisecond; 15 in one millisecond leave 10 (docs/app.md)."""
    res = _run(harness, "swarm", robots, per_ms)
    assert res["app_peers"] == seen and res["n_used"] == seen
    assert res["firmware_table_max"] == min(per_ms, 10)


def _peers(harness, *steps):
    """The harness's peer bookkeeping run (app_harness.c, mode peers): one dict per show."""
    r = subprocess.run([str(harness), "peers", *map(str, steps)], capture_output=True, text=True, check=True)
    out = [json.loads(line) for line in r.stdout.splitlines()]
    for o in out:
        o["by_id"] = {i: (ty, n, t) for i, ty, n, t in o["peers"]}
    return out


# a lab's numbering: ids from 0 to 255, large robots above 31 (issue 56)
SWARM_IDS = (0, 2, 31, 32, 40, 77, 100, 128, 150, 180, 200, 220, 240, 250, 254, 255)
SWARM_LARGE = (0, 32, 40, 128, 200, 255)


def _adapt(harness, *steps) -> list[dict]:
    """The harness's adaptation run (app_harness.c, mode adapt): one dict per show."""
    r = subprocess.run([str(harness), "adapt", *map(str, steps)], capture_output=True, text=True, check=True)
    return [json.loads(line) for line in r.stdout.splitlines()]


def test_app_adaptation_params_log_bad_writes_and_resets(harness):
    """Issue 53: PARAM ns2adapt switches the adaptation on (off at boot: f = NN bit for
    bit), LOG ns2adapt shows what the pilot holds; an absurd forgetting factor gives
    f = NN with NS2_ADAPT_BAD_PARAM and theta held, a good one resumes; so does a
    neighbour gate (ns2adapt.gateNbr) other than 0 or 1; ns2adapt.reset and a stay on the
    ground reset theta and P."""
    BAD_PARAM, UPDATED = 4, 1
    off, on, bad, good, bad_gate, gate, reset, ground = _adapt(
        harness, "tick:2000", "show", "ns2adapt.enable=1", "ns2adapt.biasMax=3", "tick:3000", "show",
        "ns2adapt.forget=7", "tick:500", "show", "ns2adapt.forget=0.99", "tick:500", "show",
        "ns2adapt.gateNbr=2", "tick:500", "show", "ns2adapt.gateNbr=1", "tick:500", "show",
        "ns2adapt.reset=1", "tick:1", "show", "tick:1000", "ground:10", "show")
    assert off["enable"] == 0 and off["updates"] == 0 and off["fa_used_g"] == off["fa_hat_g"]
    assert off["log"]["status"] == 2 and off["log"]["lstatus"] == 0        # NS2_ADAPT_OFF, the label sane
    assert on["enable"] == 1 and on["updates"] > 250 and on["log"]["status"] & UPDATED
    assert on["log"]["bias"] == on["theta"][0] != 0 and on["log"]["scale"] == on["theta"][1]
    assert abs(on["theta"][0]) <= 3.0 and on["log"]["trP"] == on["trP"] <= 2 * 10.0 + 2e-6 and on["theta"][1] == 0
    assert on["fa_used_g"] == pytest.approx(on["fa_hat_g"] + on["log"]["term"], abs=1e-6)
    assert bad["forget"] == 7.0 and bad["log"]["status"] == BAD_PARAM and bad["theta"] == on["theta"]
    assert bad["fa_used_g"] == bad["fa_hat_g"] and bad["log"]["term"] == 0 and bad["updates"] == on["updates"]
    assert good["log"]["status"] & UPDATED and good["updates"] > bad["updates"]
    assert bad_gate["log"]["status"] == BAD_PARAM and bad_gate["updates"] == good["updates"]
    assert bad_gate["fa_used_g"] == bad_gate["fa_hat_g"] and bad_gate["theta"] == good["theta"]
    assert gate["log"]["status"] & UPDATED and gate["updates"] > good["updates"]     # no neighbour: learns
    assert reset["reset"] == 0 and reset["updates"] <= 1
    assert ground["theta"] == [0.0, 0.0] and ground["updates"] == 0 and ground["trP"] == 2.0      # p0 I


def test_app_peer_bookkeeping_of_a_full_swarm_with_any_radio_ids(harness):
    """The app (this robot: radio id 1) with the firmware's real peer localization and
    the type table written as the ground writes it (PARAM ns2type.t0..t15): a swarm
    numbered 0..255 with large robots above id 31 gets every peer with its own type;
    radio id 0 never reaches the app (the firmware's table takes id 0 for a free slot,
    which is why the ground side refuses it); a 16th peer fills the table and a 17th
    is refused while all are live; a peer whose type the ground rewrites flies with the
    new type from its next frame; a peer that disappears leaves the neighbour list after
    ns2.maxAgeMs and gives its slot to the waiting robot after NS2_PEERS_STALE_MS."""
    ids = ",".join(map(str, SWARM_IDS))
    snap = _peers(harness, *[f"type:{i}=1" for i in SWARM_LARGE], f"ids:{ids}", "ms:200", "show",
                  f"ids:{ids},60", "ms:100", "show",                         # a 16th peer: the table is full
                  f"ids:{ids},60,61", "ms:100", "show",                      # a 17th: refused
                  "type:40=0", "type:2=1", "ms:20", "show",                  # two robots change type
                  f"ids:{ids.replace(',77,', ',')},60,61", "ms:300", "show",  # robot 77 disappears
                  "ms:800", "show")                                          # ... for more than 1 s
    full, sixteen, refused, retyped, silent, replaced = snap
    seen = [i for i in SWARM_IDS if i != 0]
    assert sorted(full["by_id"]) == seen and full["n_used"] == 15
    assert all(full["by_id"][i][0] == int(i in SWARM_LARGE) and full["by_id"][i][1] == 2 for i in seen)
    assert full["table"][15] >> 30 == 1 and full["table"][0] & 3 == 1   # ids 255 and 0 in the table
    assert len(sixteen["peers"]) == 16 and 60 in sixteen["by_id"] and sixteen["n_used"] == 16
    assert refused["by_id"].keys() == sixteen["by_id"].keys()           # 61 waits: every peer is live
    assert retyped["by_id"][40][0] == 0 and retyped["by_id"][2][0] == 1 and retyped["by_id"][255][0] == 1
    assert 77 in silent["by_id"] and 61 not in silent["by_id"] and silent["n_used"] == 15   # left out, slot kept
    assert 77 not in replaced["by_id"] and replaced["by_id"][61][1] == 2 and len(replaced["peers"]) == 16
    assert replaced["n_used"] == 16 and all(replaced["by_id"][i][0] == retyped["by_id"][i][0]
                                            for i in replaced["by_id"] if i != 61)


DEG2RAD = np.float32(0.017453292519943295)  # the app's NS2_DEG2RAD
# one 1 kHz tick of the harness's trace mode (app_harness.c, trace_tick)
TRACE = np.dtype([("disable", "<u4"), ("bat", "<f4"), ("p", "<f4", 3), ("v", "<f4", 3), ("q", "<f4", 4),
                  ("gyro", "<f4", 3), ("sp_p", "<f4", 3), ("sp_v", "<f4", 3), ("sp_a", "<f4", 3), ("yaw", "<f4"),
                  ("n", "<u4"), ("peers", [("id", "<u4"), ("x", "<f4", 3)], 3)])
PEER_IDS = (2, 3, 4)  # the trace's three peers; the first and the last are large robots


def _trace_inputs(n=1500, seed=7, ids=PEER_IDS):
    """A small robot (radio id 1) around a moving setpoint with a perturbation, gyro and
    tilt; three peers (radio ids ``ids``) circling 0.2-0.4 m above, their mocap frames at
    100 Hz with a fifth lost; no position setpoint (on the ground) for ticks 700-759."""
    rng = np.random.default_rng(seed)
    x = np.zeros(n, TRACE)
    t = np.arange(n) / 1000.0
    x["disable"] = (t >= 0.7) & (t < 0.76)
    x["bat"] = 4.0 - 0.1 * t
    x["sp_p"] = np.stack([0.1 * np.sin(2 * t), 0.05 * t, 1.0 + 0.0 * t], 1)
    x["sp_v"] = np.stack([0.2 * np.cos(2 * t), 0.05 + 0.0 * t, 0.0 * t], 1)
    x["sp_a"] = np.stack([-0.4 * np.sin(2 * t), 0.0 * t, 0.0 * t], 1)
    x["yaw"] = 10.0 * np.sin(t)
    kick = 0.03 * np.exp(-((t - 0.3) / 0.05) ** 2)  # the perturbation
    x["p"] = x["sp_p"] + np.stack([0.02 * np.sin(7 * t), -0.01 * np.cos(5 * t), 0.01 * np.sin(3 * t) - kick], 1)
    x["v"] = x["sp_v"] + rng.normal(0, 0.02, (n, 3))
    q = np.stack([np.ones(n), 0.02 * np.sin(9 * t), -0.03 * np.sin(4 * t), 0.05 * np.sin(t)], 1)
    x["q"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x["gyro"] = rng.normal(0, 20.0, (n, 3))  # deg/s
    for k in range(n):
        if k % 10 not in (1, 4) or rng.random() < 0.2:
            continue
        which = (0,) if k % 10 == 1 else (1, 2)  # two positions in one millisecond
        for j, w in enumerate(which):
            i = w + 2   # the orbit of the w-th peer, whatever its radio id
            a = t[k] * (1.0 + i) + i
            x["peers"][k, j] = (ids[w], (0.15 * np.cos(a), 0.15 * np.sin(a), 1.0 + 0.1 * i))
        x["n"][k] = len(which)
    return x


def _pilot_direct(ffi, lib, x, veh, gains, pcfg, large_ids):
    """ns2_pilot driven as ns2_app.c drives it: the firmware's peer table stamps each
    position with xTaskGetTickCount() (= the tick) and is drained every 1 kHz tick, the
    500 Hz ticks run ns2_pilot_tick (period + position at 100 Hz), self radio id 1,
    gyro and yaw deg -> rad in float32, quaternion [w x y z], reset with no setpoint."""
    pl = ffi.new("ns2_pilot_t *")
    lib.ns2_pilot_init(pl, pcfg, veh, gains)
    lib.ns2_pilot_reset(pl, veh)
    s, sp = ffi.new("ns2_ctrl_state_t *"), ffi.new("ns2_setpoint_t *")
    pwm, fa, n_used = np.zeros((len(x), 4), np.float32), np.zeros(len(x), np.float32), np.zeros(len(x), int)
    u = np.zeros(4, np.float32)
    for k, r in enumerate(x):
        for j in range(r["n"]):
            i, p = int(r["peers"][j]["id"]), r["peers"][j]["x"]
            lib.ns2_pilot_peer(pl, i, int(i in large_ids), k, [float(c) for c in p])
        if r["disable"]:
            lib.ns2_pilot_reset(pl, veh)
            u = np.zeros(4, np.float32)
        elif k % 2 == 0:
            s.p, s.v, s.q = r["p"].tolist(), r["v"].tolist(), r["q"].tolist()
            s.w = (r["gyro"] * DEG2RAD).tolist()
            sp.p, sp.v, sp.a, sp.w = r["sp_p"].tolist(), r["sp_v"].tolist(), r["sp_a"].tolist(), [0.0] * 3
            sp.yaw = float(r["yaw"] * DEG2RAD)
            lib.ns2_pilot_tick(pl, s, sp, int(k % 10 == 0), 1, k, float(r["bat"]))
            u = np.array(list(pl.ctrl.pwm), np.float32)
        pwm[k], fa[k], n_used[k] = u, pl.fa_hat_g, pl.n_used
    return pwm, fa, n_used


@pytest.mark.parametrize("fixed,self_type,ids", [(1, 0, PEER_IDS), (0, 0, PEER_IDS), (1, 1, PEER_IDS),
                                                  (1, 0, (200, 3, 255)), (0, 1, (40, 99, 33))])
def test_app_motor_commands_equal_ns2_pilot_bit_for_bit(harness, exported, tmp_path, fixed, self_type, ids):
    """The app (the real ns2_app.c on the firmware's headers and peer_localization.c)
    and ns2_pilot called directly on the same 1.5 s of 1 kHz inputs (moving setpoint,
    perturbation, three peers of both types with lost frames, a stretch on the ground)
    give the same motor PWM on every tick, bit for bit; the app's vehicle, default
    gains (generated ns2_vehicles.h) and PARAM defaults equal ns2codegen.vehicle's and
    ns2_pilot_default_cfg's; the learned force was in use and the PWM varied.  The large
    peers' radio ids may be any (200 and 255, 40 and 33): their types come from the
    type table (PARAM ns2type.t0..t15) the ground writes."""
    _app_equals_pilot(harness, exported, tmp_path, fixed, self_type, ids)


def test_app_with_wake_memory(history, tmp_path_factory, tmp_path):
    """A network with wake memory (model.history_ms) in the app: the peer table's
    history ring at the 100 Hz position tick (ns2_peers_record), the own past, the
    sliced prediction through ns2_job_begin_hist equal to the direct one-shot
    prediction bit for bit (hovering: every past state is the present), and the app's
    motor commands equal ns2_pilot's on the moving 1.5 s trace, bit for bit."""
    exe = cfapp.build_harness(history.gen_dir, tmp_path_factory.mktemp("harness-history"))
    for fixed in (1, 0):
        res = _run(exe, fixed, 1)
        assert res["mode"] == 2 and res["n"] == 1 and res["fa_hat_g"] != 0.0
        assert np.float32(res["fa_hat_g"]) == np.float32(res["direct_g"])
    _app_equals_pilot(exe, history, tmp_path, 1, 0, PEER_IDS)


def test_app_with_wake_memory_fits_the_real_firmware(history, app, stock):
    """The app with a history network builds in the real firmware (cf2) within the flash
    budget and leaves RAM free; the rings cost RAM (docs/app.md: about 11 KB for 3 lags)."""
    s, d = cfapp.sizes(stock / "cf2.elf"), cfapp.sizes(app / "cf2.elf")
    h = cfapp.sizes(cfapp.build_app(history.gen_dir) / "cf2.elf")
    assert 0 < h["flash"] - s["flash"] <= cfapp.FLASH_BUDGET and h["ram_free"] > 0 and h["ccm_free"] >= 0
    assert 10_000 < h["ram"] - d["ram"] < 12_000   # 16 peers x 21 ticks x 24 B, the own ring, job, list


def _app_equals_pilot(harness, exported, tmp_path, fixed, self_type, ids):
    from ns2host.cbuild import fill_gains, fill_vehicle
    from ns2host.cfhost import load_fly
    from ns2host.sim.vehicle import default_gains, vehicle

    ffi, lib = load_fly(exported.gen_dir)
    veh, gains, pcfg = ffi.new("ns2_vehicle_t *"), ffi.new("ns2_gains_t *"), ffi.new("ns2_pilot_cfg_t *")
    v = vehicle(exported.cfg, exported.cfg.robot_types[self_type])
    fill_vehicle(veh[0], v)
    fill_gains(gains[0], default_gains(v))
    lib.ns2_pilot_default_cfg(pcfg, self_type)
    pcfg.enable, pcfg.fixed = 1, fixed
    x = _trace_inputs(ids=ids)
    (tmp_path / "in.bin").write_bytes(x.tobytes())
    large = (ids[0], ids[2])
    subprocess.run([str(harness), "trace", str(fixed), "1", str(self_type), ",".join(f"{i}=1" for i in large),
                    str(tmp_path / "in.bin"), str(tmp_path / "out.bin")], check=True)
    out = (tmp_path / "out.bin").read_bytes()
    head = [bytes(ffi.buffer(c)) for c in (veh, gains, pcfg)]
    assert out[:len(b"".join(head))] == b"".join(head)  # ns2_vehicles.h == ns2codegen.vehicle, PARAM == default cfg
    app = np.frombuffer(out[len(b"".join(head)):], np.float32).reshape(-1, 4)
    direct, fa, n_used = _pilot_direct(ffi, lib, x, veh, gains, pcfg, large)
    assert app.shape == direct.shape == (len(x), 4)
    assert np.array_equal(app.view(np.uint32), direct.view(np.uint32))
    on = x["disable"] == 0
    assert (app[~on] == 0).all() and (app[on].max(axis=1) > 0).all()  # off on the ground, flying otherwise
    assert np.ptp(app[on], axis=0).min() > 0.01  # the PWM varied on every motor
    assert n_used.max() == 3 and (n_used[on] > 0).mean() > 0.8
    assert np.abs(fa).max() > 0.5 and (fa != 0).mean() > 0.5  # the learned term was in use


# ------------------------------------------------------------------ 1 ms stabilizer iteration


@pytest.mark.parametrize("infer", ["fixed", "float", "both"])
def test_app_compiles_against_the_real_headers_for_each_inference_path(exported, infer):
    """ns2_app.c + ns2_lib.c for the Cortex-M4 with the firmware's flags and headers,
    warnings as errors, linked with the firmware's estimator and PID controller."""
    from ns2host import stabilizer

    syms = _symbols(stabilizer.build_image(exported.gen_dir, infer))
    assert ("ns2_job_step_f32" in syms) == (infer != "fixed")
    assert ("ns2_job_step_q15" in syms) == (infer != "float")
    for fn in ("kalmanCorePredict", "kalmanCoreUpdateWithPosition", "controllerPid", "controllerOutOfTree"):
        assert syms[fn][0] == "STT_FUNC", fn


def test_stabilizer_iteration_counts(exported):
    """The firmware's Kalman estimator, its PID controller and the app counted on the
    emulated Cortex-M4: deterministic instruction counts in ranges that a missing
    measurement update, an empty controller or a skipped prediction would leave; the
    worst iteration over every phase of the estimator's costly tick against the app's
    period; and the app's schedule (ns2_pilot_step) adds at most 10 % of 1 ms to the
    stock worst iteration, at zero wait states and on the memory-system model (fixed
    point, 15 peers), with no millisecond of the app above the stock PID's plus 10 %."""
    from ns2host import stabilizer

    r = stabilizer.iteration(exported.gen_dir)
    est, quiet = r["estimator_kalman_predict_and_position"], r["estimator_kalman_other_ticks"]
    pid, app = r["stock_controller_pid"], r["app_controller_oot"]
    assert 20_000 < est["instructions"] < 200_000  # 9-state covariance update, three scalar updates
    assert 300 < quiet["instructions"] < 5_000 and quiet["instructions"] * 10 < est["instructions"]
    assert 1_000 < pid["instructions"] < 20_000
    assert 5_000 < app["instructions"] < 100_000 and app["cycles"] > pid["cycles"]
    assert r["app_neighbors_used"] == 15  # 15 peers broadcast, all through the firmware's 10 slots
    tenth = 0.1 * stabilizer.CLOCK_HZ * stabilizer.TICK_US * 1e-6  # cycles in 10 % of 1 ms
    for model, attr in stabilizer.MODELS.items():
        ticks = r["app_by_tick"][model]
        assert len(ticks) == 10 and min(ticks) > 2_000  # the app works in every millisecond of its period
        assert max(ticks) <= app[attr] and r["app_worst_tick"][model]["cycles"] == est[attr] + app[attr]
        assert r["stock_worst_tick"][model]["cycles"] == est[attr] + pid[attr]
        assert len(set(r["app_worst_tick"][model]["share_by_phase"])) > 3  # the phase matters
        assert app[attr] <= pid[attr] + tenth, (model, ticks)
        assert 0 < r["app_adds_to_worst_tick"][model] <= 0.10
        assert 0 < r["stock_mean_load"][model] < r["app_mean_load"][model] < r["app_worst_tick"][model]["share_of_1ms"]
    assert stabilizer.iteration(exported.gen_dir) == r  # deterministic


def test_stabilizer_budget_with_wake_memory_and_adaptation(history):
    """Issue 53's bound with the network make real exports (wake memory: 24 inputs per
    neighbour, the paper's H and L): the app with the adaptation on, and with a whole
    label-and-update step added to its position tick, adds at most 10 % of 1 ms to the
    stock worst iteration, at zero wait states and on the memory-system model.  The
    job's begin (each neighbour's 24 inputs checked and clamped) runs at k = 1, not in
    the position tick with the neighbour list and the position loop."""
    from ns2host import stabilizer

    assert history.cfg.phi_dims() == [24, 25, 40, 40, 20] and history.cfg.rho_dims() == [20, 40, 40, 40, 1]
    r = stabilizer.with_adaptation(history.gen_dir)
    for model in stabilizer.MODELS:
        assert 0 < r["app_adds_to_worst_tick"][model] <= r[f"adds_to_worst_tick_bound_{model}"] <= 0.10, (model, r)
        assert r[f"within_budget_{model}"] and r[f"update_step_cycles_{model}"] > 500
