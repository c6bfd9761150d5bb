"""The ground truth (aero.py) against every quantitative point the paper gives about
the interactions themselves, point by point with the relative error; printed by
``python -m ns2host.sim.calibration`` (Markdown; ``--json FILE`` writes the result docs/ground-truth.md's
tables are made of) and checked by tests/test_aero.py.

Two points are fitted (the wake's spreading rate and the ground-effect radius); the
others are predictions of the physics.  Points the paper states only in words get
a measured number and the check that the words hold (no relative error).
Experiment results (swaps, rings, planning) are never calibration points."""
from __future__ import annotations

import sys

import numpy as np

from ns2codegen.config import Config

from .aero import DOWNWASH_POINT, GROUND_POINT, calibrated
from .vehicle import G, STRONG, vehicle

# Fig. vis (g): the paper does not state the layout of its three small neighbours;
# assumed: two side by side at z = 0.5 m (y = -0.1, 0.1), one above at (0, 0.7).
VIS_G_LAYOUT = (("small", -0.1, 0.5), ("small", 0.1, 0.5), ("small", 0.0, 0.7))
VIS_G_ALTERNATIVES = ((("small", -0.2, 0.5), ("small", 0.0, 0.5), ("small", 0.2, 0.5)),
                      (("small", 0.0, 0.5), ("small", 0.0, 0.75), ("small", 0.0, 1.0)),
                      (("small", -0.15, 0.4), ("small", 0.15, 0.4), ("small", 0.0, 0.8)))
GRID_Y, GRID_Z = np.linspace(-0.5, 0.5, 41), np.linspace(0.02, 1.0, 50)   # the heat maps' (y, z) plane


