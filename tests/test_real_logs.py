"""The paper's own flights (issue 22, 29): the authors' uSD logs of 16 June 2020 read,
decoded, aligned, labelled and cut as docs/real-flights.md says, on real files from
../shared/neural-swarm-data (extracted into build/test-real, never committed)."""
from __future__ import annotations

import struct
import subprocess
import zlib

import numpy as np
import pytest

from conftest import FIRMWARE, REAL_DATA, needs, real_logs
from ns2codegen.data.from_logs import flight_queries, flights_to_dataset
from ns2codegen.logs import usdlog
from ns2codegen.logs.align import RobotLog, logs_to_flights
from ns2paper.collection import COLLECTION, write_manifest
from ns2codegen.logs.compressed import quat_decompress
from ns2codegen.logs.usdlog import UsdLogError

pytestmark = needs(REAL_DATA)
SWAPS, WALKS1 = "neural-swarm-2020-06-16-swaps.tar.xz", "neural-swarm-2020-06-16-randomwalks-1.tar.xz"
SL = [f"{COLLECTION}/swap_sl/cf51_03", f"{COLLECTION}/swap_sl/cf101_03"]
LLL = [f"{COLLECTION}/swap_lll/cf{n}_01" for n in (100, 101, 102)]
LL_TOUCH = [f"{COLLECTION}/randomwalk_ll/cf{n}_01" for n in (101, 102)]


@pytest.fixture(scope="module")
def swaps():
    return real_logs(SWAPS, SL + LLL)


@pytest.fixture(scope="module")
def walks():
    return real_logs(WALKS1, LL_TOUCH)


def _first_block_by_hand(data: bytes):
    """The header and first block decoded with nothing but struct (the README's layout)."""
    n, i, names = data[0], 1, []
    for _ in range(n):
        j = data.index(b",", i)
        names.append(data[i:j].decode())
        i = j + 1
    assert ~zlib.crc32(data[:i]) & 0xFFFFFFFF == struct.unpack_from("<I", data, i)[0]
    rec = struct.Struct("<" + "".join(s[-2] for s in names))
    k = data[i + 4]
    return names, [rec.unpack_from(data, i + 5 + r * rec.size) for r in range(k)]


def test_reader_decodes_the_original_format(swaps):
    path = swaps / SL[0]
    log = usdlog.read(path)
    names, first = _first_block_by_hand(path.read_bytes())
    ev = log.event("fixedFrequency")
    assert log.version == 1 and log.crc_ok and len(names) == 35 and log.entries > 1800
    assert [f"{n}({t})" for n, t in log.types[usdlog.FIXED_FREQUENCY_ID].variables] == names
    for r, row in enumerate(first):
        for c, name in enumerate(names):
            assert ev[name[:-3]][r] == row[c]
    assert np.all(np.diff(ev["timestamp_us"].astype(np.int64)) > 0)
    assert np.array_equal(ev["timestamp_us"], ev["tick"].astype(np.uint64))


def test_reader_refuses_corruption_and_keeps_complete_blocks_of_a_cut_file(swaps, tmp_path):
    data = (swaps / SL[0]).read_bytes()
    names, first = _first_block_by_hand(data)
    hdr = data.index(b"ctrlFa.Faz(f),") + len("ctrlFa.Faz(f),") + 4
    bad = bytearray(data)
    bad[hdr + 3] ^= 0x10                     # a record byte of block 0
    with pytest.raises(UsdLogError, match="block 0 at byte .*CRC-32 mismatch"):
        usdlog.decode_fixed(bytes(bad))
    bad = bytearray(data)
    bad[2] ^= 0x01                           # a header byte: "tick" becomes "thck"
    with pytest.raises(UsdLogError, match="header CRC-32 mismatch"):
        usdlog.decode_fixed(bytes(bad))
    unknown = data.replace(b"tick(I)", b"tick(Q)", 1)
    with pytest.raises(UsdLogError, match=r"'tick\(Q\)' is not"):
        usdlog.decode_fixed(unknown)
    cut = tmp_path / "cf51_03"
    cut.write_bytes(data[:len(data) - 150])
    with pytest.raises(UsdLogError, match=r"cf51_03: block \d+ at byte \d+ is cut off"):
        usdlog.read(cut)
    kept = usdlog.read(cut, allow_truncated=True)
    assert "truncated" in kept.note and 0 < kept.entries < usdlog.read(swaps / SL[0]).entries
    assert len(str(pytest.raises(UsdLogError, usdlog.read, cut).value).splitlines()) == 1


