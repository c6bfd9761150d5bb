"""The planning model: the deep set ``ns2 plan`` plans with when it is given no
checkpoint, trained on the simulator's flights (ns2host.sim.collect) with the
config's interaction volumes, its data sets kept beside it and reused."""
from __future__ import annotations

import itertools
from pathlib import Path

from ns2codegen.config import Config


NEAR_FIELD_SECONDS = 600.0              # close-range passes per pair of types in default_checkpoint
NEAR_GAP_MAX = 1.5                      # m, largest vertical gap of the close-range passes in default_checkpoint
WHO_MOVES_SECONDS = 300.0               # one robot moving past the other, hovering one, per pair (issue 24)
WHO_BYSTANDER_SECONDS = 150.0           # the same with a third robot hovering nearby, per team of bystander_teams


def data_path(cfg: Config, folder: Path, flights: str, seed: int) -> Path:
    """Where default_checkpoint keeps a collected data set: named by its flights, the
    gaps, the seed and the config."""
    import hashlib

    tag = hashlib.sha256(cfg.to_json().encode()).hexdigest()[:10]
    return Path(folder) / f"data_{flights}_gap{NEAR_GAP_MAX:g}_seed{seed}_{tag}.npz"


def default_checkpoint(cfg: Config, folder: Path, seconds_per_team: float = 60.0, log=print,
                       near_field_seconds: float = NEAR_FIELD_SECONDS,
                       who_moves_seconds: float = WHO_MOVES_SECONDS,
                       who_bystander_seconds: float = WHO_BYSTANDER_SECONDS, workers: int = 1) -> Path:
    """A model of the simulator's interactions when none is given (or when the one in
    ``folder`` has another config or was trained on other flights): baseline flights of every team in the simulator
    (ns2 sim collect) plus close-range passes of every pair of types (the near-field
    downwash that the planner's plans fly through) and flights of one robot moving
    under and over the other, hovering one (who moves), alone and with a third robot
    hovering nearby (every pair with every type beside it), then training (ns2 train),
    with the config's interaction volumes (the one policy for control and planning,
    host/sim/volumes.py).  The collected data sets are kept in ``folder``
    (``data_*.npz``, named by their flights and the config) and reused; ``workers``
    flights are flown at once."""
    from ns2codegen.checkpoint import load_checkpoint, save_checkpoint
    from ns2codegen.data.analytic import downwash_dataset
    from ns2codegen.data.dataset import Dataset
    from ns2codegen.export import export
    from ns2codegen.train import train
    from ns2host.sim.collect import bystander_teams, collect

    pairs = list(itertools.combinations_with_replacement(cfg.robot_types, 2))
    sets = [(data_path(cfg, folder, f"base{seconds_per_team:g}s_near{near_field_seconds:g}s", 1),
             lambda: collect(cfg, folder / "boot_gen", seconds_per_team, seed=1, workers=workers,
                             near_field_seconds=near_field_seconds, near_gap_max=NEAR_GAP_MAX))]
    if who_moves_seconds > 0:
        sets.append((data_path(cfg, folder, f"who{who_moves_seconds:g}s", 2),
                     lambda: collect(cfg, folder / "boot_gen", 0.0, seed=2, team_list=pairs, workers=workers,
                                     who_moves_seconds=who_moves_seconds, near_gap_max=NEAR_GAP_MAX)))
    if who_bystander_seconds > 0:
        sets.append((data_path(cfg, folder, f"who3_{who_bystander_seconds:g}s", 3),
                     lambda: collect(cfg, folder / "boot_gen", 0.0, seed=3, team_list=bystander_teams(cfg),
                                     workers=workers, who_moves_seconds=who_bystander_seconds,
                                     near_gap_max=NEAR_GAP_MAX)))
    folder.mkdir(parents=True, exist_ok=True)
    ck = folder / "model.pt"
    if ck.is_file():
        old = load_checkpoint(ck)
        if old.cfg.to_json() == cfg.to_json() and old.meta.get("data_files") == [p.name for p, _ in sets]:
            return ck
    log(f"no checkpoint given: training the planning model on simulated flights ({seconds_per_team:.0f} s per "
        f"team, {near_field_seconds:.0f} s of close-range passes and {who_moves_seconds:.0f} s of who-moves "
        f"flights per pair, {who_bystander_seconds:.0f} s of them with a third robot beside per team of three) "
        f"into {ck}; this takes a while (about 0.65 CPU-s per simulated second of a pair's "
        f"flight); give --checkpoint to skip")
    if not all(p.is_file() for p, _ in sets):
        boot = downwash_dataset(cfg, 300, seed=0)       # the controller build needs some exported model
        m0, rep0 = train(cfg, boot, epochs=1)
        save_checkpoint(folder / "boot.pt", m0, cfg, {"seed": 0, "data_hash": boot.content_hash(), "report": rep0})
        export(folder / "boot.pt", folder / "boot_gen")
    parts, names = [], []
    for path, make in sets:
        if path.is_file():
            parts.append(Dataset.load(path, cfg.neighbor_types))
        else:
            parts.append(make())
            parts[-1].save(path)
        names.append(path.name)
    ds = Dataset.concat(parts) if len(parts) > 1 else parts[0]
    model, rep = train(cfg, ds)
    save_checkpoint(ck, model, cfg, {"seed": rep["seed"], "data_hash": ds.content_hash(), "report": rep,
                                     "data_files": names})
    return ck
