"""Planned trajectories in forms the Crazyflie can fly.

* Piecewise polynomials for the firmware's high-level commander
  (``crtp_commander_high_level``: trajectory upload to the trajectory memory, then
  ``define_trajectory`` with type POLY4D (0), offset and piece count, then
  ``start_trajectory``).  A piece is ``struct poly4d { float p[4][8]; float
  duration; }``: 8 coefficients (ascending powers of the time since the piece's
  start, in s) for x, y, z and yaw, then the duration, 33 float32 = 132 bytes
  little-endian, pieces back to back.  ``<robot>.bin`` holds those bytes;
  ``<robot>.csv`` the same pieces in Crazyswarm's text format
  ``Duration,x^0..x^7,y^0..y^7,z^0..z^7,yaw^0..yaw^7``.  A plan is a C^1 piecewise
  quadratic (dynamics.py), so one piece per planning step is exact; ``merge``
  pieces fits 7th-degree polynomials over several steps (position and velocity
  matched at both ends, least squares inside) to fit the trajectory memory.
* ``setpoints.csv``: time-stamped setpoints of every robot at a fixed rate
  (t, robot, type, p, v, a = planned acceleration, u = planned control, f_a,z-hat).

Checked against the public sources (the layout was written from these
descriptions, no code taken from them):
* bitcraze/crazyflie-firmware ``src/modules/interface/pptraj.h``: ``PP_DEGREE
  7``, ``PP_SIZE 8``, ``struct poly4d { float p[4][PP_SIZE]; float duration; }``
  (``__attribute__((packed))`` in current versions), coefficients "stored in
  ascending order, i.e. p[0] is the constant term"; ``src/modules/src/pptraj.c``
  evaluates them with Horner's rule in the time since the piece's start
  (``piecewise_eval``).
* bitcraze/crazyflie-firmware ``src/modules/src/crtp_commander_high_level.c``:
  ``#define TRAJECTORY_MEMORY_SIZE 4096`` ("4k allows us to store 31 poly4d
  pieces"; some versions define it in ``crtp_commander_high_level.h``), a write
  is accepted only if offset + length <= the memory size, the piece count of a
  definition is a ``uint8_t``; newer firmware reports the size at run time
  (``crtpCommanderHighLevelTrajectoryMemSize``, the memory element's size in
  cflib), so 4096 is the stock firmware's value, not a protocol constant.
* bitcraze/crazyflie-lib-python ``cflib/crazyflie/mem/trajectory_memory.py``:
  ``TrajectoryMemory.write_data`` packs per ``Poly4D`` the x, y, z, yaw values
  as eight ``<f`` each, then the duration as ``<f``, from address 0.
* USC-ACTLab/crazyswarm ``ros_ws/src/crazyswarm/scripts/uav_trajectory.py``
  (``Trajectory.loadcsv``): one header row, then duration, x[8], y[8], z[8],
  yaw[8] per row.
"""
from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np

from ns2codegen.fileio import atomic_write_bytes, atomic_write_files
from .dynamics import Trajectory

DEG = 7
POLY4D_BYTES = 4 * 8 * 4 + 4      # 33 float32
TRAJECTORY_MEMORY_BYTES = 4096     # stock crazyflie-firmware TRAJECTORY_MEMORY_SIZE
MAX_PIECES = TRAJECTORY_MEMORY_BYTES // POLY4D_BYTES    # 31 pieces of one trajectory at offset 0


def exact_pieces(traj: Trajectory, kappa: float) -> list[tuple[float, np.ndarray]]:
    """One piece per step: p(s) = p_k + v_k s + a_k s^2 / 2 (exact)."""
    a = traj.accel(kappa)
    out = []
    for k in range(traj.T):
        c = np.zeros((4, DEG + 1))
        c[:3, 0], c[:3, 1], c[:3, 2] = traj.p[k], traj.v[k], 0.5 * a[k]
        out.append((traj.dt, c))
    return out


