"""Analytic stand-ins for flight data: known functions the deep set must learn.

* ``scenario_mixes``: the type mixes of Table "data_collection" (for K robot
  types: every robot type with 0, 1 or 2 robot neighbours of any types; K = 2
  gives exactly the paper's 12 scenarios).
* ``downwash_dataset``: a smooth analytic downwash + ground-effect + drag model
  (NOT the simulator's ground truth, which is a separate module): a small robot
  0.3 m under another small one feels about -9 g, a large neighbour about twice
  that, a small robot at z = 0.05 m about +5 g of ground effect.
* ``max_dataset``: the paper's 2-group example h = max(x1, x2) + 2 max(y1, y2).
"""
from __future__ import annotations

import itertools

import numpy as np

from ..config import Config, ConfigError
from .dataset import Dataset, scenario_name

G_SMALL_UNDER_SMALL = 9.0  # g, downwash 0.3 m under a small robot (paper, Fig. "vis")
GROUND_AT_5CM = 5.0        # g, ground effect on a small robot at z = 0.05 m
NEAR_LO, NEAR_HI = np.array([-0.4, -0.4, -0.4]), np.array([0.4, 0.4, 1.2])  # m, neighbours drawn here


def scenario_mixes(cfg: Config, max_neighbors: int = 2) -> list[tuple[int, tuple[int, ...], str]]:
    """[(robot type, neighbour robot types, name)] in the paper's order."""
    names = cfg.robot_types
    out = []
    for r in range(cfg.num_robot_types):
        for n in range(max_neighbors + 1):
            for mix in itertools.combinations_with_replacement(range(cfg.num_robot_types), n):
                out.append((r, mix, scenario_name(names, names[r], [names[m] for m in mix])))
    return out


def analytic_fa_z(cfg: Config, robot_type, sample_of, nbr_type, nbr_state) -> np.ndarray:
    """f_a,z in grams of each sample from its CSR neighbour rows (environment included)."""
    n = robot_type.shape[0]
    masses = np.array([cfg.vehicle(t)["mass_g"] for t in cfg.robot_types])
    diam = np.array([cfg.vehicle(t).get("diameter_m", 0.12) for t in cfg.robot_types])
    is_env = nbr_type == cfg.env_index
    # robot's own height and velocity from its environment row (x_ij = [-p_i; -v_i])
    z = np.zeros(n)
    vz = np.zeros(n)
    z[sample_of[is_env]] = np.maximum(-nbr_state[is_env, 2], 0.0)
    vz[sample_of[is_env]] = -nbr_state[is_env, 5]
    recv = diam[robot_type] / 0.12
    # ground effect, a Cheeseman-Bennett-like 1 / (1 + (z/z0)^2) profile, plus vertical drag
    f = recv * GROUND_AT_5CM * (1 + (0.05 / 0.04) ** 2) / (1.0 + (z / 0.04) ** 2) - 0.8 * vz
    # downwash from neighbours above: a Gaussian plume widening with height difference,
    # advected by the relative horizontal velocity, mitigated close to the ground
    rob = ~is_env
    s = nbr_state[rob].astype(np.float64)
    dz = s[:, 2]
    above = np.clip(dz, 0.0, None)
    xy = s[:, 0:2] - 0.25 * s[:, 3:5] * above[:, None]
    width = 0.04 + 0.12 * above
    amp = G_SMALL_UNDER_SMALL * masses[nbr_type[rob]] / masses[0]
    shape = (above / 0.3) * np.exp(1.0 - above / 0.3) * np.exp(-(xy ** 2).sum(1) / (2 * width ** 2))
    contrib = -amp * shape * recv[robot_type[sample_of[rob]]]
    dw = np.zeros(n)
    np.add.at(dw, sample_of[rob], contrib)
    f = f + dw * np.tanh(z / 0.15 + 0.2)
    return f.astype(np.float32)


def _csr(counts: np.ndarray):
    offsets = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    sample_of = np.repeat(np.arange(counts.size), counts)
    return offsets, sample_of


def no_history(cfg: Config, generator: str) -> None:
    """The analytic generators draw single instants: no past states (``model.history_ms``)."""
    if cfg.history_ms:
        raise ConfigError(f"model.history_ms {cfg.history_ms}: the {generator} generator draws single instants "
                          "without a past; make the data with `ns2 sim collect` or from logs")


