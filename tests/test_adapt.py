"""Issue 53: the on-board label (firmware/src/ns2_label.c) and the adaptation on top
of the deep set (ns2_adapt.c) equal their float32 references (ns2codegen.onboard)
bit for bit on random, hostile and real sequences, in the host build and on the
emulated STM32F405; the label equals the data pipeline's (float64) within a stated
tolerance on real 16 June 2020 flights; bad input gives defined, bounded outputs
and a status, and recovery."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import ARM, QEMU, REAL_DATA, needs, real_logs
from ns2codegen import onboard as ob
from ns2codegen.onboard import AdaptCfg, LabelCfg
from ns2paper.collection import COLLECTION
from ns2codegen.vehicle import G
from ns2host import onboard as host

OUT_KEYS = ("label_N", "label_g", "out_g", "term_g", "theta", "P", "label_status", "adapt_status", "updates")
# the float32 label against the float64 pipeline on the real flights below, grams
REAL_LABEL_TOLERANCE_G = 1e-4


def reference(lcfg: LabelCfg, t: host.Ticks) -> dict:
    lab_N, lab_g, lst = ob.label_f32(lcfg, t.vz, t.z, t.q, t.pwm, t.battery_V)
    res = ob.adapt_f32(t.cfgs, t.nn_g, t.wake, lab_g, lst, t.reset, t.s_h)
    return {"label_N": lab_N, "label_g": lab_g, "label_status": lst, "adapt_status": res.pop("status"), **res}


def assert_bits(a: dict, b: dict) -> None:
    for k in OUT_KEYS:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.shape == y.shape, k
        if x.dtype == np.float32:
            x, y = x.view(np.uint32), y.view(np.uint32)
        bad = np.flatnonzero((x != y).reshape(len(x), -1).any(1))
        assert bad.size == 0, (k, bad[:5], a[k][bad[:3]], b[k][bad[:3]])


def label_cfg(cfg, robot_type: str = "small", **kw) -> LabelCfg:
    return LabelCfg.of_vehicle(cfg.vehicle(robot_type), **kw)


def hover_ticks(cfg, rng, n: int, robot_type: str = "small", offset_g: float = 0.0, noise: float = 0.02):
    """A robot hovering at 0.5 m with noisy velocity and the PWM that holds its weight
    (psi_1 solved numerically), plus ``offset_g`` of unmodelled weight."""
    veh = cfg.vehicle(robot_type)
    k = np.asarray(veh["psi1"], float)
    per_motor_g = (veh["mass_g"] + offset_g) / 4
    pw = np.linspace(0.01, 1.0, 100_000)
    pwm0 = pw[np.argmin(np.abs(k[0] + k[1] * pw + k[2] + k[3] * pw * pw + k[4] * pw - per_motor_g))]
    vz = rng.normal(0, noise, n)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)) + rng.normal(0, 0.01, (n, 4))
    pwm = np.clip(pwm0 + rng.normal(0, noise, (n, 4)), 0.0, 1.0)
    return vz, np.full(n, 0.5), q, pwm, np.full(n, 4.2)


def wild_ticks(cfg, seed: int, n: int) -> tuple[LabelCfg, host.Ticks]:
    """Random ticks: hover-like, with NaN/Inf/absurd inputs, saturated and stopped
    motors, ground contact, tilt, wakes, absurd parameter writes and resets."""
    rng = np.random.default_rng(seed)
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=rng.uniform(-5, 5), noise=0.1)
    nn = rng.normal(0, 2.0, n) + np.where(rng.random(n) < 0.1, rng.normal(-8, 4, n), 0.0)
    z = z + rng.normal(0, 0.3, n)
    wild = [np.nan, np.inf, -np.inf, 1e9, -1e9, 2.0, -0.5, 0.0, 1.0, 11.0, 1e-30, -0.0]
    for arr in (vz, z, bat, nn):
        m = rng.random(n) < 0.01
        arr[m] = rng.choice(wild, m.sum())
    for arr in (q, pwm):
        m = rng.random(arr.shape) < 0.005
        arr[m] = rng.choice(wild, m.sum())
    pwm[rng.random(n) < 0.02, rng.integers(0, 4)] = 1.0
    q[rng.random(n) < 0.02] = [0.8, 0.6, 0.0, 0.0]            # 74 degrees of roll
    base = AdaptCfg()
    cfgs, cur = [], base
    for t in range(n):
        r = rng.random()
        if r < 0.01:
            field = str(rng.choice(ob.ADAPT_FIELDS))
            value = int(rng.choice([0, 1, 2, 255])) if field in ob.ADAPT_U8_FIELDS else \
                float(rng.choice([np.nan, np.inf, -1.0, 0.0, 0.3, 2.0, 1e6, 0.99, 5.0, 1e-7]))
            cur = AdaptCfg(**{**cur.as_dict(), field: value})
        elif r < 0.02:
            cur = AdaptCfg(**{**base.as_dict(), "forget": float(rng.uniform(0.9, 1.0)),
                              "p_max": float(rng.uniform(1, 100)), "wake_g": float(rng.uniform(0, 5)),
                              "scale_max": float(rng.choice([0.0, rng.uniform(0, 1)])),
                              "gate_neighbours": int(rng.integers(0, 2)),
                              "track_gain": float(rng.choice([0.0, rng.uniform(0, 1e5)]))})
        cfgs.append(cur)
    # every sequence has the composite law at its defaults, then a gate other than 0/1 written
    cfgs[n // 3:n // 3 + 300] = [AdaptCfg(track_gain=2e4)] * 300
    cfgs[n // 2:n // 2 + 20] = [AdaptCfg(**{**cfgs[n // 2].as_dict(), "gate_neighbours": 2})] * 20
    lc = label_cfg(cfg, min_z_m=0.2)
    s_h = rng.normal(0, 0.005, n)                   # the composite tracking error times 10 ms, m
    m = rng.random(n) < 0.01
    s_h[m] = rng.choice(wild, m.sum())
    return lc, host.ticks(vz, z, q, pwm, bat, nn, cfgs, rng.random(n) < 0.002, rng.random(n) < 0.1, s_h)


def test_exp_neg_bit_exact_and_accurate(exported):
    from ns2host import cbuild

    _, lib = cbuild.load(exported.gen_dir)
    xs = np.concatenate([np.linspace(0, 20, 4001), np.random.default_rng(0).uniform(0, 1e4, 2000),
                         [np.nan, -1.0, np.inf, 1e4, 1.0001e4]]).astype(np.float32)
    c = np.array([lib.ns2_label_exp_neg(float(x)) for x in xs], np.float32)
    r = np.array([ob.exp_neg_f32(x) for x in xs], np.float32)
    assert np.array_equal(c.view(np.uint32), r.view(np.uint32))
    for hi, rtol in ((1.0, 3e-7), (20.0, 1e-5)):                 # lambda h of a Crazyflie: about 0.16
        ok = (xs >= 0) & (xs <= hi)
        assert np.allclose(r[ok], np.exp(-xs[ok].astype(float)), rtol=rtol, atol=0), hi
    assert r[-5] == 1.0 and r[-4] == 1.0 and r[-3] == 0.0 and r[-1] == 0.0    # NaN and x <= 0 give 1, beyond 1e4 0


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_random_and_hostile_sequences_bit_exact(cfg, exported, seed):
    lc, t = wild_ticks(cfg, seed, 6000)
    c, r = host.run_host(exported.gen_dir, lc, t), reference(lc, t)
    assert_bits(c, r)
    # every path was taken, and whatever came in, the outputs are finite and bounded
    st = c["adapt_status"]
    for bit in (ob.ADAPT_UPDATED, ob.ADAPT_BAD_PARAM, ob.ADAPT_BAD_INPUT, ob.ADAPT_LABEL, ob.ADAPT_WAKE):
        assert (st & bit).any(), bit
    # both gates flown, each updating on some ticks; a gate value other than 0/1 written
    gate = np.array([cf.gate_neighbours for cf in t.cfgs])
    for g in (0, 1):
        assert ((gate == g) & ((st & ob.ADAPT_UPDATED) != 0)).any(), g
    assert ((gate > 1) & (st == ob.ADAPT_BAD_PARAM)).any()
    # the composite law flown on some updates, its bad tracking input seen
    track = np.array([cf.track_gain for cf in t.cfgs])
    assert ((track > 0) & ((st & ob.ADAPT_UPDATED) != 0)).any() and (st & ob.ADAPT_BAD_TRACK).any()
    for bit in (ob.LABEL_BAD_INPUT, ob.LABEL_WARMUP, ob.LABEL_GROUND, ob.LABEL_TILTED, ob.LABEL_SATURATED):
        assert (c["label_status"] & bit).any(), bit
    for k in ("label_N", "out_g", "term_g", "theta", "P"):
        assert np.isfinite(c[k]).all(), k
    assert (np.abs(c["theta"][:, 0]) <= max(cf.bias_max_g for cf in t.cfgs if ob.adapt_cfg_ok(cf))).all()
    lim = np.array([cf.fa_max_g if ob.adapt_cfg_ok(cf) else 0.0 for cf in t.cfgs], np.float32)
    assert (np.abs(c["term_g"]) <= lim).all()
    nn_ok = np.isfinite(t.nn_g) & (np.abs(t.nn_g) <= 1e30)
    assert np.array_equal(c["out_g"][~nn_ok], np.zeros((~nn_ok).sum(), np.float32))
    assert (c["label_N"][c["label_status"] & (ob.LABEL_BAD_INPUT | ob.LABEL_WARMUP) > 0] == 0).all()


def test_label_of_a_known_hover_is_the_unmodelled_weight(cfg, exported):
    """A robot 3 g heavier than its config: the label is -3 g (gravity's share the
    network does not know) and the adaptation's bias takes it within 3 s."""
    rng = np.random.default_rng(5)
    n = 600
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=3.0, noise=0.001)
    q[:] = [1.0, 0.0, 0.0, 0.0]
    t = host.ticks(vz, z, q, pwm, bat, np.zeros(n))
    c = host.run_host(exported.gen_dir, label_cfg(cfg), t)
    assert_bits(c, reference(label_cfg(cfg), t))
    assert abs(np.mean(c["label_g"][5:]) + 3.0) < 0.05
    assert (c["label_status"][:4] == ob.LABEL_WARMUP).all() and (c["label_status"][4:] == 0).all()
    theta0 = c["theta"][:, 0]
    assert abs(theta0[300] + 3.0) < 0.3 and abs(theta0[-1] + 3.0) < 0.2     # 3 s at 100 Hz
    assert abs(c["out_g"][-1] + 3.0) < 0.2


