"""The simulator's ground-truth interaction model against the paper's magnitudes."""
import numpy as np
import pytest

from ns2host.sim.aero import calibrated
from ns2host.sim.vehicle import G, vehicle


@pytest.fixture(scope="module")
def S(cfg):
    return vehicle(cfg, "small")


@pytest.fixture(scope="module")
def L(cfg):
    return vehicle(cfg, "large")


def grams(model, p, v=None):
    p = np.array(p, float)
    return model(p, np.zeros_like(p) if v is None else np.array(v, float)) * 1000.0 / G


def test_downwash_magnitudes(S, L):
    below_small = grams(calibrated([S, S], S), [[0, 0, 1.0], [0, 0, 1.3]])[0]
    below_large = grams(calibrated([S, L], S), [[0, 0, 1.0], [0, 0, 1.3]])[0]
    assert below_small[2] == pytest.approx(-9.0, abs=0.1)          # paper: about -9 g at 0.3 m
    assert 1.7 < below_large[2] / below_small[2] < 2.3             # large over small: about twice
    assert np.abs(below_small[:2]).max() < 1e-9                   # on the axis: no lateral push
    # falls off with vertical and horizontal distance; nothing from robots below
    m = calibrated([S, S], S)
    fz = [grams(m, [[0, 0, 1.0], [0, 0, 1.0 + dz]])[0, 2] for dz in (0.2, 0.5, 1.0)]
    assert fz[0] < fz[1] < fz[2] < 0
    assert grams(m, [[0, 0, 1.0], [0.3, 0, 1.3]])[0, 2] > 0.2 * below_small[2]
    assert grams(m, [[0, 0, 1.0], [0, 0, 1.3]])[1, 2] == pytest.approx(0.0, abs=0.02)


def test_depends_on_relative_velocity_and_ground(S):
    m = calibrated([S, S], S)
    still = grams(m, [[0, 0, 1.0], [0, 0, 1.3]])[0]
    moving = grams(m, [[0, 0, 1.0], [0, 0, 1.3]], [[0, 0, 0], [0.8, 0, 0]])[0]
    assert moving[2] > still[2] + 0.3 and moving[0] < 0
    near_ground = grams(m, [[0, 0, 0.1], [0, 0, 0.4]])[0]
    assert near_ground[2] > still[2] + 2.0  # the ground mitigates the downwash


def test_ground_effect_and_drag(S):
    m = calibrated([S], S)
    assert grams(m, [[0, 0, 0.05]])[0, 2] == pytest.approx(5.0, abs=0.05)   # paper: ~5 g at 5 cm
    assert grams(m, [[0, 0, 0.3]])[0, 2] < 0.2
    drag = grams(m, [[0, 0, 1.0]], [[2.0, 0, 0]])[0]
    assert -4.0 < drag[0] < -1.5 and abs(drag[1]) < 1e-9