def downwash_dataset(cfg: Config, samples_per_scenario: int = 2000, seed: int = 0,
                     noise_g: float = 0.0, max_neighbors: int = 2) -> Dataset:
    """Random configurations of every scenario mix, labelled by ``analytic_fa_z``."""
    no_history(cfg, "analytic downwash")
    rng = np.random.default_rng(seed)
    mixes = scenario_mixes(cfg, max_neighbors)
    n_s = samples_per_scenario
    robot_type = np.concatenate([np.full(n_s, r) for r, _, _ in mixes])
    scenario = np.repeat(np.arange(len(mixes)), n_s)
    time_s = np.tile(np.arange(n_s) * 0.01, len(mixes))
    counts = np.concatenate([np.full(n_s, len(mix) + 1) for _, mix, _ in mixes])
    offsets, sample_of = _csr(counts)
    nbr_type = np.empty(offsets[-1], dtype=np.int64)
    nbr_state = np.empty((offsets[-1], 6), dtype=np.float32)
    n = robot_type.size
    # own state: positions in a 2 m cube, more samples near the ground; 7 % fast samples
    p = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), 1.5 * rng.uniform(0, 1, n) ** 2])
    v = rng.normal(0.0, 0.25, (n, 3)) * np.where(rng.uniform(size=n) < 0.07, 5.0, 1.0)[:, None]
    v = np.clip(v, -2.0, 2.0)
    for s_idx, (r, mix, _) in enumerate(mixes):
        rows = offsets[s_idx * n_s:(s_idx + 1) * n_s]
        for k, t in enumerate(sorted(mix)):
            lo, hi = cfg.volume(r, t)
            # where the analytic downwash lives (its plume is within 0.4 m sideways
            # and 1.2 m up: the earlier default volume), however wide the volume
            rel_p = rng.uniform(np.maximum(lo, NEAR_LO), np.minimum(hi, NEAR_HI), (n_s, 3))
            rel_v = np.clip(rng.normal(0.0, 0.3, (n_s, 3)), -2.0, 2.0)
            nbr_type[rows + k] = t
            nbr_state[rows + k] = np.column_stack([rel_p, rel_v])
        env_rows = rows + len(mix)
        nbr_type[env_rows] = cfg.env_index
        own = slice(s_idx * n_s, (s_idx + 1) * n_s)
        nbr_state[env_rows] = np.column_stack([-p[own], -v[own]])
    label = analytic_fa_z(cfg, robot_type, sample_of, nbr_type, nbr_state)
    if noise_g > 0:
        label = (label + rng.normal(0.0, noise_g, n)).astype(np.float32)
    return Dataset(robot_type, label, scenario, time_s, offsets, nbr_type, nbr_state,
                   cfg.neighbor_types, [name for _, _, name in mixes],
                   {"generator": "analytic-downwash", "seed": seed}).validated()


def max_dataset(cfg: Config, n: int = 20000, seed: int = 0) -> Dataset:
    """Paper's 2-group example: robot type 0 with two type-0 and two type-1 neighbours;
    x = first relative-position component of type-0 neighbours, y = of type-1 ones,
    label h = max(x1, x2) + 2 max(y1, y2) (in 'grams')."""
    no_history(cfg, "max example")
    if cfg.num_robot_types < 2:
        raise ValueError("the 2-group example needs two robot types")
    rng = np.random.default_rng(seed)
    counts = np.full(n, 5)
    offsets, _ = _csr(counts)
    nbr_type = np.tile([0, 0, 1, 1, cfg.env_index], n).astype(np.int64)
    nbr_state = np.zeros((5 * n, 6), dtype=np.float32)
    lo, hi = cfg.volume(0, 0)
    lo1, hi1 = cfg.volume(0, 1)
    xs = rng.uniform(lo[0], hi[0], (n, 2)).astype(np.float32)
    ys = rng.uniform(lo1[0], hi1[0], (n, 2)).astype(np.float32)
    nbr_state[0::5, 0], nbr_state[1::5, 0] = xs[:, 0], xs[:, 1]
    nbr_state[2::5, 0], nbr_state[3::5, 0] = ys[:, 0], ys[:, 1]
    label = (xs.max(1) + 2 * ys.max(1)).astype(np.float32)
    return Dataset(np.zeros(n, np.int64), label, np.zeros(n, np.int64), np.arange(n) * 0.01,
                   offsets, nbr_type, nbr_state, cfg.neighbor_types, ["max2"],
                   {"generator": "max-example", "seed": seed}).validated()