@needs(FIRMWARE)
def test_quaternion_decoding_equals_the_firmware_header_bit_for_bit(swaps, tmp_path):
    """quat_decompress against quatdecompress of the pinned firmware's quatcompress.h, compiled on the host."""
    from ns2host import crazyflie

    header = crazyflie.firmware_dir() / "src" / "modules" / "interface" / "quatcompress.h"
    src = tmp_path / "q.c"
    src.write_text('#include <stdio.h>\n#include "quatcompress.h"\nint main(void){uint32_t c;float q[4];'
                   'while(fread(&c,4,1,stdin)==1){quatdecompress(c,q);fwrite(q,4,4,stdout);}return 0;}\n')
    exe = tmp_path / "q"
    subprocess.run(["gcc", "-std=gnu11", "-O0", "-ffp-contract=off", "-I", str(header.parent), str(src), "-o", str(exe),
                    "-lm"], check=True)
    rng = np.random.default_rng(0)
    logged = usdlog.read(swaps / SL[0]).event("fixedFrequency")["stateEstimateZ.quat"].astype(np.uint32)
    comp = np.concatenate([logged, rng.integers(0, 2**32, 200_000, dtype=np.uint64).astype(np.uint32)])
    out = subprocess.run([str(exe)], input=comp.tobytes(), capture_output=True, check=True).stdout
    c_q = np.frombuffer(out, np.float32).reshape(-1, 4)
    assert np.array_equal(quat_decompress(comp).view(np.uint32), c_q.view(np.uint32))


def _manifest(root, files, ids, types, labels=None, planes=True):
    lines = ["rate_hz = 100"]
    if planes:
        lines += ["[ground_plane_m]", "small = 0.05", "large = 0.06"]
    lines += ["[[flight]]", 'name = "f"', "robots = ["]
    for k, (f, i, t) in enumerate(zip(files, ids, types)):
        lab = "" if labels is None or labels[k] else ", label = false"
        lines.append(f'  {{file = "{f}", type = "{t}", id = "{i}"{lab}}},')
    (root / "flights.toml").write_text("\n".join(lines + ["]"]) + "\n")


def test_swap_alignment_from_the_broadcast_setpoints(swaps, cfg):
    _manifest(swaps, SL, ["cf51", "cf101"], ["small", "large"])
    flights, (rep,) = logs_to_flights(cfg, swaps)
    assert rep["sync"] == "setpoint events"
    err = rep["alignment_error"]
    assert err["events"] >= 10 and err["residual_max_ms"] < 3.0 and err["residual_rms_ms"] < 1.5
    assert max(abs(o) for o in rep["clock_offsets_s"]) < 0.02       # within two log periods of the log start
    assert "ground touch" not in rep["cut_s_by_reason_and_robot"] and "impact" not in rep["cut_s_by_reason_and_robot"]
    # the aligned setpoints of the two robots start and stop their swaps together
    robots = [RobotLog.from_usd(usdlog.read(swaps / f)) for f in SL]
    e = [r.setpoint_events() - o for r, o in zip(robots, rep["clock_offsets_s"])]
    assert np.nanmax(np.abs(e[0] - e[1])) < 3e-3


def test_labels_follow_the_onboard_prediction_and_hover_is_weight(swaps, cfg):
    _manifest(swaps, SL, ["cf51", "cf101"], ["small", "large"])
    flights, _ = logs_to_flights(cfg, swaps)
    ds = flights_to_dataset(cfg, flights)
    q = flight_queries(cfg, flights)
    assert len(q) == len(ds)
    # the large robot (cf101) under the small one: labels and the network flown agree in shape
    lab = ds.label_g[ds.robot_type == 1]
    onboard = np.concatenate([f.fa_onboard_g[2:-2, 1] for f in flights])
    assert lab.size == onboard.size
    assert np.corrcoef(lab, onboard)[0, 1] > 0.7
    assert lab.min() < -12.0 and onboard.min() < -6.0       # the small robot's downwash, seen three times
    # the small robot on top feels little: its labels stay within a few grams of zero
    lab = ds.label_g[ds.robot_type == 0]
    assert abs(np.median(lab)) < 2.0 and np.percentile(np.abs(lab), 95) < 4.0


def test_body_rates_agree_with_the_logged_attitude(swaps, cfg):
    """stateEstimateZ.rateRoll/Pitch/Yaw decoded as the body rates (rad/s): roll and pitch
    follow the rate of the logged attitude itself (2 q* dq/dt, the compressed quaternion
    by central differences) with its sign."""
    _manifest(swaps, SL, ["cf51", "cf101"], ["small", "large"])
    flights, _ = logs_to_flights(cfg, swaps)
    for fl in flights:
        assert fl.w is not None and fl.w.shape == fl.p.shape and np.isfinite(fl.w).all()
    fl = max(flights, key=lambda f: len(f.t))
    for i in range(2):
        q = fl.q[:, i]
        dq = (q[2:] - q[:-2]) / (2 * (fl.t[1] - fl.t[0]))
        w0, x0, y0, z0 = (q[1:-1] * [1, -1, -1, -1]).T
        dw, dx, dy, dz = dq.T
        from_q = 2 * np.stack([w0 * dx + x0 * dw + y0 * dz - z0 * dy, w0 * dy - x0 * dz + y0 * dw + z0 * dx], 1)
        for k in range(2):
            assert np.corrcoef(from_q[:, k], fl.w[1:-1, i, k])[0, 1] > 0.5, (i, k)