class Probe:
    """f_a,z (g) of a small robot at (0, y, z) with neighbours [(type, y, z)], the
    ground truth with the ground (or in free air), neighbours hovering unless
    ``nbr_v`` gives their velocities."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.small = vehicle(cfg, cfg.robot_types[0])

    def fz(self, nbrs, y, z, ground: bool = True, nbr_v=None, v=None) -> np.ndarray:
        y, z = np.atleast_1d(np.asarray(y, float)), np.atleast_1d(np.asarray(z, float))
        model = calibrated([self.small] + [vehicle(self.cfg, t) for t, _, _ in nbrs], self.small)
        vel = np.zeros((len(nbrs) + 1, 3))
        if nbr_v is not None:
            vel[1:] = nbr_v
        if v is not None:
            vel[0] = v
        out = np.empty(len(y))
        for k in range(len(y)):
            p = np.array([[0.0, y[k], z[k]]] + [[0.0, a, b] for _, a, b in nbrs])
            out[k] = model.forces(p, vel, ground=ground)[0, 2] * 1000.0 / G
        return out


def superposition_gap(probe: Probe, nbrs) -> tuple[float, float, float]:
    """Largest |truth - ((a) + sum of (b))| over the heat-map plane, away (>= D) from
    the neighbours: (a) the robot alone over the ground, (b) each neighbour alone in
    free air (the paper's rho(phi_env) + sum rho(phi_s)).  Returns (gap, y, z)."""
    Y, Z = np.meshgrid(GRID_Y, GRID_Z)
    y, z = Y.ravel(), Z.ravel()
    ok = np.ones(y.size, bool)
    for _, a, b in nbrs:
        ok &= np.hypot(y - a, z - b) >= probe.small.diameter
    y, z = y[ok], z[ok]
    full = probe.fz(nbrs, y, z)
    sup = probe.fz([], y, z) + sum(probe.fz([n], y, z, ground=False) for n in nbrs)
    k = int(np.argmax(np.abs(full - sup)))
    return float(abs(full - sup)[k]), float(y[k]), float(z[k])


def heat_map_change(probe: Probe, nbr, speed: float) -> float:
    """max |moving - hovering| / max |hovering| of the heat map with one neighbour
    moving at ``speed`` along y (Fig. vis (c) vs (d))."""
    Y, Z = np.meshgrid(GRID_Y[::2], GRID_Z[::2])
    y, z = Y.ravel(), Z.ravel()
    ok = np.hypot(y - nbr[1], z - nbr[2]) >= probe.small.diameter
    still = probe.fz([nbr], y[ok], z[ok])
    moving = probe.fz([nbr], y[ok], z[ok], nbr_v=[[0.0, speed, 0.0]])
    return float(np.abs(moving - still).max() / np.abs(still).max())


def calibration_table(cfg: Config | None = None) -> list[dict]:
    """Rows: point, paper value, simulator value, relative error (None for points in
    words), tolerance of the check, whether fitted, and ``ok``."""
    cfg = cfg or Config.load()
    pr = Probe(cfg)
    rows = []

    def row(point, paper, sim, tol, fitted=False, ok=None, note=""):
        rel = None if paper is None else (sim - paper) / abs(paper)
        if ok is None:
            ok = abs(rel) <= tol
        rows.append({"point": point, "paper": paper, "sim": float(sim), "rel_error": rel, "tolerance": tol,
                     "fitted": fitted, "ok": bool(ok), "note": note})

    gap, target = DOWNWASH_POINT
    row(f"small {gap} m under a hovering small robot, f_z (g) [intro]", target,
        pr.fz([("small", 0.0, 1.0 + gap)], 0.0, 1.0)[0], 0.02, fitted=True)
    z, ge = GROUND_POINT
    row(f"small robot alone at z = {z} m, f_z (g) [Fig. vis (a)]", ge, pr.fz([], 0.0, z)[0], 0.02, fitted=True)
    row("small at (0, 0.3), large (-0.1, 0.5), small (0.1, 0.5), f_z (g) [Fig. vis (e)]", -10.0,
        pr.fz([("large", -0.1, 0.5), ("small", 0.1, 0.5)], 0.0, 0.3)[0], 0.3)
    g, gy, gz = superposition_gap(pr, VIS_G_LAYOUT)
    row("three small neighbours: max |truth - ((a) + 3 (b))| (g) [Fig. vis (g), layout assumed]", 11.4, g, 0.5,
        note=f"at y = {gy:.2f}, z = {gz:.2f} m; other layouts: " +
        ", ".join(f"{superposition_gap(pr, alt)[0]:.1f}" for alt in VIS_G_ALTERNATIVES))
    near = pr.fz([("small", 0.0, 0.5)], 0.0, 0.05) - pr.fz([], 0.0, 0.05)
    far = pr.fz([("small", 0.0, 1.5)], 0.0, 1.05) - pr.fz([], 0.0, 1.05)
    ratio = float(near[0] / far[0])
    row("downwash 0.45 m under a small robot at z = 0.05 m / the same pair in free air [Fig. vis (b): "
        "'mitigated' near the ground]", None, ratio, "< 0.8", ok=ratio < 0.8)
    change = heat_map_change(pr, ("large", 0.0, 0.5), 0.8)
    row("large neighbour at (0, 0.5) moving at 0.8 m/s: max heat-map change / peak [Fig. vis (c) vs (d): "
        "'significantly different']", None, change, ">= 0.2", ok=change >= 0.2)
    big = pr.fz([("large", 0.0, 0.5)], 0.0, 0.3)[0] / pr.fz([("small", 0.0, 0.5)], 0.0, 0.3)[0]
    row("f_z 0.2 m under a large / under a small robot [Fig. vis (e): 'significantly higher']", None, big,
        "> 1.15", ok=big > 1.15)
    small = vehicle(cfg, cfg.robot_types[0])
    row("S* best-case thrust-to-weight ratio [flight tests]", 2.6, small.f_max * 4 * STRONG / (small.mass * G), 0.02)
    return rows


def markdown(rows: list[dict]) -> str:
    """The calibration rows as a Markdown table (a ``|`` in a point's text escaped)."""
    lines = ["| point | paper | simulator | rel. error | tolerance | |", "|---|---|---|---|---|---|"]
    for r in rows:
        paper = "in words" if r["paper"] is None else f"{r['paper']:g}"
        rel = "" if r["rel_error"] is None else f"{100 * r['rel_error']:+.1f} %".replace("-0.0 %", "0.0 %")
        tol = r["tolerance"] if isinstance(r["tolerance"], str) else f"{100 * r['tolerance']:.0f} %"
        tag = ("fitted" if r["fitted"] else "predicted") + ("" if r["ok"] else ", OUT OF TOLERANCE")
        note = f" ({r['note']})" if r["note"] else ""
        point = f"{r['point']}{note}".replace("|", "\\|")
        lines.append(f"| {point} | {paper} | {r['sim']:.2f} | {rel} | {tol} | {tag} |")
    return "\n".join(lines) + "\n"


def gap_rows(cfg: Config | None = None, gaps=(0.1, 0.2, 0.3, 0.5, 1.0, 1.5, 2.0)) -> dict:
    """f_z (g) of a hovering robot at z = 1 m under a hovering neighbour, per gap (m):
    {"gaps_m": [...], "rows": [{"lower", "upper", "f_z_g": [one per gap]}]}."""
    cfg = cfg or Config.load()
    small = vehicle(cfg, cfg.robot_types[0])
    rows = []
    for lo in cfg.robot_types:
        for up in cfg.robot_types:
            m = calibrated([vehicle(cfg, lo), vehicle(cfg, up)], small)
            rows.append({"lower": lo, "upper": up, "f_z_g": [
                float(m.forces(np.array([[0, 0, 1.0], [0, 0, 1.0 + g]]), np.zeros((2, 3)))[0, 2] * 1000 / G)
                for g in gaps]})
    return {"gaps_m": list(gaps), "rows": rows}


def gap_markdown(doc: dict) -> str:
    lines = ["| lower under upper | " + " | ".join(f"{g} m" for g in doc["gaps_m"]) + " |",
             "|---|" + "---|" * len(doc["gaps_m"])]
    for r in doc["rows"]:
        lines.append(f"| {r['lower']} under {r['upper']} | " + " | ".join(f"{c:.1f}" for c in r["f_z_g"]) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Print both tables; with ``--json FILE`` also write them as a result (the rows and
    the gap table, stamped with the commit and command: docs/ground-truth.md's tables,
    ``make results``)."""
    import argparse
    import json
    from pathlib import Path

    from ns2codegen.fileio import atomic_write_bytes
    from ns2codegen.results import command_line, stamp

    ap = argparse.ArgumentParser(prog="python -m ns2host.sim.calibration", description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=None, help="also write the tables as a stamped JSON result here")
    args = ap.parse_args(argv)
    rows, gaps = calibration_table(), gap_rows()
    print(markdown(rows))
    print(gap_markdown(gaps))
    if args.json is not None:
        command = command_line(None if argv is None else ["", *argv], prog=ap.prog)
        doc = stamp({"points": rows, "gap_table": gaps}, command)
        try:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(args.json, (json.dumps(doc, indent=1) + "\n").encode())
        except OSError as e:
            print(f"{args.json}: cannot write ({e.strerror or e})", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
