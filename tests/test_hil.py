"""Serial hardware-in-the-loop: the HIL image in QEMU behind a pseudo-terminal,
driven through pyserial; corrupted streams, a silent and a wrong target."""
import os
import threading
import time

import numpy as np
import pytest

from ns2codegen.queries import random_queries
from conftest import ARM, QEMU, needs
from ns2host import hil, target

needs_target = needs(ARM, QEMU)


@pytest.fixture(scope="module")
def qemu_hil(exported):
    proc, pty = hil.start_qemu(target.build_hil_image(exported.gen_dir))
    client = hil.HilClient(pty, timeout=2.0)
    yield client
    client.close()
    proc.kill()
    proc.wait()


@needs_target
def test_hil_bit_exact_over_serial(exported, qemu_hil):
    q = random_queries(exported.cfg, 150, seed=8, wild=0.05, max_given=20)
    report = hil.run(qemu_hil, q, exported.cmodel())
    assert report["mismatches"] == 0, report["first_mismatches"]
    assert report["queries"] == 150 and report["round_trip_ms"]["median"] > 0


@needs_target
def test_hil_with_wake_memory_bit_exact_over_serial(history):
    """A network with wake memory over the serial link: 24 values per neighbour and the
    own past in the PREDICT frame (at most 9 neighbours fit a frame), the *_hist entry
    points on the target, bit for bit with the host C."""
    proc, pty = hil.start_qemu(target.build_hil_image(history.gen_dir))
    client = hil.HilClient(pty, timeout=2.0)
    try:
        q = random_queries(history.cfg, 80, seed=8, wild=0.05, max_given=9)
        assert q.past.shape[1] == 3
        report = hil.run(client, q, history.cmodel())
        assert report["mismatches"] == 0, report["first_mismatches"]
        assert report["queries"] == 80 and report["error_frames"] == 0
    finally:
        client.close()
        proc.kill()
        proc.wait()


@needs_target
def test_hil_recovers_from_a_corrupted_stream(exported, qemu_hil):
    port = qemu_hil.port
    errors_before = qemu_hil.stats.error_frames
    good = hil.frame(hil.PING, 7, b"x" * 10)
    bad_crc = bytearray(good)
    bad_crc[8] ^= 0xFF
    port.write(os.urandom(300).replace(b"\xa5", b"\x00") + bytes(bad_crc) + b"\xa5\x5a\xff\xff" + good[:5])
    time.sleep(0.3)
    # the target rejected the bad frames (ERROR answers) and still serves requests
    assert qemu_hil.ping(b"after garbage") == b"after garbage"
    assert qemu_hil.stats.error_frames > errors_before
    q = random_queries(exported.cfg, 20, seed=9, max_given=8)
    assert hil.run(qemu_hil, q, exported.cmodel())["mismatches"] == 0


def test_silent_target_is_reported():
    master, slave = os.openpty()
    try:
        client = hil.HilClient(os.ttyname(slave), timeout=0.2, retries=1)
        with pytest.raises(hil.HilError, match="no answer within 0.2 s after 2 attempts"):
            client.ping()
        client.close()
    finally:
        os.close(master)
        os.close(slave)


def test_wrong_answer_is_reported():
    """A fake target that answers PONG to everything."""
    master, slave = os.openpty()
    stop = threading.Event()

    def fake():
        reader = hil.FrameReader()
        while not stop.is_set():
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            for _, seq, _ in reader.feed(data):
                os.write(master, hil.frame(hil.PONG, seq, b""))

    th = threading.Thread(target=fake, daemon=True)
    th.start()
    try:
        client = hil.HilClient(os.ttyname(slave), timeout=5.0)   # generous: the fake answers from a thread (a loaded machine)
        with pytest.raises(hil.HilError, match="answered type 0x82, expected 0x81"):
            client.predict(0, [0, 0, 1], [0, 0, 0], [], np.zeros((0, 6)))
        client.close()
    finally:
        stop.set()
        os.close(slave)
        os.close(master)


def test_frame_reader_resynchronizes():
    good = hil.frame(hil.RESULT, 3, bytes(18))
    bad = bytearray(hil.frame(hil.RESULT, 4, bytes(18)))
    bad[-1] ^= 1
    r = hil.FrameReader()
    frames = r.feed(b"\x00\xa5garbage\xa5\x5a" + bytes(bad) + good[:7])
    frames += r.feed(good[7:])
    assert frames == [(hil.RESULT, 3, bytes(18))]
    assert r.bad_frames >= 1 and r.garbage_bytes > 0
    assert hil.crc16(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE check value


def test_ping_longer_than_a_reply_is_refused():
    """Issue 17 D1: the target echoes at most MAX_REPLY bytes (the C side is checked
    under ASan by tests/test_fuzz.py); the client refuses to ask for more."""
    master, slave = os.openpty()
    try:
        client = hil.HilClient(os.ttyname(slave), timeout=0.2, retries=0)
        with pytest.raises(ValueError, match="at most 32"):
            client.ping(b"x" * 35)
        client.close()
    finally:
        os.close(master)
        os.close(slave)
