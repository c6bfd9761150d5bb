"""`ns2 logs-to-data` on the radio log of `ns2 fly` (JSON lines, ns2codegen/logs/radiolog.py):
the robots' clocks put on the ground's, the log blocks joined, and every bad line one
error naming the file and the line, with nothing written."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from ns2cli import main

PERIOD_MS = 50
BOOT_MS = {"cf1": 12_345, "cf7": 987}       # each robot's clock at the ground's 0


def _lines(n=120, seed=0):
    """Two robots circling at 0.5 m and 0.9 m, their packets in the blocks of ns2ground.cf,
    each block delayed 2-12 ms on the way to the ground."""
    rng = np.random.default_rng(seed)
    out = [{"flight": {"robots": {"cf1": "small", "cf7": "large"}, "sync": 7}}]
    for k in range(n):
        t = k * PERIOD_MS / 1000.0
        for name, z in (("cf1", 0.5), ("cf7", 0.9)):
            tr = k * PERIOD_MS + BOOT_MS[name]
            p = [0.2 * np.cos(t), 0.2 * np.sin(t), z]
            v = [-0.2 * np.sin(t), 0.2 * np.cos(t), 0.0]
            blocks = [{"ns2.faHat": 0.1, "ns2.status": 0, "pm.vbat": 3.9},
                      {"stateEstimate.x": p[0], "stateEstimate.y": p[1], "stateEstimate.z": p[2],
                       "stateEstimate.vx": v[0], "stateEstimate.vy": v[1]},
                      {"stateEstimate.vz": v[2], **{f"motor.m{j}": 30000 for j in range(1, 5)}},
                      {"stateEstimate.qw": 1.0, "stateEstimate.qx": 0.0, "stateEstimate.qy": 0.0, "stateEstimate.qz": 0.0}]
            for b in blocks:
                host = tr - BOOT_MS[name] + int(rng.integers(2, 13))
                out.append({"robot": name, "t_ms": tr, "host_ms": host, **b})
    return out


def _write(path, lines):
    path.write_text("".join((x if isinstance(x, str) else json.dumps(x)) + "\n" for x in lines))
    return path


def test_radio_log_to_data_set(tmp_path):
    log = _write(tmp_path / "f.jsonl", _lines() + _lines(seed=1))   # ns2 fly appends: two flights
    r = CliRunner().invoke(main, ["logs-to-data", str(log), "--out", str(tmp_path / "d.npz"), "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert len(rep["flights"]) == 2 and rep["samples"] > 300
    for fl in rep["flights"]:
        assert fl["rate_hz"] == 20.0 and fl["robots"] == ["cf1", "cf7"]
        off = np.array(fl["clock_offsets_s"])   # each robot's clock at the common instant
        # the boot times recovered to within the delays' spread at their fastest (2 ms)
        assert abs((off[0] - off[1]) - (BOOT_MS["cf1"] - BOOT_MS["cf7"]) / 1000.0) <= 0.003, off
    from ns2codegen.data.dataset import Dataset
    ds = Dataset.load(tmp_path / "d.npz")
    assert set(ds.robot_type.tolist()) == {0, 1} and np.all(np.isfinite(ds.label_g))


GOOD = _lines(40)


@pytest.mark.parametrize("edit, message", [
    (lambda x: x[:5] + ["{not json"] + x[5:], "line 6: not JSON"),
    (lambda x: x[1:], "line 1: a log packet before the first flight header line"),
    (lambda x: x[:3] + [dict(x[3], robot="cf9")] + x[4:], "line 4: robot: 'cf9' is not a robot of the flight of "
                                                          "line 1 (cf1, cf7)"),
    (lambda x: x[:3] + [dict(x[3], t_ms="soon")] + x[4:], "line 4: t_ms: missing or not a finite number"),
    (lambda x: x[:3] + ['{"robot": "cf1", "t_ms": 1, "host_ms": 2, "pm.vbat": NaN}'] + x[4:],
     "line 4: pm.vbat: nan is not a finite number"),
    (lambda x: [{"flight": {"robots": []}}] + x[1:], "line 1: flight.robots must map each robot's name"),
    (lambda x: [{"flight": {"robots": {"cf1": "tiny", "cf7": "large"}}}] + x[1:],
     "line 1: flight.robots: robot types ['tiny'] are not in the config"),
    (lambda x: [y for y in x if "motor.m1" not in str(y)], "robot cf1: no samples of ['stateEstimate.vz', 'motor.m1', "),
    (lambda x: [], "no flight header line"),
    # issue 56: nested 100,000 deep, numbers beyond any float or of more digits than Python converts,
    # values no Crazyflie logs, names that are not one printable line
    (lambda x: x[:5] + ["[" * 100_000] + x[5:], "line 6: not JSON of a radio log: nested deeper than 8 levels"),
    (lambda x: x[:5] + ["[" * 100_000 + "]" * 100_000] + x[5:], "line 6: not JSON of a radio log: nested deeper"),
    (lambda x: x[:5] + ['{"robot": "cf1", "x": ' + "{" * 50_000] + x[5:], "line 6: not JSON of a radio log: nested"),
    (lambda x: x[:3] + ['{"robot": "cf1", "t_ms": 1' + "0" * 5000 + ', "host_ms": 2}'] + x[4:], "line 4: not JSON ("),
    (lambda x: x[:3] + ['{"robot": "cf1", "t_ms": 1' + "0" * 400 + ', "host_ms": 2}'] + x[4:],
     "line 4: t_ms: missing or not a finite number"),
    (lambda x: x[:3] + ['{"robot": "cf1", "t_ms": 1, "host_ms": 2, "pm.vbat": 1e999}'] + x[4:],
     "line 4: pm.vbat: inf is not a finite number"),
    (lambda x: x[:3] + [dict(x[3], robot=["cf1"])] + x[4:], "line 4: robot: ['cf1'] is not a robot of the flight"),
    (lambda x: x[:6] + [dict(x[6], **{"stateEstimate.z": 150.0})] + x[7:],
     "line 7: stateEstimate.z: 150.0 is outside the physical range [-100, 100]: corrupt log"),
    (lambda x: x[:6] + [dict(x[6], **{"stateEstimate.z": 3e38})] + x[7:], "line 7: stateEstimate.z: 3e+38 is beyond"),
    (lambda x: x[:8] + [dict(x[8], **{"stateEstimate.qw": 0.0})] + x[9:], "line 9: stateEstimate.qw/qx/qy/qz: norm 0"),
    (lambda x: [{"flight": {"robots": {"cf1\n": "small"}}}] + x[1:], "line 1: flight.robots: 'cf1\\n': a robot's"),
    (lambda x: [{"flight": {"robots": {"cf1": "small"}, "sync": "x"}}] + x[1:], "line 1: flight.sync: 'x'"),
])
def test_bad_radio_logs_are_one_line_errors(tmp_path, edit, message):
    log = _write(tmp_path / "f.jsonl", edit(list(GOOD)))
    out = tmp_path / "d.npz"
    r = CliRunner().invoke(main, ["logs-to-data", str(log), "--out", str(out)])
    assert r.exit_code == 1, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith(f"Error: {log}") and message in last, last
    assert not out.exists()


@pytest.mark.parametrize("encode, message", [
    (lambda t: t.encode("utf-16"), "UTF-16 text (byte-order mark ff fe)"),
    (lambda t: t.encode("utf-32"), "UTF-32 text (byte-order mark ff fe 00 00)"),
    (lambda t: t.encode()[:300] + b"\xff\xfe" + t.encode()[300:], "line 3: not UTF-8 text (byte 0xff)"),
    (lambda t: bytes(range(256)), "line 2: not UTF-8 text (byte 0x80)"),   # 0x0a ends line 1
])
def test_a_radio_log_that_is_not_utf8_is_one_line(tmp_path, encode, message):
    """Issue 56: a radio log in another encoding or binary: one line naming the file."""
    log = tmp_path / "f.jsonl"
    log.write_bytes(encode("".join(json.dumps(x) + "\n" for x in GOOD)))
    r = CliRunner().invoke(main, ["logs-to-data", str(log), "--out", str(tmp_path / "d.npz")])
    assert r.exit_code == 1 and isinstance(r.exception, SystemExit), (r.output, r.exception)
    line, = r.output.strip().splitlines()
    assert line.startswith(f"Error: {log}: ") and message in line, line
    assert not (tmp_path / "d.npz").exists()


def test_utf8_byte_order_mark_and_crlf_are_read(tmp_path):
    """A radio log saved by an editor (UTF-8 with a byte-order mark, CRLF line ends) reads as
    ns2 fly wrote it; lines are numbered as an editor numbers them (U+2028 in a string
    does not end a line)."""
    good = "".join(json.dumps(x) + "\n" for x in GOOD)
    log = tmp_path / "f.jsonl"
    log.write_bytes(b"\xef\xbb\xbf" + good.replace("\n", "\r\n").encode())
    from ns2codegen.logs import radiolog

    assert [len(f["samples"]["cf1"]) for f in radiolog.read(log)] == [len(GOOD[1:]) // 2]
    lines = list(GOOD)
    lines[0] = {"flight": dict(lines[0]["flight"], note="a\u2028b")}   # the header's other keys are not read
    lines[4] = "{not json"
    log.write_text("".join((x if isinstance(x, str) else json.dumps(x, ensure_ascii=False)) + "\n" for x in lines))
    with pytest.raises(radiolog.RadioLogError, match=r"line 5: not JSON"):
        radiolog.read(log)
