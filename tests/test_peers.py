"""Neighbour tracking (firmware/src/ns2_peers.c) through the host build."""
import math

import pytest


@pytest.fixture(scope="module")
def lib(exported):
    c = exported.cmodel()
    return c.ffi, c.lib


def _update(ffi, lib, s, id_, typ, t, p):
    return lib.ns2_peers_update(s, id_, typ, t, ffi.new("float[3]", p))


def test_velocity_by_finite_differences_and_staleness(lib):
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 1.0)
    assert _update(ffi, L, s, 7, 1, 1000, [0.0, 0.0, 1.0]) == 0
    assert _update(ffi, L, s, 7, 1, 1010, [0.01, 0.0, 0.98]) == 0  # 1 m/s in x, -2 m/s in z
    assert _update(ffi, L, s, 7, 1, 1005, [5.0, 5.0, 5.0]) == -1   # out of order: ignored
    assert _update(ffi, L, s, 8, 0, 1010, [math.nan, 0.0, 0.0]) == -1
    out = ffi.new("ns2_neighbor_t[16]")
    p, v = ffi.new("float[3]", [0.0, 0.0, 0.5]), ffi.new("float[3]", [0.5, 0.0, 0.0])
    n = L.ns2_peers_neighbors(s, 1, p, v, 1020, 100, out, 16)
    assert n == 1 and out[0].type == 1
    rel = list(out[0].rel)
    assert rel[0] == pytest.approx(0.01) and rel[2] == pytest.approx(0.48)
    assert rel[3] == pytest.approx(1.0 - 0.5, abs=1e-4) and rel[5] == pytest.approx(-2.0, abs=1e-4)
    assert L.ns2_peers_neighbors(s, 1, p, v, 1200, 100, out, 16) == 0  # stale
    assert L.ns2_peers_neighbors(s, 7, p, v, 1020, 100, out, 16) == 0  # itself


def test_nearest_first_and_limits(lib):
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 0.5)
    for i in range(L.NS2_PEERS_MAX):
        assert _update(ffi, L, s, i + 10, i % 2, 5, [0.0, 0.0, 2.0 - 0.1 * i]) == 0
    assert _update(ffi, L, s, 99, 0, 5, [0.0, 0.0, 0.0]) == -1  # table full
    out = ffi.new("ns2_neighbor_t[40]")
    p, v = ffi.new("float[3]", [0.0, 0.0, 0.0]), ffi.new("float[3]", [0.0, 0.0, 0.0])
    n = L.ns2_peers_neighbors(s, 0, p, v, 5, 10, out, 4)
    assert n == 4
    assert [round(out[k].rel[2], 3) for k in range(4)] == [0.5, 0.6, 0.7, 0.8]
    assert all(out[k].rel[5] == 0.0 for k in range(4))  # one sample: no velocity yet
    assert L.ns2_peers_neighbors(s, 0, p, v, 5, 10, out, 40) == L.NS2_PEERS_MAX  # capped


def _full(ffi, L, s, ids, t, types=None):
    for k, i in enumerate(ids):
        ty = types[k] if types is not None else k % 2
        assert _update(ffi, L, s, i, ty, t, [0.1 * k, 0.0, 1.0]) == 0


def test_radio_ids_0_and_255_are_peers_like_any_other(lib):
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 1.0)
    for t in (1000, 1010):
        assert _update(ffi, L, s, 0, 1, t, [0.0, 0.0, 1.5]) == 0
        assert _update(ffi, L, s, 255, 0, t, [0.0, 0.0, 1.2 + (t - 1000) * 0.001]) == 0
    out = ffi.new("ns2_neighbor_t[16]")
    p, v = ffi.new("float[3]", [0.0, 0.0, 1.0]), ffi.new("float[3]", [0.0, 0.0, 0.0])
    assert L.ns2_peers_neighbors(s, 7, p, v, 1010, 100, out, 16) == 2
    assert [(out[k].type, round(out[k].rel[2], 3), round(out[k].rel[5], 3)) for k in range(2)] == [
        (0, 0.21, 1.0), (1, 0.5, 0.0)]                    # 255 (nearer, moving up 1 m/s), then 0
    assert L.ns2_peers_neighbors(s, 0, p, v, 1010, 100, out, 16) == 1 and out[0].type == 0    # robot 0 itself
    assert L.ns2_peers_neighbors(s, 255, p, v, 1010, 100, out, 16) == 1 and out[0].type == 1  # robot 255 itself


