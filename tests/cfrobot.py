"""A link driver of the tests for bitcraze's cflib, and the robot behind it.

``RecordingDriver`` is a cflib link driver (``cflib.crtp.CLASSES``): cflib itself
builds every packet; the driver records them and hands them to a ``Robot`` whose
answers come from the built cf2.elf: its PARAM and LOG tables in table order (the
TOC ids the firmware gives them), each parameter's start value read from the ELF's
initialized data, the trajectory memory's size from the size of the firmware's
``trajectories_memory``.  The robot answers as the firmware's CRTP services do
(param_logic.c, log.c, mem.c, platformservice.c, read for the protocol, no code
taken), so cflib connects, reads and writes parameters, uploads trajectories and
streams log blocks through it; the tests then decode what cflib sent.  ``lose``
ends the link (cflib's link error), ``log_values`` sets what the robot logs.
"""
from __future__ import annotations

import queue
import struct
import time
import zlib

from cflib.crtp.crtpdriver import CRTPDriver
from cflib.crtp.crtpstack import CRTPPacket
from cflib.crtp.exceptions import WrongUriType

from ns2host import cfapp

PORT_PARAM, PORT_LOG, PORT_MEM, PORT_HL, PORT_PLATFORM, PORT_LINK = 2, 5, 4, 8, 13, 15
PROTOCOL_VERSION = 12             # crtp.h CRTP_PROTOCOL_VERSION of the pinned firmware
MEM_TYPE_TRAJ = 0x12
# the bootloader (Cloader's commands; the STM32F405's layout: 1 KB pages, the firmware from page 16)
NRF51, STM32 = 0xFE, 0xFF
BL_RESET, BL_RESET_INIT, BL_GET_INFO, BL_LOAD_BUFFER, BL_WRITE_FLASH = 0xF0, 0xFF, 0x10, 0x14, 0x18
BL_PROTOCOL = 0x10               # BootVersion.CF2_PROTO_VER
BL_INFO = {STM32: (1024, 10, 1024, 16), NRF51: (1024, 10, 232, 88)}   # page size, buffer pages, pages, start page
PARAM_RONLY, LOG_TYPE_MASK = 0x40, 0x0F
LOG_FMT = {1: "<B", 2: "<H", 3: "<I", 4: "<b", 5: "<h", 6: "<i", 7: "<f"}

ROBOTS: dict[str, "Robot"] = {}   # uri -> robot behind it
ROBOTS_MADE: list[str] = []
SENT: list[tuple[str, int, int, bytes]] = []   # every packet cflib sent to any robot, in order: (robot, port, channel, data)


def param_fmt(typ: int) -> str:
    """struct format of a PARAM type (param.h: size bits, float bit, unsigned bit)."""
    size = 1 << (typ & 0x03)
    if typ & 0x04:
        return "<f" if size == 4 else "<d"
    code = {1: "b", 2: "h", 4: "i", 8: "q"}[size]
    return "<" + (code.upper() if typ & 0x08 else code)


