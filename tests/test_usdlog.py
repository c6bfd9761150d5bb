"""Crazyflie uSD-card logs: the format (against an independent writer), its errors,
multi-robot clock alignment, and the real-flight path end to end on simulated flights
(sim -> uSD files -> `ns2 logs-to-data` -> `ns2 train` -> `ns2 export`)."""
import json
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

from ns2codegen.checkpoint import save_checkpoint
from ns2codegen.data.dataset import Dataset
from ns2codegen.data.labels import G, residual_force
from ns2codegen.logs import usdlog
from ns2codegen.logs.align import LogError, PWM_FULL, RobotLog, VARIABLES, align, logs_to_flights
from ns2codegen.logs.usdlog import UsdLogError, UsdLogWriter
from ns2codegen.train import train
from ns2host.sim.cloop import CLoopSwarm, robots_of
from ns2host.sim.scenarios import swap
from ns2host.sim.usdlogs import write_flight, write_manifest


# --- an independent writer: bytes packed by hand from the documented layout -----------
def pack_by_hand(types, entries, version=2, crc=True) -> bytes:
    """types: [(id, name, [(var, typechar)])]; entries: [(id, t_us, values)]."""
    out = bytearray([0xBC]) + struct.pack("<H", version) + struct.pack("<H", len(types))
    fmt = {}
    for eid, name, variables in types:
        out += struct.pack("<H", eid) + name.encode() + b"\x00" + struct.pack("<H", len(variables))
        for var, t in variables:
            out += var.encode() + b"(" + t.encode() + b")\x00"
        fmt[eid] = "<" + "".join(t for _, t in variables)
    for eid, stamp, values in entries:
        out += struct.pack("<H", eid) + struct.pack("<Q", stamp) + struct.pack(fmt[eid], *values)
    if crc:
        out += struct.pack("<I", zlib.crc32(bytes(out)) & 0xFFFFFFFF)
    return bytes(out)


TYPES = [(0xFFFF, "fixedFrequency", [("stateEstimate.z", "f"), ("motor.m1", "I"), ("pm.state", "b"),
                                     ("radio.rssi", "B"), ("a.h", "h"), ("a.H", "H"), ("a.i", "i"), ("a.e", "e")]),
         (3, "estPosition", [("x", "f"), ("y", "f"), ("stdDev", "f")]),
         (9, "emptyEvent", [])]
ENTRIES = [(0xFFFF, 1_000_000, (0.5, 40000, -1, 200, -300, 60000, -70000, 1.5)),
           (3, 1_003_000, (0.1, -0.2, 0.01)),
           (0xFFFF, 1_010_000, (0.25, 65535, 3, 0, 32767, 0, 2 ** 31 - 1, -0.25)),
           (9, 1_012_345, ()),
           (3, 1_013_000, (1.0, 2.0, 0.5))]


def test_reader_decodes_the_independently_packed_layout():
    log = usdlog.decode(pack_by_hand(TYPES, ENTRIES))
    assert log.version == 2 and log.crc_ok and log.entries == 5 and not log.note
    ff = log.event("fixedFrequency")
    assert ff["timestamp_us"].tolist() == [1_000_000, 1_010_000]
    assert ff["stateEstimate.z"].tolist() == [0.5, 0.25] and ff["motor.m1"].tolist() == [40000, 65535]
    assert ff["pm.state"].tolist() == [-1, 3] and ff["a.i"].tolist() == [-70000, 2 ** 31 - 1]
    assert ff["a.e"].tolist() == [1.5, -0.25] and ff["a.h"].tolist() == [-300, 32767]
    est = log.event("estPosition")
    assert est["timestamp_us"].tolist() == [1_003_000, 1_013_000]
    np.testing.assert_array_equal(est["y"], np.float32([-0.2, 2.0]))
    assert log.event("emptyEvent")["timestamp_us"].tolist() == [1_012_345]
    assert log.types[3].variables == (("x", "f"), ("y", "f"), ("stdDev", "f"))


def test_writer_produces_the_same_bytes_as_the_documented_layout(tmp_path):
    w = UsdLogWriter()
    ets = {eid: w.declare(eid, name, variables) for eid, name, variables in TYPES}
    for eid, stamp, values in ENTRIES:
        w.add(ets[eid], stamp, values)
    assert w.encode() == pack_by_hand(TYPES, ENTRIES)
    w.write(tmp_path / "log00")
    assert usdlog.read(tmp_path / "log00").entries == 5


@pytest.mark.parametrize("mutate, message", [
    (lambda b: b"\xAB" + b[1:], "magic byte 0xAB"),
    (lambda b: b[:1] + struct.pack("<H", 1) + b[3:], "version 1 is not supported"),
    (lambda b: b[:3] + struct.pack("<H", 0) + b[5:], "declares no event types"),
    (lambda b: b[:3], "too short"),
    (lambda b: b[:12], "no NUL terminator"),
    (lambda b: b[:-30] + bytes([b[-30] ^ 0x40]) + b[-29:], "CRC-32 mismatch"),
    (lambda b: b[:-7], "CRC-32 mismatch"),
])
def test_bad_files_are_rejected_with_a_clear_error(mutate, message):
    with pytest.raises(UsdLogError, match=message):
        usdlog.decode(mutate(pack_by_hand(TYPES, ENTRIES)))