def test_ground_touches_cut_and_the_old_imu_robot_never_labelled(swaps, walks, cfg):
    _manifest(walks, LL_TOUCH, ["cf101", "cf102"], ["large", "large"])
    flights, (rep,) = logs_to_flights(cfg, walks)
    cuts = rep["cut_s_by_reason_and_robot"]
    assert "ground touch" in cuts and sum(cuts["ground touch"].values()) > 0.3     # readme: flight 01 touched
    for f in flights:
        gz = np.array([0.06, 0.06]) + 0.01
        assert np.all(f.p[:, :, 2] > gz)
    _manifest(swaps, LLL, ["cf100", "cf101", "cf102"], ["large"] * 3, labels=[False, True, True])
    flights, (rep,) = logs_to_flights(cfg, swaps)
    assert rep["not_labelled"] == ["cf100"]
    ds = flights_to_dataset(cfg, flights)
    steps = sum(len(f.t) - 4 for f in flights)
    assert len(ds) == 2 * steps                                 # cf101 and cf102 only
    nbr_counts = np.diff(ds.nbr_offsets) - 1
    assert nbr_counts.max() == 2                                # cf100 still a neighbour


def test_collection_manifest_covers_every_log():
    root = real_logs(SWAPS, SL + LLL)
    text = write_manifest(root).read_text()
    assert text.count("[[flight]]") == 2 and 'id = "cf100", label = false' in text


@pytest.fixture(scope="module", params=["exported", "history"])
def model(request):
    """The default network, then the one with wake memory (conftest.history)."""
    return request.getfixturevalue(request.param)


def test_selection_of_the_data_equals_the_c_on_real_flights(swaps, model):
    """Issue 29: the neighbour sets written to the data set equal the C's selection
    (host build of ns2_select.c) sample for sample on real flights, and the data set's
    rows (with wake memory: the lagged states too) the inputs the C feeds to phi."""
    from ns2exp.real import selection_mismatches
    from ns2host.cbuild import CModel

    _manifest(swaps, LLL, ["cf100", "cf101", "cf102"], ["large"] * 3)
    flights, _ = logs_to_flights(model.cfg, swaps)
    ds = flights_to_dataset(model.cfg, flights)
    q = flight_queries(model.cfg, flights)
    _, info = CModel(model.gen_dir).predict(q, fixed=False)
    ours = np.diff(ds.nbr_offsets) - 1
    assert len(q) == len(ds) > 1000
    assert np.array_equal(info["n_used"].astype(np.int64), ours)
    assert np.array_equal(info["status"], np.zeros(len(q), np.int32))
    res = selection_mismatches(model.gen_dir, q, ds)
    assert res["mismatches"] == 0 and res["input_row_mismatches"] == 0 and res["input_rows"] == len(ds.nbr_type)
    assert ds.nbr_state.shape[1] == model.cfg.input_dim
    if model.cfg.history_ms:   # the rows differ where the past differs: the check can fail
        q.nbr_rel[:, :, 6:] += np.float32(0.01)
        assert selection_mismatches(model.gen_dir, q, ds)["input_row_mismatches"] > 1000


def test_c_in_the_loop_on_real_samples_and_the_held_out_rule(swaps, cfg, model):
    """Issue 22 item 6 on a real flight: every sample through the exported C, float and
    fixed point, equals the references bit for bit (with wake memory too)."""
    exported = model
    from ns2exp.real import c_in_the_loop, is_held_out

    _manifest(swaps, LLL, ["cf100", "cf101", "cf102"], ["large"] * 3, labels=[False, True, True])
    flights, _ = logs_to_flights(exported.cfg, swaps)
    ds = flights_to_dataset(exported.cfg, flights)
    res = c_in_the_loop(exported.gen_dir, exported.checkpoint, flight_queries(exported.cfg, flights), ds.label_g)
    assert res["samples"] == len(ds) > 1000
    assert res["float_mismatches"] == 0 and res["fixed_mismatches"] == 0 and res["status_nonzero"] == 0
    assert 0 < res["abs_fixed_minus_float_g"]["max"] < 1.0
    if exported.cfg.history_ms:  # present-state queries (a data folder made without the lags): refused
        from ns2exp.real import RealDataError
        with pytest.raises(RealDataError, match=r"model.history_ms \[50, 100, 200\] but the queries have 0"):
            c_in_the_loop(exported.gen_dir, exported.checkpoint, flight_queries(cfg, flights), ds.label_g)
    names = [f"swap_ss/{k:02d}" for k in range(11)] + ["takeoff_l/cf102_00"]
    held = [n for n in names if is_held_out(n, names)]
    assert held == ["swap_ss/02", "swap_ss/07"]
