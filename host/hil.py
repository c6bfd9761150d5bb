"""Serial hardware-in-the-loop: stream queries to a target running the HIL image
(firmware/target/hil_usart.c + firmware/hil/ns2_hil.c), read its answers and
compare them bit for bit with the host build of the same C.

The framing is documented in firmware/hil/ns2_hil.h.  The client writes one
request at a time, waits for the answer with a timeout, resends (a bounded
number of times) after a timeout or an ERROR frame, and its own reader
resynchronizes on garbage and frames with a bad CRC.  With QEMU the target is
the HIL image in ``qemu-system-arm -M netduinoplus2 -serial pty``; with a board
it is a USB-serial port.
"""
from __future__ import annotations

import re
import struct
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from ns2codegen.errors import Ns2Error

SYNC = b"\xa5\x5a"
PREDICT, PING, RESULT, PONG, ERROR = 0x01, 0x02, 0x81, 0x82, 0xEE
MAX_PAYLOAD = 1024
MAX_NEIGHBORS = 32
MAX_REPLY = 32  # body bytes of a frame sent by the target (NS2_HIL_MAX_REPLY)
ERROR_CODES = {1: "bad CRC", 2: "bad length", 3: "unknown type", 4: "malformed body"}


class HilError(Ns2Error, RuntimeError):
    """The target answered wrongly or not at all."""


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE."""
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def frame(msg_type: int, seq: int, body: bytes) -> bytes:
    payload = bytes([msg_type]) + struct.pack("<H", seq & 0xFFFF) + body
    if len(payload) > MAX_PAYLOAD:
        raise ValueError("payload too long")
    head = struct.pack("<H", len(payload))
    return SYNC + head + payload + struct.pack("<H", crc16(head + payload))


def predict_body(robot_type: int, p, v, types, rels, past=()) -> bytes:
    """A PREDICT body: rels of 6 values per neighbour, or 6 (1 + lags) with wake memory
    and then the own past ([p; v] at each lag)."""
    if len(types) > MAX_NEIGHBORS:
        raise ValueError(f"at most {MAX_NEIGHBORS} neighbours per HIL request")
    out = [struct.pack("<BB3f3f", robot_type, len(types), *np.asarray(p, np.float32), *np.asarray(v, np.float32))]
    for t, r in zip(types, rels):
        out.append(struct.pack("<B", int(t)) + np.asarray(r, "<f4").tobytes())
    out.append(np.asarray(past, "<f4").tobytes())
    return b"".join(out)


class FrameReader:
    """Incremental frame parser with resynchronization (the host-side twin of ns2_hil.c)."""

    def __init__(self):
        self.buf = bytearray()
        self.bad_frames = 0
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        self.buf += data
        frames = []
        while True:
            i = self.buf.find(SYNC)
            if i < 0:
                keep = 1 if self.buf.endswith(SYNC[:1]) else 0
                self.garbage_bytes += len(self.buf) - keep
                del self.buf[:len(self.buf) - keep]
                return frames
            self.garbage_bytes += i
            del self.buf[:i]
            if len(self.buf) < 4:
                return frames
            (n,) = struct.unpack_from("<H", self.buf, 2)
            if n < 3 or n > MAX_PAYLOAD:
                self.bad_frames += 1
                del self.buf[:1]
                continue
            if len(self.buf) < 6 + n:
                return frames
            payload = bytes(self.buf[4:4 + n])
            (crc,) = struct.unpack_from("<H", self.buf, 4 + n)
            if crc != crc16(bytes(self.buf[2:4]) + payload):
                self.bad_frames += 1
                del self.buf[:1]
                continue
            del self.buf[:6 + n]
            frames.append((payload[0], struct.unpack_from("<H", payload, 1)[0], payload[3:]))


@dataclass
class Result:
    status: int
    f32_bits: int
    q15: int
    n_used: int
    n_invalid: int
    n_outside: int
    n_truncated: int


@dataclass
class Stats:
    requests: int = 0
    retries: int = 0
    error_frames: int = 0
    latencies_s: list = field(default_factory=list)


class HilClient:
    """Request/response over a pyserial port (or any object with read/write)."""

    def __init__(self, port, timeout: float = 1.0, retries: int = 3, baudrate: int = 115200):
        if isinstance(port, (str, Path)):
            import serial

            port = serial.Serial(str(port), baudrate=baudrate, timeout=0.002)
        self.port = port
        self.timeout = timeout
        self.retries = retries
        self.reader = FrameReader()
        self.seq = 0
        self.stats = Stats()

    def close(self) -> None:
        self.port.close()

    def _exchange(self, msg_type: int, body: bytes, want: int) -> bytes:
        last = "no answer"
        for attempt in range(self.retries + 1):
            self.seq = (self.seq + 1) & 0xFFFF
            t0 = time.perf_counter()
            self.port.write(frame(msg_type, self.seq, body))
            self.stats.requests += 1
            if attempt:
                self.stats.retries += 1
            deadline = t0 + self.timeout
            while time.perf_counter() < deadline:
                chunk = self.port.read(max(1, getattr(self.port, "in_waiting", 0)))
                for ftype, seq, fbody in self.reader.feed(chunk or b""):
                    if ftype == ERROR:
                        self.stats.error_frames += 1
                        code = fbody[0] if fbody else 0
                        last = f"target reported {ERROR_CODES.get(code, code)}"
                        if seq in (self.seq, 0xFFFF):
                            deadline = 0.0  # resend now
                            break
                        continue
                    if seq != self.seq:
                        continue  # a late answer to an earlier attempt
                    if ftype != want:
                        raise HilError(f"target answered type 0x{ftype:02x}, expected 0x{want:02x}")
                    self.stats.latencies_s.append(time.perf_counter() - t0)
                    return fbody
            else:
                last = f"no answer within {self.timeout} s"
        raise HilError(f"{last} after {self.retries + 1} attempts")

    def ping(self, data: bytes = b"ns2") -> bytes:
        if len(data) > MAX_REPLY:
            raise ValueError(f"PING body of {len(data)} bytes: the target echoes at most {MAX_REPLY}")
        body = self._exchange(PING, data, PONG)
        if body != data:
            raise HilError(f"PING echo differs ({len(body)} bytes back, {len(data)} sent)")
        return body

    def predict(self, robot_type: int, p, v, types, rels, past=()) -> Result:
        body = self._exchange(PREDICT, predict_body(robot_type, p, v, types, rels, past), RESULT)
        if len(body) != 18:
            raise HilError(f"RESULT body of {len(body)} bytes, expected 18")
        return Result(*struct.unpack("<iIhHHHH", body))


def run(client: HilClient, queries, cmodel, progress=None) -> dict:
    """Run ``queries`` on the target; compare with the host C bit for bit (``progress(1)``
    after every query)."""
    f_host, info = cmodel.predict(queries, fixed=False)
    q_host, _ = cmodel.predict(queries, fixed=True)
    mismatches = []
    for i in range(len(queries)):
        n = int(queries.n[i])
        r = client.predict(int(queries.robot_type[i]), queries.p[i], queries.v[i],
                           queries.nbr_type[i, :n], queries.nbr_rel[i, :n], queries.past[i])
        host = (int(info["status"][i]), int(f_host[i:i + 1].view(np.uint32)[0]), int(q_host[i]),
                int(info["n_used"][i]), int(info["n_invalid"][i]), int(info["n_outside"][i]),
                int(info["n_truncated"][i]))
        got = (r.status, r.f32_bits, r.q15, r.n_used, r.n_invalid, r.n_outside, r.n_truncated)
        if got != host:
            mismatches.append({"query": i, "target": got, "host": host})
        if progress is not None:
            progress(1)
    lat = np.array(client.stats.latencies_s) * 1e3
    return {"queries": len(queries), "mismatches": len(mismatches), "first_mismatches": mismatches[:5],
            "requests": client.stats.requests, "retries": client.stats.retries,
            "error_frames": client.stats.error_frames, "garbage_bytes": client.reader.garbage_bytes,
            "bad_frames": client.reader.bad_frames,
            "round_trip_ms": {"median": float(np.median(lat)), "p99": float(np.percentile(lat, 99)),
                              "max": float(lat.max())} if lat.size else None}


def start_qemu(elf: Path, timeout: float = 10.0) -> tuple[subprocess.Popen, str]:
    """Start the HIL image in QEMU with its USART on a new pseudo-terminal."""
    proc = subprocess.Popen(["qemu-system-arm", "-M", "netduinoplus2", "-display", "none", "-monitor", "none",
                             "-serial", "pty", "-kernel", str(elf)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + timeout
    line = ""
    while time.time() < deadline:
        line = proc.stdout.readline()
        m = re.search(r"(/dev/pts/\d+)", line)
        if m:
            return proc, m.group(1)
        if proc.poll() is not None:
            break
    proc.kill()
    raise HilError(f"qemu did not report its pty: {line!r}")