def test_a_full_swarm_and_a_peer_that_disappears(lib):
    """16 live peers fill the table (ids 0..255); a 17th is refused while every one is
    live; once one has been silent for NS2_PEERS_STALE_MS the newcomer takes its slot
    (the stalest one's), a new track; the others keep their tracks and velocities."""
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 1.0)
    ids = [0, 255, 1, 31, 32, 33, 64, 99, 100, 127, 128, 150, 200, 230, 254, 77]
    assert len(ids) == L.NS2_PEERS_MAX
    stale = L.NS2_PEERS_STALE_MS
    _full(ffi, L, s, ids, 1000)
    assert _update(ffi, L, s, 42, 1, 1000 + stale, [1.0, 1.0, 1.0]) == -1        # all live: refused
    for t in (1010, 1020):                                   # every peer but 77 flies on at 1 m/s in x
        for k, i in enumerate(ids[:-1]):
            assert _update(ffi, L, s, i, k % 2, t, [0.1 * k + (t - 1000) * 1e-3, 0.0, 1.0]) == 0
    assert _update(ffi, L, s, 42, 1, 1000 + stale, [1.0, 1.0, 1.0]) == -1        # 77 silent for 1 s: not yet
    assert _update(ffi, L, s, 42, 1, 1001 + stale, [1.0, 1.0, 1.0]) == 0         # ... now stale: 42 takes its slot
    got = {s.peer[k].id: k for k in range(s.count)}
    assert s.count == L.NS2_PEERS_MAX and 77 not in got and set(got) == set(ids[:-1]) | {42}
    assert got[42] == ids.index(77) and s.peer[got[42]].samples == 1 and s.peer[got[42]].type == 1
    assert all(s.peer[got[i]].samples == 2 and abs(s.peer[got[i]].v[0] - 1.0) < 1e-3 for i in ids[:-1])
    assert _update(ffi, L, s, 43, 0, 1001 + stale, [1.0, 1.0, 1.0]) == -1        # no other peer is stale
    assert _update(ffi, L, s, 77, 0, 1002 + stale, [0.0, 0.0, 1.0]) == -1        # nor for 77, back again


def test_the_stalest_slot_is_taken_and_a_clock_that_went_back_counts_as_stale(lib):
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 0.5)
    ids = list(range(100, 100 + L.NS2_PEERS_MAX))
    for k, i in enumerate(ids):   # peer k last heard at 1000 + 10 k
        assert _update(ffi, L, s, i, 0, 1000 + 10 * k, [0.0, 0.0, 1.0]) == 0
    t = 1000 + 10 * 3 + L.NS2_PEERS_STALE_MS + 1      # peers 0..3 are stale, peer 0 the stalest
    assert _update(ffi, L, s, 7, 1, t, [0.0, 0.0, 1.0]) == 0 and s.peer[0].id == 7
    assert _update(ffi, L, s, 8, 1, t, [0.0, 0.0, 1.0]) == 0 and s.peer[1].id == 8
    # a peer stamped after the new sample: within the reorder window it is live, beyond it
    # (its clock went back, e.g. a reboot) it is the stalest of all
    for ahead_ms, evicted in ((500, 100), (L.NS2_PEERS_REORDER_MS + 1, 105)):
        s2 = ffi.new("ns2_peers_t *")
        L.ns2_peers_init(s2, 0.5)
        for k, i in enumerate(ids):
            assert _update(ffi, L, s2, i, 0, 12_000 + ahead_ms if i == 105 else 10_000, [0.0, 0.0, 1.0]) == 0
        assert _update(ffi, L, s2, 9, 0, 12_000, [0.0, 0.0, 1.0]) == 0
        left = [s2.peer[k].id for k in range(s2.count)]
        assert 9 in left and evicted not in left and len(left) == L.NS2_PEERS_MAX, (ahead_ms, left)


def test_a_peer_that_changes_type(lib):
    """A peer's type is the one given with its latest accepted sample (the app gives the
    type table's entry at every position: the ground rewrote it), its track goes on."""
    ffi, L = lib
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 1.0)
    out = ffi.new("ns2_neighbor_t[16]")
    p, v = ffi.new("float[3]", [0.0, 0.0, 0.5]), ffi.new("float[3]", [0.0, 0.0, 0.0])
    assert _update(ffi, L, s, 200, 1, 1000, [0.0, 0.0, 1.0]) == 0
    assert _update(ffi, L, s, 200, 1, 1010, [0.01, 0.0, 1.0]) == 0
    assert L.ns2_peers_neighbors(s, 1, p, v, 1010, 100, out, 16) == 1 and out[0].type == 1
    assert _update(ffi, L, s, 200, 0, 1020, [0.02, 0.0, 1.0]) == 0
    assert L.ns2_peers_neighbors(s, 1, p, v, 1020, 100, out, 16) == 1 and out[0].type == 0
    assert out[0].rel[3] == pytest.approx(1.0, abs=1e-4)   # the same track: velocity kept
    assert _update(ffi, L, s, 200, 1, 1015, [0.0, 0.0, 1.0]) == -1   # a late sample changes nothing
    assert s.peer[0].type == 0


