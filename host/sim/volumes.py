"""The interaction-volume policy, one for control and planning: the cuboid
V(type_i, type_j) of config/default.toml holds every relative position p_j - p_i
at which neighbour j's interaction force on robot i in the ground truth (aero.py)
reaches THRESHOLD_G, for a neighbour hovering or moving at up to NEIGHBOUR_SPEED;
vertically it reaches the whole flight space (FLIGHT_SPACE_Z), because a wake is
a turbulent jet whose speed falls only as 1 / depth (Bauersfeld et al., RA-L
2024) and the truth stays above the threshold there (its value at the top is
reported by ``report``).

THRESHOLD_G = 1.5 g: the paper neglects f_a,x and f_a,y, whose rms in its data
is 1.6 and 1.2 g ("much smaller ... do not significantly alter the nominal
dynamics"); an interaction below that is neglected alike.
"""
from __future__ import annotations

import numpy as np

from ns2codegen.config import Config

from .aero import calibrated
from .vehicle import G, vehicle

THRESHOLD_G = 1.5
NEIGHBOUR_SPEED = 0.5     # m/s: 93 % of the paper's data is slower ("7 % ... >= 0.5 m/s")
FLIGHT_SPACE_Z = 2.0      # m: the largest vertical separation of two robots in the flight space
STEP = 0.05               # m, grid of the reach computation


def _force_g(cfg: Config, robot: str, nbr: str, rel: np.ndarray, nbr_v: np.ndarray, z: float = 1.0) -> np.ndarray:
    """|f_z| (g) on a robot at height z from one neighbour at each relative position."""
    model = calibrated([vehicle(cfg, robot), vehicle(cfg, nbr)], vehicle(cfg, cfg.robot_types[0]))
    out = np.empty(len(rel))
    for k, (d, v) in enumerate(zip(rel, nbr_v)):
        p = np.array([[0.0, 0.0, z], [d[0], d[1], z + d[2]]])
        out[k] = abs(model.forces(p, np.array([[0.0, 0.0, 0.0], v]))[0, 2]) * 1000.0 / G
    return out


def _cases(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every point with the neighbour hovering and moving at NEIGHBOUR_SPEED along +-x, +-y."""
    vels = [np.zeros(3)] + [NEIGHBOUR_SPEED * np.array(d, float) for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0))]
    rel = np.concatenate([points] * len(vels))
    return rel, np.repeat(np.array(vels), len(points), axis=0)


def reach(cfg: Config, robot: str, nbr: str) -> dict:
    """Half-width (x = y), bottom and top (m) of the smallest symmetric cuboid that
    holds the relative positions where the truth reaches THRESHOLD_G (vertical
    plane through the neighbour's motion, which is the widest by symmetry)."""
    xs = np.arange(-1.5, 1.5 + 1e-9, STEP)
    zs = np.arange(-0.5, FLIGHT_SPACE_Z + 1e-9, 2 * STEP)
    X, Z = np.meshgrid(xs, zs)
    pts = np.column_stack([X.ravel(), np.zeros(X.size), Z.ravel()])
    vels = [np.zeros(3), np.array([NEIGHBOUR_SPEED, 0, 0]), np.array([-NEIGHBOUR_SPEED, 0, 0])]
    rel = np.concatenate([pts] * 3)
    v = np.repeat(np.array(vels), len(pts), axis=0)
    hit = rel[_force_g(cfg, robot, nbr, rel, v) >= THRESHOLD_G]
    return {"half_width": float(np.abs(hit[:, 0]).max()), "bottom": float(hit[:, 2].min()),
            "top": float(hit[:, 2].max())}


def edge_check(cfg: Config, robot: int, nbr: int, margin: float = STEP) -> dict:
    """The truth just outside the configured volume's sides and bottom (largest |f_z|, g)
    and at its top (the flight space's edge), neighbour hovering or moving at
    NEIGHBOUR_SPEED."""
    lo, hi = cfg.volume(robot, nbr)
    rt, nt = cfg.robot_types[robot], cfg.robot_types[nbr]
    zs = np.linspace(lo[2], hi[2], 12)
    side = [[hi[0] + margin, 0.0, z] for z in zs] + [[lo[0] - margin, 0.0, z] for z in zs] + \
           [[0.0, hi[1] + margin, z] for z in zs] + [[0.0, lo[1] - margin, z] for z in zs]
    bottom = [[x, y, lo[2] - margin] for x in np.linspace(lo[0], hi[0], 5) for y in np.linspace(lo[1], hi[1], 5)]
    top = [[0.0, 0.0, hi[2]]]
    out = {}
    for name, pts in (("side", side), ("bottom", bottom), ("top", top)):
        rel, v = _cases(np.array(pts, float))
        out[name] = float(_force_g(cfg, rt, nt, rel, v).max())
    return out


def report(cfg: Config | None = None) -> str:
    """Markdown: per (robot, neighbour) type the reach of the truth and the configured volume."""
    cfg = cfg or Config.load()
    lines = [f"| robot <- neighbour | reach at {THRESHOLD_G} g: half-width / bottom / top (m) | configured volume "
             "(m) | truth outside side / bottom (g) | truth at the top (g) |", "|---|---|---|---|---|"]
    for r, rt in enumerate(cfg.robot_types):
        for n, nt in enumerate(cfg.robot_types):
            rc, edge = reach(cfg, rt, nt), edge_check(cfg, r, n)
            lo, hi = cfg.volume(r, n)
            lines.append(f"| {rt} <- {nt} | {rc['half_width']:.2f} / {rc['bottom']:.2f} / {rc['top']:.2f} | "
                         f"{lo} .. {hi} | {edge['side']:.2f} / {edge['bottom']:.2f} | {edge['top']:.1f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(report())