def test_bad_input_defined_status_and_recovery(cfg, exported):
    rng = np.random.default_rng(6)
    n = 400
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=2.0, noise=0.01)
    nn = np.zeros(n)
    base = AdaptCfg()
    cfgs = [base] * n
    for k in range(150, 170):                      # an absurd forgetting factor written, then a good one
        cfgs[k] = AdaptCfg(**{**base.as_dict(), "forget": 7.0})
    for k in range(200, 205):
        cfgs[k] = AdaptCfg(**{**base.as_dict(), "forget": float("nan")})
    vz[100] = np.nan                               # a NaN sensor
    pwm[250:260, 2] = 1.0                          # a saturated motor
    z[300:320] = 0.02                              # on the ground
    nn[350] = np.inf                               # a non-finite network output
    lc = label_cfg(cfg)
    t = host.ticks(vz, z, q, pwm, bat, nn, cfgs)
    c = host.run_host(exported.gen_dir, lc, t)
    assert_bits(c, reference(lc, t))
    st, lst, th = c["adapt_status"], c["label_status"], c["theta"]
    # NaN sensor: label 0 with BAD_INPUT, four warm-up ticks, then labels again, equal to a fresh start's
    assert lst[100] == ob.LABEL_BAD_INPUT and c["label_N"][100] == 0 and (lst[101:105] == ob.LABEL_WARMUP).all()
    assert lst[105] == 0
    fresh = host.run_host(exported.gen_dir, lc, host.ticks(vz[101:130], z[101:130], q[101:130], pwm[101:130],
                                                           bat[101:130], nn[101:130]))
    assert np.array_equal(fresh["label_N"].view(np.uint32), c["label_N"][101:130].view(np.uint32))
    assert (st[100:105] & ob.ADAPT_LABEL).all() and not (st[100:105] & ob.ADAPT_UPDATED).any()
    assert np.array_equal(th[99], th[104])
    # absurd parameters: f = NN, theta held, BAD_PARAM; updates again with the good value
    assert (st[150:170] == ob.ADAPT_BAD_PARAM).all() and (st[200:205] == ob.ADAPT_BAD_PARAM).all()
    assert np.array_equal(c["out_g"][150:170], np.zeros(20, np.float32)) and np.array_equal(th[149], th[169])
    assert (st[170:180] & ob.ADAPT_UPDATED).all() and (st[205:215] & ob.ADAPT_UPDATED).all()
    # saturated motor and ground: labelled with the flag, never learned from
    sat = np.flatnonzero(lst & ob.LABEL_SATURATED)
    assert sat.min() == 250 and sat.max() == 263 and not (st[sat] & ob.ADAPT_UPDATED).any()
    gnd = np.flatnonzero(lst & ob.LABEL_GROUND)
    assert gnd.min() == 302 and gnd.max() == 321 and not (st[gnd] & ob.ADAPT_UPDATED).any()
    # non-finite NN: f = 0 with BAD_INPUT, the NN history restarts (two ticks without a pair)
    assert st[350] == ob.ADAPT_BAD_INPUT and c["out_g"][350] == 0
    assert (st[351:353] & ob.ADAPT_LABEL).all() and st[353] & ob.ADAPT_UPDATED
    assert abs(th[-1, 0] + 2.0) < 0.3


