"""The firmware library under ASan + UBSan (fuzz/ns2_fuzz.c via ns2host.fuzz): the
smallest triggers of issue 17 (D1 HIL PING echo, D2 controller stuck on NaN,
D3 peers stuck on NaN) and a bounded, fixed-seed run of every fuzz target with
its recovery checks, for the default export and for a network with wake memory
(24 inputs per neighbour); `pilot`: the app's ns2_pilot_step against the
simulator's ns2_pilot_tick bit for bit under glitches, resets and live parameters.
`make fuzz` runs the same targets with >= 1,000,000 inputs."""
import pytest

from ns2host import fuzz


@pytest.fixture(scope="module")
def exe(exported):
    return fuzz.build(exported.gen_dir)


def test_issue17_triggers_d1_d2_d3(exe):
    out = fuzz.run(exe, "regress", 1, 0)
    assert out["checks"] > 1000


INFERENCE = ("infer", "sliced", "hil")  # the targets that run predictions
PER_PERIOD = ("pilot",)  # one input a millisecond: a prediction per 10 ms position period


def reached_inference(target, out):
    """The predictions with status NS2_OK and a neighbour used: enough for the target."""
    if target in PER_PERIOD:
        return out["predictions_ok"] > 0.05 * out["inputs"] / 10
    return target not in INFERENCE or out["predictions_ok"] > 0.05 * out["inputs"]


@pytest.mark.parametrize("target", fuzz.TARGETS)
def test_bounded_fuzz_run(exe, target):
    out = fuzz.run(exe, target, 3000, seed=17)
    assert out["inputs"] >= 3000 and out["checks"] > out["inputs"] and out["input_dim"] == 6
    assert reached_inference(target, out), out


@pytest.fixture(scope="module")
def exe_hist(history):
    return fuzz.build(history.gen_dir)


@pytest.mark.parametrize("target", ("regress",) + fuzz.TARGETS)
def test_bounded_fuzz_run_with_wake_memory(exe_hist, target):
    """The driver on a network with wake memory: every neighbour's past and the own
    past drawn (hostile values too) through the *_hist entry points, which must reach
    the inference (not only be refused), the peers' history ring recovered after
    glitches, HIL bodies with 24 inputs per neighbour and the own past."""
    out = fuzz.run(exe_hist, target, 1000, seed=17)
    assert out["input_dim"] == 24 and out["checks"] > out["inputs"] >= (1 if target == "regress" else 1000)
    assert reached_inference(target, out), out


def test_a_failed_check_is_reported(exe, tmp_path):
    """The runner does fail: an unknown target exits non-zero."""
    with pytest.raises(fuzz.FuzzFailure, match="exit 2"):
        fuzz.run(exe, "no-such-target", 1, 0)


def test_make_fuzz_gives_every_target_its_share():
    """`make fuzz` (ns2host.fuzz's main) splits --count over every target: each has a share."""
    assert set(fuzz.SHARE) == set(fuzz.TARGETS)
    assert sum(fuzz.SHARE.values()) == pytest.approx(1.0)
