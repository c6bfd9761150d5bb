"""The firmware's compressed state log variables (crazyflie-firmware ``stabilizer.c``,
LOG group ``stateEstimateZ``, and ``quatcompress.h``) decoded to SI units.

``stateEstimateZ``: int16 position (mm), velocity (mm/s), acceleration (mm/s^2,
``az`` includes +1 g), body rates (milliradians/s); ``quat``: the attitude quaternion
(x, y, z, w) compressed by ``quatcompress`` into 32 bits: bits 31-30 the index of the
largest component (dropped, made positive), then for the other three in index order
a sign bit and a 9-bit magnitude of |q_i| / (1/sqrt 2).  ``quat_decompress`` is
``quatdecompress`` in float32 with the same operations in the same order (checked
bit for bit against the firmware's header compiled on the host, tests/test_real_logs.py).
"""
from __future__ import annotations

import numpy as np

_MASK = np.float32((1 << 9) - 1)
_SQRT1_2 = np.float32(0.70710678118654752440)   # (float)M_SQRT1_2


def quat_decompress(comp) -> np.ndarray:
    """[..., 4] float32 quaternions (x, y, z, w) from uint32 ``comp``, as quatdecompress."""
    c = np.asarray(comp, dtype=np.uint64).astype(np.uint32)
    largest = (c >> np.uint32(30)).astype(np.int64)
    q = np.zeros(c.shape + (4,), np.float32)
    sum_sq = np.zeros(c.shape, np.float32)
    rest = c.copy()
    for i in (3, 2, 1, 0):
        here = largest != i
        mag = (rest & np.uint32(0x1FF)).astype(np.float32)
        neg = ((rest >> np.uint32(9)) & np.uint32(1)).astype(bool)
        val = (_SQRT1_2 * mag) / _MASK                      # float32 multiply, then divide
        val = np.where(neg, -val, val).astype(np.float32)
        q[..., i] = np.where(here, val, q[..., i])
        sum_sq = np.where(here, (sum_sq + val * val).astype(np.float32), sum_sq)
        rest = np.where(here, rest >> np.uint32(10), rest)
    with np.errstate(invalid="ignore"):   # an invalid code (sum > 1) gives NaN, as sqrtf does
        big = np.sqrt((np.float32(1.0) - sum_sq).astype(np.float32)).astype(np.float32)
    np.put_along_axis(q, largest[..., None], big[..., None], axis=-1)
    return q


def state_si(ev: dict) -> dict:
    """SI arrays from the ``stateEstimateZ``/``ctrltargetZ`` columns of a log:
    p, v [T, 3] (m, m/s); q [T, 4] as (w, x, y, z); body rates w [T, 3] (rad/s, when
    logged; the pitch rate as logged: on the 16 June 2020 logs it has the sign of the
    logged attitude's own pitch rate, where stock firmware 2a18fc29's stabilizer.c logs
    ``-gyro.y``: tests/test_real_logs.py); setpoint p, v (when logged)."""
    axis = lambda grp, names, scale: np.stack([ev[f"{grp}.{n}"] for n in names], 1) * scale  # noqa: E731
    out = {"p": axis("stateEstimateZ", "xyz", 1e-3), "v": axis("stateEstimateZ", ("vx", "vy", "vz"), 1e-3)}
    xyzw = quat_decompress(ev["stateEstimateZ.quat"]).astype(np.float64)
    out["q"] = xyzw[:, [3, 0, 1, 2]]
    if all(f"stateEstimateZ.rate{n}" in ev for n in ("Roll", "Pitch", "Yaw")):
        out["w"] = axis("stateEstimateZ", ("rateRoll", "ratePitch", "rateYaw"), 1e-3)
    if all(f"ctrltargetZ.{n}" in ev for n in ("x", "y", "z", "vx", "vy", "vz")):
        out["setpoint_p"] = axis("ctrltargetZ", "xyz", 1e-3)
        out["setpoint_v"] = axis("ctrltargetZ", ("vx", "vy", "vz"), 1e-3)
    return out
