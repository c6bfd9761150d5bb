"""Issue 29: one neighbour selection for training and flight.  Constructed cases on
every face, edge and corner of every interaction volume (exactly on the bound, one
float32 ulp inside and outside, positions in whole millimetres): the neighbour sets
the data pipeline writes equal the C's selection (host build), sample for sample."""
from __future__ import annotations

import itertools

import numpy as np

from ns2codegen.data.from_logs import Flight, flight_queries, flights_to_dataset
from ns2codegen.selection import membership, relative_state, volumes_f32


def _boundary_offsets(lo, hi):
    """Relative positions (float32) on every face, edge and corner of [lo, hi], and one ulp
    either side of each bound, the other coordinates inside or on a bound too."""
    lo, hi = np.float32(lo), np.float32(hi)
    per_axis = []
    for a in range(3):
        vals = [lo[a], hi[a], np.float32(0.5) * (lo[a] + hi[a])]
        vals += [np.nextafter(lo[a], np.float32(-np.inf)), np.nextafter(lo[a], np.float32(np.inf)),
                 np.nextafter(hi[a], np.float32(-np.inf)), np.nextafter(hi[a], np.float32(np.inf))]
        per_axis.append(np.array(vals, np.float32))
    return np.array(list(itertools.product(*per_axis)), np.float32)            # 7^3 = 343 points


def _flight(types, p_i, p_j, v_j=None):
    """A flight of two robots whose relative positions run through the cases, one per step."""
    t_n = len(p_i) + 4
    p = np.zeros((t_n, 2, 3))
    p[2:-2, 0], p[2:-2, 1] = p_i, p_j
    p[:2], p[-2:] = p[2], p[-3]
    v = np.zeros((t_n, 2, 3))
    if v_j is not None:
        v[2:-2, 1] = v_j
    q = np.zeros((t_n, 2, 4))
    q[..., 0] = 1.0
    return Flight(list(types), np.arange(t_n) * 0.01, p, v, q, np.full((t_n, 2, 4), 0.6), np.full((t_n, 2), 3.9),
                  labelled=[True, False])


def test_every_face_edge_and_corner_matches_the_c(cfg, exported):
    from ns2host.cbuild import CModel

    cm = CModel(exported.gen_dir)
    k = cfg.num_robot_types
    vols = volumes_f32(cfg)
    checked = inside_total = 0
    for r, n in itertools.product(range(k), range(k)):
        rel = _boundary_offsets(vols[r, n, 0], vols[r, n, 1])
        # own position 0 (every float32 offset exact), and in whole millimetres
        p0 = np.zeros((len(rel), 3), np.float32)
        p_mm = np.round(np.random.default_rng(r * k + n).uniform(-1.5, 1.5, (len(rel), 3)) * 1000) / 1000
        p_mm_j = np.round((p_mm + rel.astype(np.float64)) * 1000) / 1000             # neighbours in whole mm too
        for p_i, p_j in ((p0, rel), (p_mm, p_mm_j)):
            fl = _flight([cfg.robot_types[r], cfg.robot_types[n]], p_i, p_j)
            ds = flights_to_dataset(cfg, [fl])
            q = flight_queries(cfg, [fl])
            _, info = cm.predict(q, fixed=False)
            ours = np.diff(ds.nbr_offsets) - 1
            assert np.array_equal(info["n_used"].astype(np.int64), ours), (r, n)
            expect = np.all((relative_state(p_i, 0 * p_i, p_j, 0 * p_j)[:, :3] >= vols[r, n, 0])
                            & (relative_state(p_i, 0 * p_i, p_j, 0 * p_j)[:, :3] <= vols[r, n, 1]), axis=1)
            assert np.array_equal(ours, expect.astype(np.int64))
            checked += len(rel)
            inside_total += int(ours.sum())
    assert checked == 2 * k * k * 343 and 0 < inside_total < checked


def test_the_max_neighbors_cut_keeps_the_first_in_the_given_order(cfg):
    """membership: the first max_neighbors slots inside V, in the order given; NaN and
    unknown types are invalid, never inside."""
    m = cfg.model["max_neighbors"]
    k = cfg.num_robot_types
    s = m + 5
    rel = np.zeros((1, s, 6), np.float32)
    rel[0, 3, 0] = 50.0                     # outside
    rel[0, 5, 1] = np.nan                   # invalid
    ntype = np.zeros((1, s), np.int64)
    ntype[0, 7] = k                         # the environment's index: not a robot neighbour
    valid, inside, acc = membership(volumes_f32(cfg), np.zeros(1, np.int64), ntype, rel, np.ones((1, s), bool), k, m)
    assert not valid[0, 5] and not valid[0, 7] and valid[0, 3] and not inside[0, 3]
    want = [j for j in range(s) if j not in (3, 5, 7)][:m]
    assert np.flatnonzero(acc[0]).tolist() == want