def test_bad_variable_descriptor_duplicate_id_and_unknown_event():
    bad = pack_by_hand([(1, "e", [("x", "q")])], [])   # 'q' (int64) is not a log type
    with pytest.raises(UsdLogError, match="not '<name>\\(<t>\\)'"):
        usdlog.decode(bad)
    with pytest.raises(UsdLogError, match="declared twice"):
        usdlog.decode(pack_by_hand([(1, "a", []), (1, "b", [])], []))
    body = pack_by_hand(TYPES, ENTRIES, crc=False) + struct.pack("<HQ", 42, 2_000_000)
    data = body + struct.pack("<I", zlib.crc32(body))     # valid CRC, undeclared id 42
    with pytest.raises(UsdLogError, match="unknown event id 42 at byte"):
        usdlog.decode(data, allow_truncated=True)


def test_truncated_files_keep_their_complete_entries_when_asked():
    whole = pack_by_hand(TYPES, ENTRIES, crc=False)
    cut = whole[:-5]   # power loss: no CRC, the last entry cut off
    with pytest.raises(UsdLogError, match="truncated"):
        usdlog.decode(cut)
    log = usdlog.decode(cut, allow_truncated=True)
    assert not log.crc_ok and log.entries == 4 and "incomplete final entry" in log.note
    assert log.event("estPosition")["timestamp_us"].tolist() == [1_003_000]
    garbage = whole + struct.pack("<HQ", 77, 5) + b"\x00" * 8
    log = usdlog.decode(garbage, allow_truncated=True)
    assert log.entries == 5 and "unknown event id 77" in log.note


# --- alignment -----------------------------------------------------------------------------
def _robot_file(t_own, p, pwm, sync_us=None) -> bytes:
    """A uSD file with the flight variables (hover attitude, zero velocity)."""
    w = UsdLogWriter()
    names = [n for k in VARIABLES for n in VARIABLES[k]]
    ff = w.declare(0xFFFF, "fixedFrequency", [(n, "I" if n.startswith("motor") else "f") for n in names])
    n = len(t_own)
    cols = np.concatenate([p, np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), pwm * PWM_FULL,
                           np.full((n, 1), 3.9)], 1)
    w.add_many(ff, np.round(t_own * 1e6), cols)
    if sync_us is not None:
        w.add(w.declare(5, "ns2Sync", [("seq", "I")]), sync_us, [0])
    return w.encode()


def test_takeoff_offsets_gaps_and_mixed_sync():
    """No sync event: offsets from the motor start (broadcast take-off), within 1 ms;
    a gap in one robot's log cuts the flight into two pieces around it."""
    rng = np.random.default_rng(1)
    robots, true_off = [], [12.3456, 3.21]
    for k, off in enumerate(true_off):
        t = np.arange(0.0, 8.0, 0.01) - 1.0 + rng.uniform(0, 0.01)   # common time of the samples
        pwm = np.clip((t - 0.0) / 0.3, 0, 1)[:, None] * [0.6, 0.6, 0.6, 0.6]   # motors start at t = 0
        z = np.where(t > 0.5, np.minimum(t - 0.5, 1.0), 0.0)
        p = np.stack([np.full_like(t, k * 0.3), np.zeros_like(t), z], 1)
        keep = ~((t > 4.0) & (t < 4.3)) if k == 1 else np.ones_like(t, bool)
        robots.append(RobotLog.from_usd(usdlog.decode(_robot_file((t + off)[keep], p[keep], pwm[keep]))))
    flights, rep = align(["small", "small"], robots)
    assert rep["sync"] == "take-off"
    off = np.array(rep["clock_offsets_s"])   # common clock 0 at the PWM crossing, the same for both
    np.testing.assert_allclose(off - off[0], np.array(true_off) - true_off[0], atol=1e-3)
    np.testing.assert_allclose(off - true_off, 0.05 / 2.0, atol=1e-3)   # PWM_ON / ramp slope
    gap = np.array([4.0, 4.3]) - 0.025            # the missing samples on the common clock
    assert len(flights) == 2 and gap[0] - 0.02 < flights[0].t[-1] < gap[0] < gap[1] < flights[1].t[0] < gap[1] + 0.02
    assert 0.5 - 0.025 < flights[0].t[0] <= 0.51 and all(np.all(f.p[:, :, 2] > 0.02) for f in flights)   # airborne only
    robots[0].sync_s = 1.0
    with pytest.raises(LogError, match="only some robots"):
        align(["small", "small"], robots)


@pytest.fixture(scope="module")
def sim_logs(cfg, exported, tmp_path_factory):
    """A small and a large robot swapping (6 s, ground truth kept apart), written as
    two uSD files with their own clocks."""
    sp, start = swap(2, [0.5, 0.8], radius=0.4, duration=2.5, rest=0.5, seed=2)
    log = CLoopSwarm(cfg, robots_of(["small", "large"], start), exported.gen_dir, aero=True).run(6.0, sp)
    root = tmp_path_factory.mktemp("usd")
    write_manifest(root, [write_flight(root, "swap", ["small", "large"], log, seed=5)])
    return root, log


