"""Flight-test experiments of the paper, reproduced in the simulator with the
firmware controller in the loop: swaps "XY2Z" (robots X, Y above swap with Z
below, all vertically aligned once per swap), baseline (f_a = 0) vs the learned
feed-forward (NN), worst-case z error of the bottom robot per swap; plots like
the paper's flight-test figure (box plots), f_a predicted vs true over time, and
f_a,z heat maps of the exported model (learning-results figure)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ns2codegen.config import Config

from ns2host.sim.cloop import CLoopSwarm
from ns2host.sim.scenarios import intertwined_rings, swap
from ns2host.sim.vehicle import G

# case -> (robots from the bottom up); the bottom robot is the one measured
SWAP_CASES = {
    "S2S": ("small", "small"),
    "L2S": ("small", "large"),
    "SS2L": ("large", "small", "small"),
    "SL2S": ("small", "small", "large"),
    "LL2S": ("small", "large", "large"),
    "LL2S*": ("small*", "large", "large"),  # the small robot with stronger motors
}
SWAP_S, REST_S, SPACING_M, BOTTOM_M = 2.5, 0.5, 0.3, 0.5


def run_swaps(cfg: Config, gen_dir, case: str, learned: str | None, swaps: int = 6, seed: int = 0) -> dict:
    team = SWAP_CASES[case]
    heights = BOTTOM_M + SPACING_M * np.arange(len(team))
    sp, start = swap(len(team), heights, radius=0.4, duration=SWAP_S, rest=REST_S, seed=seed)
    sw = CLoopSwarm(cfg, list(team), gen_dir, start, aero=True, learned=learned)
    log = sw.run(swaps * (SWAP_S + REST_S), sp)
    period = SWAP_S + REST_S
    z_err = np.abs(log["p"][:, 0, 2] - log["p_d"][:, 0, 2])
    worst = [float(z_err[(log["t"] >= k * period) & (log["t"] < (k + 1) * period)].max()) for k in range(swaps)]
    return {"worst_z_error_m": worst, "log": log}


def heat_maps(cfg: Config, gen_dir, out: Path) -> None:
    """f_a,z of a small robot over (y, z) with hovering neighbours (paper, Fig. vis)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ns2host.cbuild import CModel
    from ns2codegen.queries import Queries

    c = CModel(gen_dir)
    ys, zs = np.linspace(-0.5, 0.5, 81), np.linspace(0.0, 1.0, 81)
    Y, Z = np.meshgrid(ys, zs)
    n = Y.size
    layouts = {"(a) environment only": [], "(b) small at (0, 0.5)": [("small", 0.0, 0.5)],
               "(c) large at (0, 0.5)": [("large", 0.0, 0.5)],
               "(e) large (-0.1, 0.5), small (0.1, 0.5)": [("large", -0.1, 0.5), ("small", 0.1, 0.5)]}
    fig, axes = plt.subplots(1, len(layouts), figsize=(4 * len(layouts), 3.6), sharey=True)
    for ax, (title, nbrs) in zip(axes, layouts.items()):
        p = np.column_stack([np.zeros(n), Y.ravel(), Z.ravel()]).astype(np.float32)
        s = max(len(nbrs), 1)
        types = np.zeros((n, s), np.uint8)
        rel = np.zeros((n, s, 6), np.float32)
        for k, (t, y, z) in enumerate(nbrs):
            types[:, k] = cfg.robot_types.index(t)
            rel[:, k, 1], rel[:, k, 2] = y - p[:, 1], z - p[:, 2]
        q = Queries(np.zeros(n, np.uint8), p, np.zeros((n, 3), np.float32), np.full(n, len(nbrs)), types, rel)
        f, _ = c.predict(q, fixed=False)
        im = ax.pcolormesh(Y, Z, f.reshape(Y.shape), cmap="RdBu", vmin=-20, vmax=20, shading="auto")
        for t, y, z in nbrs:
            ax.plot(y, z, "k^" if t == "large" else "kv", markersize=10 if t == "large" else 6)
        ax.axhline(0.0, color="k", ls="--", lw=0.8)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("y (m)")
    axes[0].set_ylabel("z (m)")
    fig.colorbar(im, ax=axes, label="predicted f_a,z (g)")
    fig.savefig(out / "fa_heatmaps.png", dpi=110)
    plt.close(fig)


