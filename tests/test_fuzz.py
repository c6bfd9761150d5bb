"""The firmware library under ASan + UBSan (fuzz/ns2_fuzz.c via ns2host.fuzz): the
smallest triggers of issue 17 (D1 HIL PING echo, D2 controller stuck on NaN,
D3 peers stuck on NaN) and a bounded, fixed-seed run of every fuzz target with
its recovery checks.  `make fuzz` runs the same targets with >= 1,000,000 inputs."""
import pytest

from ns2host import fuzz


@pytest.fixture(scope="module")
def exe(exported):
    return fuzz.build(exported.gen_dir)


def test_issue17_triggers_d1_d2_d3(exe):
    out = fuzz.run(exe, "regress", 1, 0)
    assert out["checks"] > 1000


@pytest.mark.parametrize("target", fuzz.TARGETS)
def test_bounded_fuzz_run(exe, target):
    out = fuzz.run(exe, target, 3000, seed=17)
    assert out["inputs"] >= 3000 and out["checks"] > out["inputs"]


def test_a_failed_check_is_reported(exe, tmp_path):
    """The runner does fail: an unknown target exits non-zero."""
    with pytest.raises(fuzz.FuzzFailure, match="exit 2"):
        fuzz.run(exe, "no-such-target", 1, 0)


def test_make_fuzz_gives_every_target_its_share():
    """`make fuzz` (ns2host.fuzz's main) splits --count over every target: each has a share."""
    assert set(fuzz.SHARE) == set(fuzz.TARGETS)
    assert sum(fuzz.SHARE.values()) == pytest.approx(1.0)