def test_simulated_logs_aligned_and_labelled_against_the_truth(cfg, sim_logs):
    root, log = sim_logs
    flights, reports = logs_to_flights(cfg, root)
    rep = reports[0]
    assert rep["sync"] == "sync event" and rep["pieces"] == 1 and len(flights) == 1
    fl = flights[0]
    k = np.rint(fl.t * 100).astype(int)                     # the grid is the simulator's log times
    np.testing.assert_allclose(fl.t, log["t"][k], atol=1e-9)
    assert len(k) >= len(log["t"]) - 16                   # only the late log starts are lost
    np.testing.assert_allclose(fl.p, log["p"][k], atol=2e-4)  # 150 us jitter resampled away
    for i, kind in enumerate(["small", "large"]):
        veh = cfg.vehicle(kind)
        fa = residual_force(fl.t, fl.v[:, i], fl.q[:, i], fl.pwm[:, i], fl.battery_V[:, i], veh["mass_g"] / 1000,
                            veh["psi1"], veh["lambda"])
        ok = ~np.isnan(fa[:, 2])
        err_g = (fa[ok, 2] - log["truth_fa"][k[ok], i, 2]) * 1000 / G
        rms = float(np.sqrt(np.mean(err_g ** 2)))
        print(f"{kind}: label error through the uSD path rms {rms:.3f} g, max {np.abs(err_g).max():.2f} g")
        assert rms < 0.5 and np.abs(err_g).max() < 6.0
    assert log["truth_fa"][:, 0, 2].min() * 1000 / G < -10.0   # the swap produced real downwash


def ns2(*args):
    return subprocess.run([sys.executable, "-m", "ns2cli", *map(str, args)], capture_output=True, text=True)


def test_end_to_end_logs_to_data_train_export(cfg, sim_logs, tmp_path, monkeypatch):
    """The real-flight path on simulated flights: uSD files -> `ns2 logs-to-data` ->
    training -> export (in-process, with fewer error-measurement queries than the
    exporter's default to keep the suite fast; tests/test_export.py covers the rest)."""
    import ns2codegen.export as export_mod
    from ns2codegen.export import cfloat

    root, _ = sim_logs
    vfile = tmp_path / "large.toml"   # a vehicle parameter file (as `ns2 sysid` writes): lambda 17.5
    vfile.write_text('[vehicle]\nname = "large"\nlambda = 17.5\n')
    cfg = cfg.with_vehicle_files([vfile])
    r = ns2("logs-to-data", root, "--out", tmp_path / "d.npz", "--vehicle", vfile, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["samples"] > 1000 and set(rep["scenarios"]) == {"L->S", "S->L"}
    assert rep["flights"][0]["sync"] == "sync event"
    ds = Dataset.load(tmp_path / "d.npz")
    assert len(ds) == rep["samples"] and ds.extra["generator"] == "usd-logs"
    assert np.any(ds.nbr_type != cfg.env_index)       # the other robot came inside the interaction volume
    model, report = train(cfg, ds, epochs=3, seed=0)
    assert np.isfinite(report["validation"]["mse"])
    save_checkpoint(tmp_path / "m.pt", model, cfg, {"seed": 0, "data_hash": ds.content_hash(), "report": report})
    monkeypatch.setattr(export_mod, "ERROR_QUERIES", 1000)
    man = export_mod.export(tmp_path / "m.pt", tmp_path / "gen")
    assert man["data_hash"] == ds.content_hash() and man["robot_types"] == ["small", "large"]
    assert man["vehicles"]["large"]["lambda"] == 17.5 and man["vehicles"]["large"]["vehicle_file"] == "large.toml"
    veh_h = (tmp_path / "gen" / "ns2_vehicles.h").read_text()   # the firmware controller's parameters
    assert veh_h.index(f".lambda = {cfloat(17.5)}") > veh_h.index("/* large */") > veh_h.index(f".lambda = {cfloat(16.0)}")
    assert (tmp_path / "gen" / "ns2_model_float.h").stat().st_size > 1000
    # a corrupt log is a clear error with exit code 1, no data set written
    bad = root.parent / "bad"
    bad.mkdir(exist_ok=True)
    (bad / "flights.toml").write_text((root / "flights.toml").read_text())
    (bad / "swap").mkdir(exist_ok=True)
    for name in ("cf0.usd", "cf1.usd"):
        (bad / "swap" / name).write_bytes((root / "swap" / name).read_bytes()[:-100])
    r = ns2("logs-to-data", bad, "--out", tmp_path / "bad.npz")
    assert r.returncode == 1 and "CRC-32 mismatch" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "bad.npz").exists()
    r = ns2("logs-to-data", bad, "--out", tmp_path / "bad.npz", "--allow-truncated", "--json")
    assert r.returncode == 0, r.stderr
    assert "no valid CRC" in r.stdout