@pytest.mark.parametrize("gate", [0, 1])
def test_wake_is_never_learned(cfg, exported, gate):
    """Where |NN| > wake_g (and with gate_neighbours = 1 where the caller's flag is up)
    theta never moves, whatever the labels say (here 6 g of downwash the network does not
    know); the adapted term there stays within fa_max_g.  With gate_neighbours = 0 (the
    default) the flag alone does not stop the updates."""
    rng = np.random.default_rng(7)
    n = 600
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=0.0, noise=0.01)
    phase = (np.arange(n) // 50) % 4
    flag = phase == 1                                               # a neighbour above: the pilot's flag
    nn = np.where(phase == 3, -20.0, 0.0)                           # beyond wake_g
    pwm[phase >= 1] *= 0.93                                         # the wake's unexplained downforce
    lc = label_cfg(cfg)
    acfg = AdaptCfg(gate_neighbours=gate)
    t = host.ticks(vz, z, q, pwm, bat, nn, acfg, wake=flag)
    c = host.run_host(exported.gen_dir, lc, t)
    assert_bits(c, reference(lc, t))
    delayed = lambda a: np.concatenate([[False, False], a[:-2]])   # noqa: E731 (the labelled sample)
    flagged = np.flatnonzero(delayed(flag) & (c["label_status"] == 0))
    if gate:
        wake_pairs = np.flatnonzero(delayed(flag) | delayed(phase == 3))
        assert wake_pairs.size > 200
    else:
        wake_pairs = np.flatnonzero(delayed(phase == 3))
        assert wake_pairs.size > 100
        assert not (c["adapt_status"][flagged] & ob.ADAPT_WAKE).any()
        assert (c["adapt_status"][flagged] & ob.ADAPT_UPDATED).mean() > 0.8     # the flag alone: learned
    assert (c["adapt_status"][wake_pairs] & ob.ADAPT_WAKE).all()
    assert not (c["adapt_status"][wake_pairs] & ob.ADAPT_UPDATED).any()
    for k in wake_pairs:
        assert np.array_equal(c["theta"][k], c["theta"][k - 1])
    assert (c["adapt_status"][delayed(phase == 2)] & ob.ADAPT_UPDATED).mean() > 0.8  # learns outside wakes
    assert (np.abs(c["term_g"]) <= AdaptCfg().fa_max_g).all()


def test_neighbour_gate_default_and_bad_values(cfg, exported):
    """gate_neighbours is 0 by default (the C's ns2_adapt_default_cfg and the reference);
    a value other than 0 or 1 is refused (BAD_PARAM: f = NN, theta held) until a good one
    returns, then it learns again; the C's check equals the reference's."""
    from ns2host import cbuild

    ffi, lib = cbuild.load(exported.gen_dir)
    c_cfg = ffi.new("ns2_adapt_cfg_t *")
    lib.ns2_adapt_default_cfg(c_cfg)
    assert c_cfg.gate_neighbours == 0 == AdaptCfg().gate_neighbours
    for g in range(256):
        c_cfg.gate_neighbours = g
        assert bool(lib.ns2_adapt_cfg_ok(c_cfg)) == ob.adapt_cfg_ok(AdaptCfg(gate_neighbours=g)) == (g <= 1), g
    rng = np.random.default_rng(8)
    n = 300
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=3.0, noise=0.01)
    cfgs = [AdaptCfg()] * n
    for k in range(100, 150):
        cfgs[k] = AdaptCfg(gate_neighbours=2 if k < 125 else 255)
    lc = label_cfg(cfg)
    t = host.ticks(vz, z, q, pwm, bat, np.full(n, 1.5), cfgs, wake=rng.random(n) < 0.5)
    c = host.run_host(exported.gen_dir, lc, t)
    assert_bits(c, reference(lc, t))
    st, th = c["adapt_status"], c["theta"]
    assert (st[100:150] == ob.ADAPT_BAD_PARAM).all()
    assert np.array_equal(c["out_g"][100:150], np.full(50, 1.5, np.float32)) and np.array_equal(th[99], th[149])
    assert (st[20:100] & ob.ADAPT_UPDATED).all() and (st[150:] & ob.ADAPT_UPDATED).all()   # flag up or not
    assert abs(th[-1, 0] + 4.5) < 0.3                    # the label (-3 g) less NN (1.5 g)


