"""The planning experiment's tables and figures: the model against the simulator's
truth where the planner exploits it, the results per case and planner, where the
planning time goes, and the paper's figures."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ns2codegen.config import Config
from ns2codegen.fileio import atomic_write_bytes
from ns2plan.forces import ForceModel
from ns2plan.problem import GRAMS_TO_N, Problem

from .cases import HEIGHT


CHECK_GAPS = (0.15, 0.3, 0.5, 1.0, 1.4)      # m, vertical gaps of downwash_check


def downwash_check(cfg: Config, fm: ForceModel, gaps=CHECK_GAPS, z: float = HEIGHT) -> list[dict]:
    """The model against the simulator's ground truth (host/sim/aero.py) where the
    planner exploits it: a robot hovering at height z directly under another hovering
    robot, for every (lower, upper) type pair and vertical gap; predicted and true
    f_a,z of the lower robot in grams."""
    from ns2host.sim.aero import calibrated
    from ns2host.sim.vehicle import vehicle

    rows = []
    for lower in cfg.robot_types:
        for upper in cfg.robot_types:
            truth = calibrated([vehicle(cfg, lower), vehicle(cfg, upper)], vehicle(cfg, cfg.robot_types[0]))
            types = [cfg.robot_types.index(lower), cfg.robot_types.index(upper)]
            for gap in gaps:
                P = np.array([[0.0, 0.0, z], [0.0, 0.0, z + gap]])
                true_g = float(truth(P, np.zeros((2, 3)))[0, 2] / GRAMS_TO_N)
                pred_g = float(fm.team_np(types, P[None], np.zeros((1, 2, 3)))[0, 0])
                rows.append({"lower": lower, "upper": upper, "gap_m": float(gap), "predicted_g": pred_g,
                             "true_g": true_g})
    return rows


def downwash_table(rows: list[dict]) -> str:
    gaps = sorted({r["gap_m"] for r in rows})
    lines = ["| lower robot under | " + " | ".join(f"{g:.2f} m" for g in gaps) + " |",
             "|---|" + "---|" * len(gaps)]
    pairs = list(dict.fromkeys((r["lower"], r["upper"]) for r in rows))
    for lower, upper in pairs:
        cells = [f"{r['predicted_g']:.1f} / {r['true_g']:.1f}" for r in rows
                 if (r["lower"], r["upper"]) == (lower, upper)]
        lines.append(f"| {lower} under {upper} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table(results: dict) -> str:
    """Markdown: per case and planner the trials planned and within every force limit in
    flight, tracking errors, the worst true force per robot type, planning times, and
    the flown states over a limit with those where the model at the flown state was
    within the planning bound (unforeseen; meaningless for BL, which plans with f_a = 0)."""
    lines = ["| case | planner | planned | within the limits in flight | worst tracking error median / max (cm) | "
             "worst f_a small: max (limit 5 g), trials over | worst f_a large: max (limit 10 g), trials over | "
             "Stage 1 / Stage 2 s per robot | flown states over the limit / of them within the bound |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, res in results.items():
        for mode in [m for m in ("BL", "NN") if m in res]:
            s = res[mode]["summary"]
            if not s.get("planned"):
                lines.append(f"| {key} | {mode} | 0/{s['trials']} | - | - | - | - | - | - |")
                continue
            cells = []
            for kind in ("small", "large"):
                cells.append(f"{s[kind]['max_worst_fa_g']:.1f} g, {s[kind]['trials_over_limit']}/{s['planned']}"
                             if kind in s else "-")
            kinds = [s[k] for k in ("small", "large") if k in s]
            over = sum(k["over_limit_states"] for k in kinds)
            in_bound = "-" if mode == "BL" else sum(k["over_limit_in_bound_states"] for k in kinds)
            lines.append(f"| {key} | {mode} | {s['planned']}/{s['trials']} | "
                         f"{s['planned'] - s['trials_any_over_limit']}/{s['planned']} | "
                         f"{100 * s['median_worst_error_m']:.1f} / {100 * s['max_worst_error_m']:.1f} | {cells[0]} | "
                         f"{cells[1]} | {s['stage1_s_per_robot']:.1f} / {s['stage2_s_per_robot']:.1f} | "
                         f"{over} / {in_bound} |")
    return "\n".join(lines)


PROFILE_COLUMNS = (("stage1_s", "Stage 1 s"), ("stage1_joint_s", "of it composite search s"),
                   ("stage1_samples", "Stage 1 samples"), ("stage2_s", "Stage 2 s"), ("scp_iterations", "SCP iterations"),
                   ("convex_solves", "convex solves"), ("cp_build_s", "build s"), ("cp_canon_s", "cvxpy canon s"),
                   ("cp_solver_s", "solver s"), ("force_calls", "force calls"), ("force_forward_s", "force forward s"),
                   ("force_backward_s", "force Jacobian backward s"))


def profile_table(results: dict) -> str:
    """Markdown: per dimension and planner the mean of every planned trial's profile
    (PlanResult.profile; Stage 2's build time includes the force Jacobians)."""
    lines = ["| dims | planner | trials | " + " | ".join(h for _, h in PROFILE_COLUMNS) + " |",
             "|---|---|---|" + "---|" * len(PROFILE_COLUMNS)]
    groups = {}
    for key, res in results.items():
        for mode, r in res.items():
            groups.setdefault((key.split()[0], mode), []).extend(t["profile"] for t in r["trials"] if t["error"] is None)
    for (dims, mode), profs in sorted(groups.items()):
        if profs:
            cells = [np.mean([p[k] for p in profs]) for k, _ in PROFILE_COLUMNS]
            lines.append(f"| {dims} | {mode} | {len(profs)} | "
                         + " | ".join(f"{c:.0f}" if c >= 100 else f"{c:.2f}" for c in cells) + " |")
    return "\n".join(lines)


def _save(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())


COLORS = ["tab:blue", "tab:orange", "tab:green"]


def example_figure(pb: Problem, examples: dict, path: Path) -> None:
    """Paper's Fig. plot2: yz plots (NN Stage 1 with the tree coloured by |f_a|; NN
    SCP (dashed) and tracked (solid); BL planned (dashed) and tracked), and the true
    interaction forces over time with the limits (dashed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(2, 3, figsize=(14, 7))
    nn, nn_log = examples["NN"]
    bl, bl_log = examples["BL"]
    ax = axes[0, 0]
    lc = None                                   # no tree when the composite search (joint.py) planned the team
    for i, tree in enumerate(nn.stage1.trees):
        if tree is None or tree.n < 2:
            continue
        child = np.arange(1, tree.n)
        segs = np.stack([tree.p[tree.parent[child]][:, 1:], tree.p[child][:, 1:]], 1)
        lc = LineCollection(segs, cmap="viridis", linewidths=0.4, alpha=0.5)
        lc.set_array(np.abs(tree.fa[child]))
        lc.set_clim(0, 15)
        ax.add_collection(lc)
        if tree.rejected:
            rej = np.array([[a[1:], b[1:]] for a, b in tree.rejected[:500]])
            ax.add_collection(LineCollection(rej, colors="tab:red", linewidths=0.4, alpha=0.4))
    if lc is not None:
        fig.colorbar(lc, ax=ax, label="|f_a,z-hat| at tree node (g)")
    for i, tr in enumerate(nn.stage1.trajs):
        ax.plot(tr.p[:, 1], tr.p[:, 2], color=COLORS[i], lw=2, label=f"{i}: {pb.robots[i].type}")
    ax.set_title("NN, Stage 1 (tree by |f_a|, red: rejected by a neighbour's force)", fontsize=8)
    ax.legend(fontsize=7)
    for ax, (res, lg, title) in zip(axes[0, 1:], ((nn, nn_log, "NN: SCP (dashed), tracked (solid)"),
                                                   (bl, bl_log, "BL: planned (dashed), tracked (solid)"))):
        for i, tr in enumerate(res.trajs):
            ax.plot(tr.p[:, 1], tr.p[:, 2], "--", color=COLORS[i])
            ax.plot(lg["truth_p"][:, i, 1], lg["truth_p"][:, i, 2], "-", color=COLORS[i], lw=1)
            mid = tr.T // 2
            ax.add_patch(plt.Circle((tr.p[mid, 1], tr.p[mid, 2]), pb.radius()[i], fill=False, color=COLORS[i]))
        ax.set_title(title, fontsize=8)
    for ax in axes[0]:
        ax.set_xlabel("y (m)")
        ax.set_ylabel("z (m)")
        ax.set_aspect("equal")
        ax.set_xlim(-1.0, 1.0)
        ax.set_ylim(0.2, 2.1)
    for ax, (res, lg) in zip(axes[1], ((nn, None), (nn, nn_log), (bl, bl_log))):
        for i in range(pb.n):
            if lg is None:
                tr = res.stage1.trajs[i]
                ax.plot(tr.t, tr.fa, color=COLORS[i])
                ax.set_title("planned f_a,z-hat (Stage 1, NN)", fontsize=8)
            else:
                ax.plot(lg["t"], lg["truth_fa"][:, i, 2] / GRAMS_TO_N, color=COLORS[i])
                ax.set_title("true f_a,z in the simulator", fontsize=8)
            ax.axhline(-pb.fa_max()[i], ls="--", color=COLORS[i], lw=0.8)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("g")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def summary_figure(results: dict, path: Path) -> None:
    """Paper's Fig. plot3: worst tracking error and worst force per type, BL vs NN."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(results)
    fig, axes = plt.subplots(3, 1, figsize=(max(6, 1.3 * len(keys)), 8), sharex=True)
    for k, key in enumerate(keys):
        for m, (mode, color) in enumerate((("BL", "tab:red"), ("NN", "tab:blue"))):
            if mode not in results[key]:
                continue
            ok = [t for t in results[key][mode]["trials"] if t["error"] is None]
            x = k + (m - 0.5) * 0.3
            axes[0].scatter([x] * len(ok), [100 * max(t["track"]["worst_error_m"]) for t in ok], color=color, s=12,
                            label=mode if k == 0 else None)
            for row, kind in ((1, "small"), (2, "large")):
                vals = []
                for t in ok:
                    vals += [f for f, ty in zip(t["track"]["worst_fa_g"], t["types"]) if ty == kind]
                axes[row].scatter([x] * len(vals), vals, color=color, s=12)
    axes[0].set_ylabel("worst tracking error (cm)")
    axes[0].legend()
    for row, (kind, lim) in ((1, ("small", 5.0)), (2, ("large", 10.0))):
        axes[row].axhline(lim, color="r", lw=1)
        axes[row].set_ylabel(f"worst |f_a| {kind} (g)")
    axes[2].set_xticks(range(len(keys)), keys, rotation=30)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