def eval_pieces(pieces, t) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity [len(t), 3] of the piecewise polynomial (held at the end)."""
    t = np.atleast_1d(np.asarray(t, float))
    starts = np.concatenate([[0.0], np.cumsum([d for d, _ in pieces])])
    k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(pieces) - 1)
    s = np.clip(t - starts[k], 0.0, np.array([pieces[i][0] for i in k]))
    C = np.stack([pieces[i][1][:3] for i in k])                        # [n, 3, 8]
    pw = s[:, None] ** np.arange(DEG + 1)[None]
    dpw = np.concatenate([np.zeros((len(s), 1)), pw[:, :-1] * np.arange(1, DEG + 1)[None]], 1)
    return np.einsum("nad,nd->na", C, pw), np.einsum("nad,nd->na", C, dpw)


def merge_pieces(traj: Trajectory, kappa: float, steps_per_piece: int = 5, samples: int = 25):
    """Fewer, longer pieces: a 7th-degree polynomial per window of steps, equal to the
    plan's p and v at both ends (C^1 overall) and least-squares inside.
    Returns (pieces, max position error in m against the exact plan)."""
    exact = exact_pieces(traj, kappa)
    out, err = [], 0.0
    for k0 in range(0, traj.T, steps_per_piece):
        k1 = min(k0 + steps_per_piece, traj.T)
        D = (k1 - k0) * traj.dt
        s = np.linspace(0.0, D, samples)
        p_ref, _ = eval_pieces(exact, k0 * traj.dt + s)
        A = s[:, None] ** np.arange(DEG + 1)[None]
        E = np.zeros((4, DEG + 1))
        E[0, 0], E[1, 1] = 1.0, 1.0
        E[2] = D ** np.arange(DEG + 1)
        E[3, 1:] = np.arange(1, DEG + 1) * D ** np.arange(DEG)
        kkt = np.block([[2 * A.T @ A, E.T], [E, np.zeros((4, 4))]])
        c = np.zeros((4, DEG + 1))
        for a in range(3):
            f = [traj.p[k0, a], traj.v[k0, a], traj.p[k1, a], traj.v[k1, a]]
            c[a] = np.linalg.solve(kkt, np.concatenate([2 * A.T @ p_ref[:, a], f]))[:DEG + 1]
        err = max(err, float(np.abs(A @ c[:3].T - p_ref).max()))
        out.append((D, c))
    return out, err


def poly4d_bytes(pieces) -> bytes:
    """cflib TrajectoryMemory layout: x[8], y[8], z[8], yaw[8], duration (float32 LE)."""
    buf = io.BytesIO()
    for d, c in pieces:
        c = np.asarray(c, float)
        if c.shape != (4, DEG + 1) or not np.all(np.isfinite(c)) or not (np.isfinite(d) and d > 0):
            raise ValueError(f"a poly4d piece needs 4 x {DEG + 1} finite coefficients and a positive duration, "
                             f"got shape {c.shape}, duration {d}")
        buf.write(struct.pack("<32f", *c.ravel()))
        buf.write(struct.pack("<f", d))
    return buf.getvalue()


def read_poly4d(data: bytes):
    if len(data) % POLY4D_BYTES:
        raise ValueError("not a whole number of poly4d pieces")
    out = []
    for o in range(0, len(data), POLY4D_BYTES):
        vals = struct.unpack_from("<33f", data, o)
        out.append((vals[32], np.array(vals[:32], float).reshape(4, 8)))
    return out


def pieces_csv(pieces) -> str:
    head = ["Duration"] + [f"{ax}^{i}" for ax in ("x", "y", "z", "yaw") for i in range(DEG + 1)]
    lines = [",".join(head)]
    for d, c in pieces:
        lines.append(",".join([repr(float(d))] + [repr(float(x)) for x in np.asarray(c).ravel()]))
    return "\n".join(lines) + "\n"


def setpoints_csv(trajs: list, names: list, types: list, kappa, rate_hz: float = 100.0) -> str:
    lines = ["t_s,robot,type,x,y,z,vx,vy,vz,ax,ay,az,ux,uy,uz,fa_z_g"]
    for i, tr in enumerate(trajs):
        n_t = int(round(tr.T * tr.dt * rate_hz))
        t = np.arange(n_t + 1) / rate_hz
        k = np.minimum((t / tr.dt + 1e-9).astype(int), tr.T - 1)
        s = t - k * tr.dt
        a = tr.accel(float(kappa[i]))[k]
        p = tr.p[k] + tr.v[k] * s[:, None] + 0.5 * a * s[:, None] ** 2
        v = tr.v[k] + a * s[:, None]
        for n in range(len(t)):
            row = [f"{t[n]:.4f}", names[i], types[i]] + [f"{x:.6f}" for x in (*p[n], *v[n], *a[n], *tr.u[k[n]])]
            lines.append(",".join(row + [f"{tr.fa[k[n]]:.4f}"]))
    return "\n".join(lines) + "\n"


def write_plan(folder, trajs: list, types: list, kappa, steps_per_piece: int = 5, rate_hz: float = 100.0) -> dict:
    """Write <robot>.bin / <robot>.csv (polynomials) and setpoints.csv atomically;
    returns per robot the number of pieces, bytes and the polynomial fit error."""
    folder = Path(folder)
    names = [f"robot{i}_{t}" for i, t in enumerate(types)]
    texts, report = {}, {}
    bins = {}
    for i, tr in enumerate(trajs):
        pieces, err = merge_pieces(tr, float(kappa[i]), steps_per_piece)
        texts[names[i] + ".csv"] = pieces_csv(pieces)
        bins[names[i] + ".bin"] = poly4d_bytes(pieces)
        report[names[i]] = {"pieces": len(pieces), "bytes": len(bins[names[i] + ".bin"]),
                            "fits_trajectory_memory": len(pieces) <= MAX_PIECES,
                            "max_fit_error_m": err}
    texts["setpoints.csv"] = setpoints_csv(trajs, names, types, kappa, rate_hz)
    atomic_write_files(folder, texts)
    for name, data in bins.items():
        atomic_write_bytes(folder / name, data)
    return report