class Robot:
    """A Crazyflie's CRTP services, with the TOCs of a built cf2.elf."""

    def __init__(self, elf, name: str = "cf"):
        """``elf`` None: no parameters, logs or trajectory memory (a robot to flash)."""
        self.name = name
        self.params, self.logs, self.values, self.traj_size = [], [], [], 0
        if elf is not None:
            self.params = cfapp.param_entries(elf)
            self.logs = cfapp.log_entries(elf)
            im = cfapp.Image(elf)
            try:
                self.values = [self._start_value(im, typ, addr) for _, _, typ, _, addr in self.params]
                self.traj_size = im.symbols["trajectories_memory"]["st_size"]
            finally:
                im.close()
        self.boot_address = struct.pack(">I", 0xE7E70000 + len(ROBOTS_MADE) % 0x10000)   # unique per robot
        ROBOTS_MADE.append(name)
        self.traj = bytearray(self.traj_size)
        self.log_values = {f"{g}.{n}": 0 for g, n, *_ in self.logs}
        self.sent: list[tuple[int, int, bytes, float]] = []   # (port, channel, data, seconds since start) cflib sent
        self.hl: list[bytes] = []                          # high-level commander packets
        self.param_writes: list[tuple[str, object]] = []   # in the order they arrived
        self.out: queue.Queue = queue.Queue()
        self.blocks: dict[int, tuple[list[int], int]] = {}  # log block id -> (variable ids, period ms)
        self.running: dict[int, float] = {}
        self.alive = True
        self.driver = None
        self._t0 = time.monotonic()
        self.in_bootloader = False
        self.flash = bytearray(b"\xff" * BL_INFO[STM32][0] * BL_INFO[STM32][2])
        self.buffers = bytearray(BL_INFO[STM32][0] * BL_INFO[STM32][1])
        self.boots: list[str] = []                         # "bootloader" / "firmware", as it was reset
        self.flash_error = 0                               # what WRITE_FLASH reports (0: none)

    @staticmethod
    def _start_value(im, typ, addr):
        fmt = param_fmt(typ)
        try:
            return struct.unpack(fmt, im.read(addr, struct.calcsize(fmt)))[0]
        except (ValueError, struct.error):   # .bss: zero at start-up
            return 0

    def index(self, full: str) -> int:
        g, n = full.split(".")
        return next(i for i, (gg, nn, *_) in enumerate(self.params) if (gg, nn) == (g, n))

    def value(self, full: str):
        return self.values[self.index(full)]

    def hl_commands(self) -> list[int]:
        return [d[0] for d in self.hl]

    # -- the link
    def answer(self, port: int, channel: int, data: bytes) -> None:
        pk = CRTPPacket()
        pk.set_header(port, channel)
        pk.data = bytes(data)
        self.out.put(pk)

    def lose(self) -> None:
        """The radio link breaks: cflib is told through its link error callback."""
        self.alive = False
        if self.driver is not None and self.driver.link_error_callback is not None:
            self.driver.link_error_callback("Too many packets lost")

    def receive(self, pk) -> None:
        data = bytes(pk.data)
        port, channel = pk.header >> 4, pk.header & 0x03   # as sent (the bootloader sets port 0xFF)
        self.sent.append((port, channel, data, time.monotonic() - self._t0))
        SENT.append((self.name, port, channel, data))
        if not self.alive:
            return
        handler = {PORT_LINK: self._link, PORT_PLATFORM: self._platform, PORT_PARAM: self._param,
                   PORT_LOG: self._log, PORT_MEM: self._mem, PORT_HL: self._hl}.get(port)
        if handler is not None:
            handler(channel, data)

    @property
    def boot_uri(self) -> str:
        """Where the robot's bootloader answers (cflib's Cloader: radio://0/0/2M/B1<address>)."""
        return f"radio://0/0/2M/B1{self.boot_address.hex().upper()}"

    def _link(self, ch, data):
        if ch == 1 and not self.in_bootloader:  # source: the firmware speaks protocol versions
            self.answer(PORT_LINK, 1, b"Bitcraze Crazyflie" + bytes(12))
        elif ch == 3 and len(data) >= 2:
            self._bootloader(data)

    def _bootloader(self, data):
        target, cmd = data[0], data[1]
        if cmd == BL_RESET_INIT and target == NRF51:       # the address, little end first
            self.answer(PORT_LINK, 3, bytes([target, cmd]) + self.boot_address[::-1])
        elif cmd == BL_RESET and target == NRF51:
            self.in_bootloader = data[2] == 0
            self.boots.append("bootloader" if self.in_bootloader else "firmware")
        elif not self.in_bootloader:
            return
        elif cmd == BL_GET_INFO and target in BL_INFO:
            self.answer(PORT_LINK, 3, struct.pack("<BBHHHH", target, cmd, *BL_INFO[target]) + bytes(12)
                        + bytes([BL_PROTOCOL]))
        elif cmd == BL_LOAD_BUFFER and target == STM32:
            page, addr = struct.unpack_from("<HH", data, 2)
            at = page * BL_INFO[STM32][0] + addr
            self.buffers[at:at + len(data) - 6] = data[6:]
        elif cmd == BL_WRITE_FLASH and target == STM32:
            buf, page, count = struct.unpack_from("<HHH", data, 2)
            size = BL_INFO[STM32][0]
            if not self.flash_error:
                self.flash[page * size:(page + count) * size] = self.buffers[buf * size:(buf + count) * size]
            self.answer(PORT_LINK, 3, bytes([target, cmd, 0 if self.flash_error else 1, self.flash_error]))

    def _platform(self, ch, data):
        if ch == 1 and data[:1] == b"\x00":
            self.answer(PORT_PLATFORM, 1, bytes([0, PROTOCOL_VERSION]))

    def _toc(self, port, entries, data, type_of):
        if data[0] == 3:      # info v2: count, crc (log.c adds max blocks and ops)
            crc = zlib.crc32(repr(entries).encode())
            extra = bytes([16, 128]) if port == PORT_LOG else b""
            self.answer(port, 0, struct.pack("<BHI", 3, len(entries), crc) + extra)
        elif data[0] == 2:    # item v2
            i = struct.unpack_from("<H", data, 1)[0]
            g, n = entries[i][0], entries[i][1]
            self.answer(port, 0, struct.pack("<BHB", 2, i, type_of(entries[i])) + g.encode() + b"\0" + n.encode()
                        + b"\0")

    def _param(self, ch, data):
        if ch == 0:
            self._toc(PORT_PARAM, self.params, data, lambda e: e[2])
        elif ch == 1:         # read: id, status 0, value
            i = struct.unpack_from("<H", data)[0]
            fmt = param_fmt(self.params[i][2])
            self.answer(PORT_PARAM, 1, struct.pack("<HB", i, 0) + struct.pack(fmt, self.values[i]))
        elif ch == 2:         # write: the firmware ignores read-only ones, else echoes the packet
            i = struct.unpack_from("<H", data)[0]
            g, n, typ, _, _ = self.params[i]
            if typ & PARAM_RONLY:
                return
            self.values[i] = struct.unpack_from(param_fmt(typ), data, 2)[0]
            self.param_writes.append((f"{g}.{n}", self.values[i]))
            self.answer(PORT_PARAM, 2, data)
        elif ch == 3 and data[0] == 7:   # extended type v2
            i = struct.unpack_from("<H", data, 1)[0]
            self.answer(PORT_PARAM, 3, data[:3] + bytes([0, self.params[i][3]]))

    def _log(self, ch, data):
        if ch == 0:
            self._toc(PORT_LOG, self.logs, data, lambda e: e[2] & LOG_TYPE_MASK)  # log.c logGetType
        elif ch == 1:
            cmd, block = data[0], data[1] if len(data) > 1 else 0
            if cmd == 6:      # create block v2: (type, id16) per variable
                ids = [struct.unpack_from("<BH", data, o)[1] for o in range(2, len(data), 3)]
                self.blocks[block] = (ids, 0)
                self.answer(PORT_LOG, 1, bytes([cmd, block, 0]))
            elif cmd == 3:    # start: period in 10 ms
                self.blocks[block] = (self.blocks[block][0], data[2] * 10)
                self.running[block] = 0.0
                self.answer(PORT_LOG, 1, bytes([cmd, block, 0]))
            elif cmd in (2, 4):  # delete, stop
                self.running.pop(block, None)
                self.answer(PORT_LOG, 1, bytes([cmd, block, 0]))
            elif cmd == 5:    # reset
                self.blocks.clear()
                self.running.clear()
                self.answer(PORT_LOG, 1, bytes([cmd, 0, 0]))

    def _mem(self, ch, data):
        if ch == 0 and data[0] == 1:
            self.answer(PORT_MEM, 0, bytes([1, 1]))
        elif ch == 0 and data[0] == 2:
            self.answer(PORT_MEM, 0, struct.pack("<BBBI", 2, 0, MEM_TYPE_TRAJ, self.traj_size) + bytes(8))
        elif ch == 2:         # write: id, address, bytes -> id, address, status
            mid, addr = struct.unpack_from("<BI", data)
            payload = data[5:]
            ok = addr + len(payload) <= self.traj_size
            if ok:
                self.traj[addr:addr + len(payload)] = payload
            self.answer(PORT_MEM, 2, struct.pack("<BIB", mid, addr, 0 if ok else 8))
        elif ch == 1:         # read
            mid, addr, n = struct.unpack_from("<BIB", data)
            self.answer(PORT_MEM, 1, struct.pack("<BIB", mid, addr, 0) + bytes(self.traj[addr:addr + n]))

    def _hl(self, ch, data):
        self.hl.append(data)

    def poll_logs(self) -> None:
        """Send the data of every started log block that is due."""
        now = (time.monotonic() - self._t0) * 1000.0
        for block, last in list(self.running.items()):
            ids, period = self.blocks[block]
            if self.alive and now - last >= period:
                self.running[block] = now
                body = b"".join(struct.pack(LOG_FMT[self.logs[i][2] & LOG_TYPE_MASK],
                                            self.log_values[f"{self.logs[i][0]}.{self.logs[i][1]}"]) for i in ids)
                self.answer(PORT_LOG, 2, bytes([block]) + struct.pack("<I", int(now))[:3] + body)