def test_composite_law_tracking_term(cfg, exported):
    """Neural-Fly's composite law (track_gain > 0): the C equals the reference bit for bit
    with a tracking error s_h; theta moves with s (a positive s, the robot above its
    reference's motion, raises the bias against the RLS alone); track_gain = 0 (the
    default, the C's and the reference's) ignores s_h entirely (bit for bit the run with
    s_h = 0); no update, no tracking term either (a wake); a non-finite or absurd s_h skips
    the term (BAD_TRACK) but not the RLS update; a negative or absurd gain is a bad
    parameter (the C's check equals the reference's)."""
    from ns2host import cbuild

    ffi, lib = cbuild.load(exported.gen_dir)
    c_cfg = ffi.new("ns2_adapt_cfg_t *")
    lib.ns2_adapt_default_cfg(c_cfg)
    assert c_cfg.track_gain == 0.0 == AdaptCfg().track_gain
    for g in (0.0, 1.0, 2e4, 1e6, 1.1e6, -1.0, -0.0, float("nan"), float("inf")):
        c_cfg.track_gain = g
        assert bool(lib.ns2_adapt_cfg_ok(c_cfg)) == ob.adapt_cfg_ok(AdaptCfg(track_gain=g)) == (0 <= g <= 1e6), g
    rng = np.random.default_rng(12)
    n = 600
    vz, z, q, pwm, bat = hover_ticks(cfg, rng, n, offset_g=3.0, noise=0.01)
    nn = np.where((np.arange(n) // 100) % 3 == 2, -20.0, 0.5)          # a wake every third 100 ticks
    s_h = np.full(n, 2e-4, np.float32)                                   # 0.02 m/s for 10 ms
    s_h[[150, 151, 160]] = [np.nan, np.inf, 2.0]
    lc = label_cfg(cfg)
    runs = {}
    for g in (0.0, 2e3):
        t = host.ticks(vz, z, q, pwm, bat, nn, AdaptCfg(track_gain=g), s_h=s_h)
        runs[g] = c = host.run_host(exported.gen_dir, lc, t)
        assert_bits(c, reference(lc, t))
    zero = host.run_host(exported.gen_dir, lc, host.ticks(vz, z, q, pwm, bat, nn, AdaptCfg()))
    assert_bits(runs[0.0], zero)                                         # gain 0: s_h never read
    st, th = runs[2e3]["adapt_status"], runs[2e3]["theta"][:, 0]
    upd = (st & ob.ADAPT_UPDATED) != 0
    assert (th[upd] > runs[0.0]["theta"][upd, 0]).all()                 # s > 0 raises the bias
    wake = np.flatnonzero(st & ob.ADAPT_WAKE)
    assert wake.size > 100 and all(th[k] == th[k - 1] for k in wake)    # no update: no tracking term
    assert np.array_equal(np.flatnonzero(st & ob.ADAPT_BAD_TRACK), [150, 151, 160])
    assert upd[[150, 151, 160]].all() and not (runs[0.0]["adapt_status"] & ob.ADAPT_BAD_TRACK).any()


SWAPS = "neural-swarm-2020-06-16-swaps.tar.xz"
REAL_MEMBERS = [f"{COLLECTION}/{f}" for f in ("swap_sl/cf51_04", "swap_sl/cf101_04", "swap_lll/cf100_01",
                                               "swap_lll/cf101_01", "swap_lll/cf102_01")]


@pytest.fixture(scope="module")
def real_flights(cfg):
    """Two real 16 June 2020 flights (swap_sl/04, swap_lll/01), aligned and cut into pieces."""
    from ns2codegen.logs.align import logs_to_flights
    from ns2paper.collection import write_manifest

    root = real_logs(SWAPS, REAL_MEMBERS)
    write_manifest(root)
    return logs_to_flights(cfg, root)[0]


@pytest.fixture(scope="module")
def real_robots(cfg, real_flights):
    """(label config, Ticks with the on-board prediction flown as NN, the pipeline's f_a,z in N)
    of every labelled robot of the two real flights."""
    from ns2codegen.data.from_logs import labelled_steps

    out = []
    for fl, i, steps, fa in labelled_steps(cfg, real_flights):
        h = float(np.median(np.diff(fl.t)))
        lc = label_cfg(cfg, fl.types[i], h_s=h)
        nn = fl.fa_onboard_g[:, i] if fl.fa_onboard_g is not None else np.zeros(len(fl.t))
        out.append((lc, host.ticks(fl.v[:, i, 2], fl.p[:, i, 2], fl.q[:, i], fl.pwm[:, i], fl.battery_V[:, i],
                                   np.nan_to_num(nn)), fa[:, 2]))
    assert len(out) >= 4 and sum(len(t) for _, t, _ in out) > 4000
    return out


@needs(REAL_DATA)
def test_label_on_real_flights_equals_the_pipeline(exported, real_robots):
    """Real 16 June 2020 flights through the host C: bit for bit the float32 reference,
    and within REAL_LABEL_TOLERANCE_G of the float64 pipeline's labels
    (labels.residual_force), two samples late."""
    worst = 0.0
    for lc, t, fa_N in real_robots:
        c, r = host.run_host(exported.gen_dir, lc, t), reference(lc, t)
        assert_bits(c, r)
        d = ob.LABEL_DELAY
        ok = (c["label_status"][d:] & (ob.LABEL_BAD_INPUT | ob.LABEL_WARMUP)) == 0
        pipe_g = fa_N[:-d] * 1000.0 / G
        assert np.array_equal(ok, np.isfinite(pipe_g))                 # labelled where the pipeline labels
        diff = np.abs(c["label_g"][d:][ok].astype(float) - pipe_g[ok])
        worst = max(worst, float(diff.max()))
        assert (c["adapt_status"] & ob.ADAPT_UPDATED).any()
    assert worst < REAL_LABEL_TOLERANCE_G, worst


@needs(REAL_DATA)
@pytest.mark.parametrize("gate", [0, 1])
def test_real_flights_bit_exact_with_either_gate(exported, real_robots, gate):
    """The real flights with a wake flag (here: where the flown network's |f_a,z| > 3 g,
    a stand-in for a neighbour in range) through the host C with gate_neighbours 0 and 1:
    bit for bit the float32 reference; with 1 it never learns from a flagged tick, with 0 it
    does."""
    on_flagged = updates = 0
    for lc, t, _ in real_robots:
        flag = np.abs(t.nn_g) > 3.0
        tw = host.ticks(t.vz, t.z, t.q, t.pwm, t.battery_V, t.nn_g, AdaptCfg(gate_neighbours=gate), wake=flag)
        c = host.run_host(exported.gen_dir, lc, tw)
        assert_bits(c, reference(lc, tw))
        upd = np.flatnonzero(c["adapt_status"] & ob.ADAPT_UPDATED)
        on_flagged += int(flag[upd - ob.LABEL_DELAY].sum())
        updates += upd.size
    assert updates > 1000 and ((on_flagged == 0) if gate else (on_flagged > 100)), (updates, on_flagged)


@needs(ARM, QEMU)
def test_qemu_stm32f405_bit_exact(cfg, exported):
    lc, t = wild_ticks(cfg, 11, 4000)
    elf = host.build_image(exported.gen_dir)
    assert_bits(host.run_qemu(exported.gen_dir, elf, lc, t), reference(lc, t))


@needs(ARM, QEMU, REAL_DATA)
def test_qemu_real_flights_bit_exact(exported, real_robots):
    elf = host.build_image(exported.gen_dir)
    for lc, t, _ in real_robots[:2]:
        assert_bits(host.run_qemu(exported.gen_dir, elf, lc, t), host.run_host(exported.gen_dir, lc, t))


@needs(ARM)
def test_cycle_counts_of_one_update_on_the_cortex_m4(cfg, exported):
    """The benchmark's counts (budget.adapt_runs) exist: an RLS update costs more than
    a tick in a wake (no update), and label + update stay a small part of 10 ms."""
    from ns2host import budget

    runs = budget.adapt_runs(exported.gen_dir, cfg)
    assert runs["adapt_step_update"].cycles > runs["adapt_step_wake"].cycles > 0
    assert 0 < runs["label_step"].memory_cycles + runs["adapt_step_update"].memory_cycles < 10_000


@needs(REAL_DATA)
def test_replay_of_real_flights_for_the_judgement(cfg, exported, real_flights):
    """experiments/adaptation.py's replay (issue 53 item 4) on the two real flights: every
    sample once, each robot's in time order, its flight's pieces joined by one non-finite
    tick that restarts the label and NN history and holds theta; the take-off reset; the C
    bit for bit the float32 reference across the joins; a robot 3 g heavier than its
    config recovers, found by the recovery detection, unless it never learns; with the
    neighbour gate (gate_neighbours 1) it never learns from a flagged tick, by default it does."""
    from ns2codegen.data.from_logs import flights_to_dataset, sample_info
    from ns2exp import adaptation as ad
    from ns2exp.real import RealDataError

    ds, info = flights_to_dataset(cfg, real_flights), sample_info(cfg, real_flights)
    trs = ad.tracks(cfg, real_flights, info)
    assert np.array_equal(np.sort(np.concatenate([t.samples for t in trs])), np.arange(len(ds)))
    for t in trs:
        assert np.array_equal(t.t_s[t.tick], info["t_s"][t.samples]) and (np.diff(t.t_s[t.tick]) > 0).all()
        assert len(set(info["robot"][t.samples])) == 1
    with pytest.raises(RealDataError):
        ad.tracks(cfg, real_flights[::-1], info)           # not the data set's order: refused
    nn = np.nan_to_num(info["onboard_g"])
    sp = ad.Split(ds, info, trs, onboard=False)
    acfg = AdaptCfg()
    adapted, runs = sp.run(exported.gen_dir, cfg, nn, acfg)
    joined = [(t, c) for t, c in zip(trs, runs) if np.isnan(t.vz).any()]
    assert joined                                           # swap_sl/04 is cut into three pieces
    for t, c in joined:
        assert_bits(c, reference(ad.label_cfg(cfg, t), ad.track_ticks(t, nn, sp.wake, acfg)))
        for j in np.flatnonzero(np.isnan(t.vz)):
            assert c["label_status"][j] == ob.LABEL_BAD_INPUT and c["adapt_status"][j] == ob.ADAPT_BAD_INPUT
            assert np.array_equal(c["theta"][j - 1], c["theta"][j + 4])   # held until the label is warm again
            assert not (c["adapt_status"][j:j + 5] & ob.ADAPT_UPDATED).any()
    gated = sp.run(exported.gen_dir, cfg, nn, AdaptCfg(gate_neighbours=1))[1]
    on_flagged = {0: 0, 1: 0}
    for t, c, cg in zip(trs, runs, gated):
        first = t.tick[0]
        assert first == 2 and c["updates"][first] == 0 and adapted[t.samples[0]] == np.float32(nn[t.samples[0]])
        flagged = np.zeros(len(t), bool)
        flagged[t.tick] = sp.wake[t.samples]
        for g, r in ((0, c), (1, cg)):
            on_flagged[g] += int(flagged[np.flatnonzero(r["adapt_status"] & ob.ADAPT_UPDATED) - 2].sum())
    assert on_flagged[1] == 0 and on_flagged[0] > 100, on_flagged   # the neighbour gate: never from a flagged tick
    m = ad.mass_offset(exported.gen_dir, cfg, sp, nn, runs, acfg, cfg.robot_types)
    assert m["adapted"]["plain"] < m["static"]["plain"]
    assert sum(r["wake_flag_share"] < 0.5 for r in m["per_robot"].values()) >= 1
    for name, r in m["per_robot"].items():
        if r["wake_flag_share"] < 0.5:
            assert r["from_takeoff_s"] is not None and r["from_takeoff_s"] < 3.0, name
            assert r["from_step_s"] is not None and r["from_step_s"] < 15.0, name
        if r["updates"] == 0:
            assert r["from_takeoff_s"] is None, name


def test_recovery_detection():
    """The time until the adapted terms' difference is within the tolerance of the offset
    for good: 2 ln 6 s for an exponential approach with a 2 s time constant; None when it
    leaves the band again at the end; from a step, counted from the step."""
    from ns2exp import adaptation as ad

    n = 2000
    t_s = np.arange(n) * 0.01
    tr = ad.Track("x", "small", 0.01, *(np.zeros(n),) * 2, np.zeros((n, 4)), np.zeros((n, 4)), np.zeros(n),
                  np.arange(n), np.arange(n), t_s)
    d = -3.0 * (1 - np.exp(-t_s / 2.0))
    assert abs(ad.recovery_times(tr, d, 0, -3.0, 0.5) - 2 * np.log(6)) <= 0.011
    assert ad.recovery_times(tr, np.where(t_s > 19.0, 0.0, d), 0, -3.0, 0.5) is None
    late = np.where(t_s < 5.0, 0.0, -3.0 * (1 - np.exp(-(t_s - 5.0) / 2.0)))
    assert abs(ad.recovery_times(tr, late, 500, -3.0, 0.5) - 2 * np.log(6)) <= 0.011
    wobble = d.copy()
    wobble[1500] = 0.0                                        # out of the band once, late: counted from after it
    assert abs(ad.recovery_times(tr, wobble, 0, -3.0, 0.5) - 15.01) <= 1e-9
