"""The simulator's flight logs as Crazyflie uSD-card files (format of
ns2codegen.logs.usdlog), one per robot, each on its own on-board clock, so that
simulated flights go through the real-flight path (logs -> alignment -> labels).

What a drone would write: the ``fixedFrequency`` event at 100 Hz with the
variables of ns2codegen.logs.timebase.VARIABLES (floats; motor PWM as uint16-range
integers in a uint32, like ``motor.m1``), timestamps in microseconds of a clock
that started at the robot's boot (a random 2-30 s before the synchronization
broadcast, which is the simulator's t = 0), scheduling jitter of up to
``jitter_us``, each log starting a random 0-15 samples late; and the
``ns2Sync`` event at the broadcast.  The ground truth stays out of the files.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ns2codegen.config import dump_toml
from ns2codegen.fileio import atomic_write_bytes
from ns2codegen.logs.timebase import PWM_FULL, SYNC_EVENT, VARIABLES
from ns2codegen.logs.usdlog import FIXED_FREQUENCY_ID, FIXED_FREQUENCY_NAME, UsdLogWriter

SYNC_ID = 7  # any id of the firmware's event-trigger table


def robot_usd(log: dict, i: int, rng: np.random.Generator, jitter_us: float = 150.0, sync: bool = True) -> bytes:
    """uSD file of robot ``i`` of a cloop flight log (arrays [T, N, ...])."""
    w = UsdLogWriter()
    ff = w.declare(FIXED_FREQUENCY_ID, FIXED_FREQUENCY_NAME,
                   [(n, "I" if k == "pwm" else "f") for k in VARIABLES for n in VARIABLES[k]])
    boot_s = rng.uniform(2.0, 30.0)
    first = int(rng.integers(0, 16))
    t = log["t"][first:]
    stamps = np.round((t + boot_s) * 1e6 + rng.uniform(-jitter_us, jitter_us, len(t))).astype(np.int64)
    cols = {"p": log["p"][first:, i], "v": log["v"][first:, i], "q": log["q"][first:, i],
            "pwm": np.round(log["pwm"][first:, i] * PWM_FULL), "battery_V": log["battery_V"][first:, i, None]}
    w.add_many(ff, stamps, np.concatenate([cols[k] for k in VARIABLES], axis=1))
    if sync:
        ev = w.declare(SYNC_ID, SYNC_EVENT, [("seq", "I")])
        w.add(ev, int(round(boot_s * 1e6)), [1])
    return w.encode()


def write_flight(folder: Path, name: str, team: list[str], log: dict, seed: int, sync: bool = True) -> dict:
    """Write one file per robot under ``folder/name/``; returns the flights.toml entry."""
    rng = np.random.default_rng(seed)
    sub = Path(folder) / name
    sub.mkdir(parents=True, exist_ok=True)
    robots = []
    for i, ty in enumerate(team):
        atomic_write_bytes(sub / f"cf{i}.usd", robot_usd(log, i, rng, sync=sync))
        robots.append({"file": f"{name}/cf{i}.usd", "type": ty.rstrip("*")})
    return {"name": name, "robots": robots}


def write_manifest(folder: Path, flights: list[dict], rate_hz: float = 100.0) -> None:
    atomic_write_bytes(Path(folder) / "flights.toml",
                       dump_toml({"rate_hz": rate_hz, "flight": flights}).encode())
