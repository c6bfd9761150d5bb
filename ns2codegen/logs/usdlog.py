"""Reader and writer of the binary log files of the Crazyflie uSD-card deck.

Format followed: the event-based log format **version 2** that bitcraze's
crazyflie-firmware writes since its event-trigger logging (``usddeck.c``,
firmware 2021.01 and later; the same layout its ``tools/usdlog/cfusdlog.py``
decodes).  All integers little-endian:

  header   uint8   magic 0xBC
           uint16  version (2)
           uint16  number of event types
  per event type:
           uint16  event id (0xFFFF: the fixed-frequency "event" of the config's
                   ``on:fixedFrequency`` block)
           char[]  event name, NUL-terminated
           uint16  number of variables
           per variable: char[] "<name>(<t>)", NUL-terminated, where <t> is the
                   struct type character B b H h I i f e (uint8 ... float, fp16);
                   an event's payload variables come first, then the logged
                   variables of its config block
  entries, until the last 4 bytes:
           uint16  event id
           uint64  timestamp, microseconds of the on-board clock (usecTimestamp)
           the variables' values packed without padding in the declared order
  trailer  uint32  CRC-32 (zlib/IEEE polynomial) of every byte before it

The firmware writes the CRC only when logging stops; a file cut by a power loss
has no CRC and may end inside an entry.  ``decode`` rejects such a file unless
``allow_truncated=True``, which keeps the complete entries before the first
undecodable byte and says so in ``UsdLog.note`` (documented skipping, never
silent).  Corruption is not truncation and is refused even then: an undecodable
entry followed by more than one SD sector (TRUNCATION_TAIL) of data, or entries
that end exactly where a complete file keeps its CRC-32 when that CRC is wrong.  Unknown event ids and malformed headers are errors.

The uSD deck's **original fixed-frequency format** (crazyflie-firmware before 2021;
the format of the Neural-Swarm2 authors' logs of 2019-2020) is told apart by content
(a version-2 file starts with 0xBC followed by version 2; an original file starts with
its variable count followed by an ASCII name) and decoded by ``decode_fixed``:

  header   uint8   number of variables n
           n times "<name>(<t>),"  (ASCII, each followed by a comma)
           uint32  CRC-32 of the header bytes before it
  blocks, until the end of the file:
           uint8   number of records k (1..255)
           k records, the variables packed little-endian without padding
           uint32  CRC-32 of the block's count byte and records

The CRCs are the firmware's ``crc32`` without the final inversion: the stored value
is the bitwise complement of zlib's CRC-32, so that the CRC of the bytes followed by
their stored CRC is 0xFFFFFFFF.  The records become the ``fixedFrequency`` event; its
``timestamp_us`` is the record's ``tick`` variable (microseconds of the robot's
clock); a file without ``tick`` is refused.  A bad header CRC is an error; a bad block CRC is an
error naming the block (``allow_truncated`` does not skip corruption); a file that
ends inside its last block (power loss) is an error unless ``allow_truncated``, which
keeps the complete blocks before it and says so in ``UsdLog.note``.

This is our own implementation from the documented layout, not bitcraze's code.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..fileio import atomic_write_bytes
from ..errors import Ns2Error

MAGIC = 0xBC
VERSION = 2
FIXED_FREQUENCY_ID = 0xFFFF
FIXED_FREQUENCY_NAME = "fixedFrequency"
TYPE_CHARS = "BbHhIife"
_ENTRY_HEAD = struct.Struct("<HQ")  # event id, timestamp (us)
TRUNCATION_TAIL = 512  # bytes: a power loss leaves at most one SD sector of garbage after the last entry


class UsdLogError(Ns2Error, ValueError):
    """The file is not a readable uSD log (bad header, corrupt, truncated)."""


@dataclass(frozen=True)
class EventType:
    id: int
    name: str
    variables: tuple[tuple[str, str], ...]   # (name, struct type character)

    @property
    def struct(self) -> struct.Struct:
        return struct.Struct("<" + "".join(t for _, t in self.variables))


@dataclass
class UsdLog:
    version: int
    types: dict[int, EventType]
    events: dict[str, dict[str, np.ndarray]]   # event name -> "timestamp_us" and variables
    crc_ok: bool
    note: str = ""
    entries: int = 0

    def event(self, name: str) -> dict[str, np.ndarray]:
        if name not in self.events:
            raise UsdLogError(f"the log has no event {name!r} (it has {sorted(self.events)})")
        return self.events[name]


def _cstring(data: bytes, i: int, what: str) -> tuple[str, int]:
    end = data.find(b"\0", i)
    if end < 0:
        raise UsdLogError(f"header truncated: {what} at byte {i} has no NUL terminator")
    try:
        return data[i:end].decode("ascii"), end + 1
    except UnicodeDecodeError as e:
        raise UsdLogError(f"header corrupt: {what} at byte {i} is not ASCII") from e


def _u16(data: bytes, i: int, what: str) -> tuple[int, int]:
    if i + 2 > len(data):
        raise UsdLogError(f"header truncated while reading {what} at byte {i}")
    return struct.unpack_from("<H", data, i)[0], i + 2


def _header(data: bytes) -> tuple[int, dict[int, EventType], int]:
    if len(data) < 5:
        raise UsdLogError(f"file too short for a uSD log header ({len(data)} bytes)")
    if data[0] != MAGIC:
        raise UsdLogError(f"not a uSD log: magic byte 0x{data[0]:02X}, expected 0x{MAGIC:02X}")
    version, n_types = struct.unpack_from("<HH", data, 1)
    if version != VERSION:
        raise UsdLogError(f"uSD log format version {version} is not supported (only version {VERSION})")
    if n_types == 0:
        raise UsdLogError("bad header: the log declares no event types")
    i, types = 5, {}
    for _ in range(n_types):
        eid, i = _u16(data, i, "an event id")
        name, i = _cstring(data, i, "an event name")
        n_vars, i = _u16(data, i, f"the variable count of event {name!r}")
        variables = []
        for _ in range(n_vars):
            desc, i = _cstring(data, i, f"a variable of event {name!r}")
            if len(desc) < 4 or desc[-3] != "(" or desc[-1] != ")" or desc[-2] not in TYPE_CHARS:
                raise UsdLogError(f"bad header: variable {desc!r} of event {name!r} is not '<name>(<t>)' "
                                  f"with t in {TYPE_CHARS}")
            variables.append((desc[:-3], desc[-2]))
        if eid in types:
            raise UsdLogError(f"bad header: event id {eid} declared twice")
        if not name:
            raise UsdLogError(f"bad header: event id {eid} has an empty name")
        types[eid] = EventType(eid, name, tuple(variables))
    return version, types, i


def decode(data: bytes, allow_truncated: bool = False) -> UsdLog:
    """Decode the bytes of a uSD log file (see the module docstring)."""
    version, types, i = _header(data)
    crc_ok = len(data) >= i + 4 and zlib.crc32(data[:-4]) == struct.unpack_from("<I", data, len(data) - 4)[0]
    if not crc_ok and not allow_truncated:
        raise UsdLogError("CRC-32 mismatch: the file is truncated (logging not stopped cleanly) or corrupt; "
                          "allow_truncated keeps its complete entries")
    end = len(data) - 4 if crc_ok else len(data)
    rows: dict[int, list] = {eid: [] for eid in types}
    stamps: dict[int, list] = {eid: [] for eid in types}
    packers = {eid: et.struct for eid, et in types.items()}
    max_entry = _ENTRY_HEAD.size + max(pk.size for pk in packers.values())
    note, n, tail = "", 0, 0
    while i < end:
        if i + _ENTRY_HEAD.size > end:
            note = f"dropped {end - i} trailing bytes (an incomplete entry header) at byte {i}"
            tail = end - i
            break
        eid, stamp = _ENTRY_HEAD.unpack_from(data, i)
        if eid not in types:
            msg = f"unknown event id {eid} at byte {i}: the data section is corrupt"
            if not allow_truncated or crc_ok or end - i > max(TRUNCATION_TAIL, max_entry):
                raise UsdLogError(msg)  # (a truncation leaves at most a sector of garbage at the end)
            note = f"stopped at {msg}; dropped the last {end - i} bytes"
            break
        pk = packers[eid]
        if i + _ENTRY_HEAD.size + pk.size > end:
            msg = f"entry of event {types[eid].name!r} at byte {i} is cut off"
            if not allow_truncated or crc_ok:
                raise UsdLogError(msg)
            note = f"dropped an incomplete final entry: {msg}"
            break
        rows[eid].append(pk.unpack_from(data, i + _ENTRY_HEAD.size))
        stamps[eid].append(stamp)
        i += _ENTRY_HEAD.size + pk.size
        n += 1
    if not crc_ok and tail == 4:
        # entries that end exactly where a complete log keeps its CRC-32: this is a
        # complete file whose CRC does not match, i.e. corrupt data, not a truncation
        raise UsdLogError("CRC-32 mismatch in a complete file (its entries end where the CRC is): the data are "
                          "corrupt, not truncated, and allow_truncated does not apply")
    if not crc_ok:
        note = "no valid CRC (truncated file); " + (note or "all entries complete")
    events = {}
    for eid, et in types.items():
        cols = np.array(rows[eid], dtype=float).reshape(len(rows[eid]), len(et.variables))
        ev = {"timestamp_us": np.array(stamps[eid], dtype=np.uint64)}
        ev.update({name: cols[:, k] for k, (name, _) in enumerate(et.variables)})
        events[et.name] = ev
    return UsdLog(version, types, events, crc_ok, note, n)


FIXED_TICK = "tick"          # the original format's timestamp variable (microseconds)
_CRC_DONE = 0xFFFFFFFF       # CRC-32 of bytes + their stored (complemented) CRC


def is_fixed_format(data: bytes) -> bool:
    """True for the original fixed-frequency format (see the module docstring)."""
    if len(data) >= 3 and data[0] == MAGIC and struct.unpack_from("<H", data, 1)[0] == VERSION:
        return False
    return len(data) >= 2 and data[0] > 0 and (chr(data[1]).isalpha() or data[1] == ord("_"))


def _fixed_header(data: bytes) -> tuple[list[tuple[str, str]], int]:
    n, i, variables = data[0], 1, []
    for k in range(n):
        end = data.find(b",", i)
        if end < 0:
            raise UsdLogError(f"header truncated: variable {k} of {n} has no ',' terminator")
        try:
            desc = data[i:end].decode("ascii")
        except UnicodeDecodeError as e:
            raise UsdLogError(f"header corrupt: variable {k} at byte {i} is not ASCII") from e
        if len(desc) < 4 or desc[-3] != "(" or desc[-1] != ")" or desc[-2] not in TYPE_CHARS:
            raise UsdLogError(f"bad header: variable {desc!r} is not '<name>(<t>)' with t in {TYPE_CHARS}")
        variables.append((desc[:-3], desc[-2]))
        i = end + 1
    if i + 4 > len(data):
        raise UsdLogError("header truncated: no header CRC-32")
    if zlib.crc32(data[:i + 4]) != _CRC_DONE:
        raise UsdLogError("header CRC-32 mismatch: the header is corrupt")
    names = [v for v, _ in variables]
    if len(set(names)) != len(names):
        raise UsdLogError("bad header: a variable is declared twice")
    if FIXED_TICK not in names:
        raise UsdLogError(f"bad header: no '{FIXED_TICK}' variable (the records' timestamps)")
    return variables, i + 4


def decode_fixed(data: bytes, allow_truncated: bool = False) -> UsdLog:
    """Decode the original fixed-frequency format (see the module docstring)."""
    variables, i = _fixed_header(data)
    rec = struct.Struct("<" + "".join(t for _, t in variables))
    rows, blocks, note = [], 0, ""
    while i < len(data):
        k = data[i]
        end = i + 1 + k * rec.size
        if k == 0:
            raise UsdLogError(f"block {blocks} at byte {i}: zero records (corrupt data)")
        if end + 4 > len(data):
            msg = f"block {blocks} at byte {i} is cut off ({len(data) - i} of {end + 4 - i} bytes)"
            if not allow_truncated:
                raise UsdLogError(msg + "; allow_truncated keeps the complete blocks")
            note = f"no valid end (truncated file): dropped {msg}"
            break
        if zlib.crc32(data[i:end + 4]) != _CRC_DONE:
            raise UsdLogError(f"block {blocks} at byte {i}: CRC-32 mismatch (corrupt data)")
        rows.extend(rec.iter_unpack(data[i + 1:end]))
        blocks += 1
        i = end + 4
    cols = np.array(rows, dtype=float).reshape(len(rows), len(variables))
    ev = {name: cols[:, k] for k, (name, _) in enumerate(variables)}
    ev["timestamp_us"] = ev[FIXED_TICK].astype(np.uint64)
    et = EventType(FIXED_FREQUENCY_ID, FIXED_FREQUENCY_NAME, tuple(variables))
    return UsdLog(1, {FIXED_FREQUENCY_ID: et}, {FIXED_FREQUENCY_NAME: ev}, not note, note, len(rows))


def read(path: str | Path, allow_truncated: bool = False) -> UsdLog:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise UsdLogError(f"cannot read uSD log {path}: {e.strerror or e}") from e
    try:
        return (decode_fixed if is_fixed_format(data) else decode)(data, allow_truncated)
    except UsdLogError as e:
        raise UsdLogError(f"{path}: {e}") from e


@dataclass
class UsdLogWriter:
    """Builds a version-2 file in memory: declare event types, add entries, ``encode``."""

    types: list[EventType] = field(default_factory=list)
    _body: list[bytes] = field(default_factory=list)

    def declare(self, eid: int, name: str, variables) -> EventType:
        et = EventType(int(eid), name, tuple((str(n), str(t)) for n, t in variables))
        if any(t not in TYPE_CHARS for _, t in et.variables):
            raise ValueError(f"type characters must be in {TYPE_CHARS}")
        if any(x.id == et.id for x in self.types):
            raise ValueError(f"event id {eid} declared twice")
        self.types.append(et)
        return et

    def add(self, et: EventType, timestamp_us: int, values) -> None:
        self._body.append(_ENTRY_HEAD.pack(et.id, int(timestamp_us)) + et.struct.pack(*values))

    def add_many(self, et: EventType, timestamps_us, columns) -> None:
        """Entries of one event type from a [T] timestamp array and [T, n_vars] values."""
        for stamp, row in zip(np.asarray(timestamps_us), np.asarray(columns).tolist()):
            self.add(et, int(stamp), [int(round(x)) if t not in "fe" else x for x, (_, t) in zip(row, et.variables)])

    def encode(self, order_by_time: bool = True) -> bytes:
        head = [struct.pack("<BHH", MAGIC, VERSION, len(self.types))]
        for et in self.types:
            head.append(struct.pack("<H", et.id) + et.name.encode("ascii") + b"\0")
            head.append(struct.pack("<H", len(et.variables)))
            head.extend(f"{n}({t})".encode("ascii") + b"\0" for n, t in et.variables)
        body = self._body
        if order_by_time:  # a ring buffer writes entries in the order they were triggered
            body = sorted(body, key=lambda b: _ENTRY_HEAD.unpack_from(b)[1])
        data = b"".join(head) + b"".join(body)
        return data + struct.pack("<I", zlib.crc32(data))

    def write(self, path: str | Path) -> None:
        atomic_write_bytes(Path(path), self.encode())