class RecordingDriver(CRTPDriver):
    """cflib link driver to the ``Robot`` registered for a uri in ``ROBOTS``."""

    def __init__(self):
        super().__init__()
        self.needs_resending = False
        self.robot = None
        self.link_error_callback = None

    def connect(self, uri, radio_link_statistics_callback, link_error_callback):
        uri = uri.split("?")[0]   # cflib's bootloader adds ?safelink=0
        robot = ROBOTS.get(uri) or next((r for r in ROBOTS.values() if r.in_bootloader and r.boot_uri == uri), None)
        if robot is None:
            raise WrongUriType(f"no test robot at {uri}")
        self.robot = robot
        self.robot.driver = self
        self.link_error_callback = link_error_callback

    def send_packet(self, pk):
        self.robot.receive(pk)

    def receive_packet(self, wait=0):
        self.robot.poll_logs()
        try:
            return self.robot.out.get(timeout=min(wait, 0.01) if wait and wait > 0 else 0.01)
        except queue.Empty:
            return None

    def get_status(self):
        return "test link"

    def get_name(self):
        return "test"

    def scan_interface(self, address=None):
        return []

    def close(self):
        pass


def install(robots: dict[str, Robot]):
    """Only this driver in cflib (no radio, no USB), robots at their uris."""
    import cflib.crtp

    cflib.crtp.CLASSES[:] = [RecordingDriver]
    SENT.clear()
    ROBOTS.clear()
    ROBOTS.update(robots)