def swap_experiments(cfg: Config, gen_dir, out_dir, swaps: int = 6, cases=None, learned: str = "fixed") -> dict:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cases = list(cases or SWAP_CASES)
    results, logs = {}, {}
    for case in cases:
        bl = run_swaps(cfg, gen_dir, case, None, swaps)
        nn = run_swaps(cfg, gen_dir, case, learned, swaps)
        results[case] = {"BL": bl["worst_z_error_m"], "NN": nn["worst_z_error_m"],
                         "BL_median_m": float(np.median(bl["worst_z_error_m"])),
                         "NN_median_m": float(np.median(nn["worst_z_error_m"]))}
        results[case]["improvement"] = results[case]["BL_median_m"] / max(results[case]["NN_median_m"], 1e-9)
        logs[case] = nn["log"]
    (out / "swaps.json").write_text(json.dumps(results, indent=2) + "\n")
    lines = ["| case | BL median worst z error (cm) | NN (cm) | BL / NN |", "|---|---|---|---|"]
    for case, r in results.items():
        lines.append(f"| {case} | {100 * r['BL_median_m']:.1f} | {100 * r['NN_median_m']:.1f} | {r['improvement']:.2f} |")
    (out / "swaps.md").write_text("\n".join(lines) + "\n")
    # box plots per case, BL vs NN (paper's flight-test figure)
    fig, ax = plt.subplots(figsize=(1.8 * len(cases) + 2, 3.5))
    data, labels = [], []
    for case in cases:
        data += [np.array(results[case]["BL"]) * 100, np.array(results[case]["NN"]) * 100]
        labels += [f"{case}\nBL", f"{case}\nNN"]
    ax.boxplot(data)
    ax.set_xticks(range(1, len(labels) + 1), labels)
    ax.set_ylabel("worst-case z error (cm)")
    fig.tight_layout()
    fig.savefig(out / "swaps_boxplot.png", dpi=110)
    plt.close(fig)
    # f_a predicted vs true over time, bottom robot of the first case
    log = logs[cases[0]]
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.plot(log["t"], log["truth_fa"][:, 0, 2] * 1000 / G, label="true f_a,z")
    ax.plot(log["t"], log["fa_hat"][:, 0, 2] * 1000 / G, label="predicted (on board)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("g")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "fa_over_time.png", dpi=110)
    plt.close(fig)
    heat_maps(cfg, gen_dir, out)
    return results


# name -> robots of the paper's intertwined rings (host/sim/scenarios.py): vertical
# rings of S* robots linked with a horizontal ring; the paper reports the "small*"
# robots' maximum z error (5 robots: 10 -> 5 cm, 16 robots: 15 -> 10 cm)
RING_CASES = {"5-robot rings": 5, "16-robot three rings": 16}


def ring_experiments(cfg: Config, gen_dir, out_dir, duration: float = 16.0, learned: str = "fixed") -> dict:
    """Worst-case z error of every robot, BL vs NN, mean and max per type."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, robots in RING_CASES.items():
        team, sp, start, _ = intertwined_rings(robots)
        res = {}
        for mode in (None, learned):
            log = CLoopSwarm(cfg, team, gen_dir, start, aero=True, learned=mode).run(duration, sp)
            late = log["t"] > 2.0
            worst = np.abs(log["p"][late, :, 2] - log["p_d"][late, :, 2]).max(axis=0)
            res["BL" if mode is None else "NN"] = {
                kind: {"mean_worst_z_error_m": float(worst[[t == kind for t in team]].mean()),
                       "max_worst_z_error_m": float(worst[[t == kind for t in team]].max())}
                for kind in sorted(set(team))}
        results[name] = res
    (out / "rings.json").write_text(json.dumps(results, indent=2) + "\n")
    lines = ["| experiment | robot type | BL mean / max worst z error (cm) | NN (cm) |", "|---|---|---|---|"]
    for name, res in results.items():
        for kind in res["BL"]:
            b, n = res["BL"][kind], res["NN"][kind]
            lines.append(f"| {name} | {kind} | {100 * b['mean_worst_z_error_m']:.1f} / {100 * b['max_worst_z_error_m']:.1f}"
                         f" | {100 * n['mean_worst_z_error_m']:.1f} / {100 * n['max_worst_z_error_m']:.1f} |")
    (out / "rings.md").write_text("\n".join(lines) + "\n")
    return results
