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