def test_type_table_layout_matches_the_ground_side(lib):
    """ns2_type_table_get decodes the words the ground writes (ns2host.cbuild.type_table,
    PARAM ns2type.t0..t15) for every radio id; a type the export lacks is type 0."""
    import random

    from ns2host.cbuild import TYPE_TABLE_WORDS, type_table

    ffi, L = lib
    assert L.NS2_TYPE_TABLE_WORDS == TYPE_TABLE_WORDS == 16
    rng = random.Random(56)
    for n_types in (1, 2, 3, 4):
        types = {i: rng.randrange(n_types) for i in range(256)}
        types[0], types[255] = n_types - 1, n_types - 1
        words = type_table(types)
        table = ffi.new("uint32_t[16]", words)
        assert [L.ns2_type_table_get(table, i, n_types) for i in range(256)] == [types[i] for i in range(256)]
    words = type_table({40: 3, 41: 2, 255: 3})
    table = ffi.new("uint32_t[16]", words)
    assert words[2] == (3 << 16) | (2 << 18) and words[15] == 3 << 30
    assert [L.ns2_type_table_get(table, i, 3) for i in (40, 41, 255, 39)] == [0, 2, 0, 0]   # 3: not a type
    assert L.ns2_type_table_get(ffi.NULL, 40, 4) == 0
    assert type_table([(7, 1), (7, 0)]) == [0] * 16                                         # the last one holds
    with pytest.raises(ValueError):
        type_table({256: 1})
    with pytest.raises(ValueError):
        type_table({3: 4})


def test_history_ring_gives_the_states_that_long_ago(history):
    """Wake memory (model.history_ms 50, 100, 200 ms: 5, 10, 20 ticks of 10 ms): at every
    100 Hz history tick the neighbour list holds, after x_ij of now, x_ij of the tick of
    each lag bit for bit (both states of that tick); a peer younger than the lag, a
    restarted track (a jump) and a bad own state (every history restarts) use their
    oldest recorded tick, the data sets' rule (from_logs.past_steps); the own past
    likewise."""
    import numpy as np

    c = history.cmodel()
    ffi, L = c.ffi, c.lib
    assert L.NS2_PEERS_HIST_PERIOD_MS == 10 and L.NS2_PEERS_HIST == 21
    lags = [5, 10, 20]
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 0.5)
    out = ffi.new("ns2_neighbor_t[16]")
    own_past = ffi.new("float[18]")
    present = {0: {}, 1: {}}          # by peer type (= peer): tick -> x_ij of then
    own = {}
    first = {0: None, 1: 0}           # the tick each history began
    own_first = 0
    checked = 0
    for k in range(60):
        t = 1000 + 10 * k
        pa = [0.02 * k if k < 33 else 3.0 + 0.02 * k, 0.1, 1.3]          # type 1: a jump at tick 33
        _update(ffi, L, s, 3, 1, t, pa)
        if k >= 25:
            _update(ffi, L, s, 4, 0, t, [-0.5, 0.3 + 0.01 * k, 1.1])     # type 0: from tick 25 on
        p = [0.001 * k, 0.0, 1.0] if k != 45 else [math.nan, 0.0, 1.0]     # tick 45: no own state
        v = [0.1, 0.0, 0.01 * (k % 7)]
        pp, vv = ffi.new("float[3]", p), ffi.new("float[3]", v)
        L.ns2_peers_record(s, pp, vv)
        n = L.ns2_peers_neighbors(s, 9, pp, vv, t, 100, out, 16)
        L.ns2_peers_own_past(s, pp, vv, own_past)
        if k == 25:
            first[0] = 25
        if k == 33:
            first[1] = 33
        if k == 45:
            assert n == 0 and all(math.isnan(own_past[6 * i]) for i in range(3))
            continue
        if k == 46:
            first = {0: 46, 1: 46}
            own_first = 46
        own[k] = np.float32(p + v)
        got_own = np.frombuffer(ffi.buffer(own_past), np.float32).reshape(3, 6)
        for i, lag in enumerate(lags):
            assert np.array_equal(got_own[i], own[max(k - lag, own_first)]), (k, lag)
        assert n == (2 if k >= 25 else 1)
        for j in range(n):
            rel = np.frombuffer(ffi.buffer(out[j].rel), np.float32)
            ty = out[j].type
            present[ty][k] = rel[:6].copy()
            for i, lag in enumerate(lags):
                want = present[ty][max(k - lag, first[ty])]
                assert np.array_equal(rel[6 * (i + 1):6 * (i + 2)].view(np.uint32), want.view(np.uint32)), (k, ty, lag)
                checked += 1
    assert checked > 200
    assert not np.array_equal(present[1][40], present[1][20])   # the check can tell ticks apart


def test_without_history_the_peer_table_is_that_of_before(exported, lib):
    """A network without wake memory: ns2_peers_record and ns2_peers_own_past do
    nothing, the neighbour list holds 6 values per peer, the table its old size."""
    ffi, L = lib
    assert L.NS2_HISTORY_LAGS == 0 and ffi.sizeof("ns2_neighbor_t") == 28
    assert ffi.sizeof("ns2_peer_t") == 32
    s = ffi.new("ns2_peers_t *")
    L.ns2_peers_init(s, 1.0)
    _update(ffi, L, s, 3, 1, 1000, [0.0, 0.0, 1.3])
    p, v = ffi.new("float[3]", [0.0, 0.0, 1.0]), ffi.new("float[3]", [0.0, 0.0, 0.0])
    before = bytes(ffi.buffer(s))
    L.ns2_peers_record(s, p, v)
    assert bytes(ffi.buffer(s)) == before
    own_past = ffi.new("float[2]", [7.0, 7.0])
    L.ns2_peers_own_past(s, p, v, own_past)
    assert list(own_past) == [7.0, 7.0]
