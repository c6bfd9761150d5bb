"""The firmware C (built for the host through cffi) against the Python references,
bit for bit, and against the trained torch module: the default network and one with
wake memory (model.history_ms, 24 inputs per neighbour and the robot's own past)."""
import numpy as np
import pytest
import torch

from ns2codegen import reference as ref
from ns2codegen.queries import Queries, random_queries

N_QUERIES = 100_000  # per run, float and fixed point each
CHUNK = 25_000


def _bits(a):
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def _queries(cfg, seed):
    """100k queries: 0..max+4 neighbours of every type mix, 5 % of coordinates on box
    and volume edges, 20 % of neighbours anywhere in the box (mostly outside the
    volume), and in a quarter of the queries out-of-box values, NaN/Inf and bad types."""
    parts = []
    for i, s in enumerate(range(0, N_QUERIES, CHUNK)):
        parts.append(random_queries(cfg, CHUNK, seed=seed + i, wild=0.0 if i % 4 else 0.08))
    return parts


@pytest.fixture(scope="module", params=["exported", "history"])
def model(request):
    """The default network, then the one with wake memory (conftest.history)."""
    return request.getfixturevalue(request.param)


@pytest.fixture(scope="module")
def cmodel(model):
    return model.cmodel()


@pytest.fixture(scope="module")
def query_sets(model):
    return _queries(model.cfg, seed=1000)


def test_coverage_of_query_sets(model, query_sets):
    exported = model
    q = Queries.concat(query_sets)
    assert len(q) >= 100_000
    mx = exported.cfg.model["max_neighbors"]
    assert set(np.unique(q.n)) == set(range(mx + 5))
    sel = ref.select(exported.em, q)
    used = sel.accepted.sum(1)
    assert set(np.unique(used[sel.status == 0])) == set(range(mx + 1))
    assert (sel.n_truncated > 0).sum() > 1000 and (sel.n_outside > 0).sum() > 1000
    assert (sel.n_invalid > 0).sum() > 1000
    assert set(np.unique(sel.status)) == {0, ref.ERR_ROBOT_TYPE, ref.ERR_STATE}
    # every mix of (robot type, number of small, number of large accepted neighbours) up to 2+2
    mixes = set()
    for r in range(2):
        for a in range(3):
            for b in range(3):
                small = (sel.accepted & (q.nbr_type == 0)).sum(1)
                large = (sel.accepted & (q.nbr_type == 1)).sum(1)
                if ((q.robot_type == r) & (small == a) & (large == b)).any():
                    mixes.add((r, a, b))
    assert len(mixes) == 18
    lags = len(exported.cfg.history_ms)
    assert q.nbr_rel.shape[-1] == 6 * (1 + lags) and q.past.shape[1:] == (lags, 6)
    if lags:  # past values alone make neighbours invalid and queries fail
        present_ok = np.isfinite(q.nbr_rel[..., :6]).all(-1) & (q.nbr_type < 2) & q.given()
        assert (present_ok & ~np.isfinite(q.nbr_rel).all(-1)).sum() > 1000
        own_ok = np.isfinite(q.p).all(1) & np.isfinite(q.v).all(1) & (q.robot_type < 2)
        assert (own_ok & (sel.status == ref.ERR_STATE)).sum() > 100


def test_float_c_bit_exact_with_torch_reference(model, cmodel, query_sets):
    exported = model
    total = 0
    for q in query_sets:
        c_out, info = cmodel.predict(q, fixed=False)
        r_out, sel = ref.predict_f32(exported.em, q)
        mismatch = np.flatnonzero(_bits(c_out) != _bits(r_out))
        assert mismatch.size == 0, f"{mismatch.size} float mismatches, first at {mismatch[:5]}"
        assert np.array_equal(info["status"], sel.status)
        assert np.array_equal(info["n_used"], np.where(sel.status == 0, sel.accepted.sum(1), 0))
        assert np.array_equal(info["n_invalid"], sel.n_invalid)
        assert np.array_equal(info["n_outside"], sel.n_outside)
        assert np.array_equal(info["n_truncated"], sel.n_truncated)
        assert np.all(np.isfinite(c_out))
        assert np.all(c_out[sel.status != 0] == 0.0)
        total += len(q)
    assert total >= 100_000


def test_fixed_c_bit_exact_with_integer_reference(model, cmodel, query_sets):
    exported = model
    total = 0
    for q in query_sets:
        c_out, info = cmodel.predict(q, fixed=True)
        r_out, sel = ref.predict_q15(exported.em, q)
        mismatch = np.flatnonzero(c_out != r_out)
        assert mismatch.size == 0, f"{mismatch.size} fixed-point mismatches, first at {mismatch[:5]}"
        assert np.array_equal(info["status"], sel.status)
        total += len(q)
    assert total >= 100_000


def test_fixed_close_to_float_as_the_manifest_says(model, cmodel, query_sets):
    exported = model
    man = exported.manifest["fixed_vs_float_error_g"]
    q = query_sets[1]
    f, _ = cmodel.predict(q, fixed=False)
    i, info = cmodel.predict(q, fixed=True)
    ok = info["status"] == 0
    err = np.abs(i[ok] * 2.0 ** -exported.em.q15.out_frac - f[ok])
    assert err.max() < 0.5  # grams
    assert err.mean() < 2 * man["box"]["mean_abs_g"] + 1e-3


def _torch_module_prediction(exported, q, sel):
    """The trained nn.Module fed with the same selected, clamped inputs."""
    em = exported.em
    rows_type, rows_state, sample_of = [], [], []
    ok = np.flatnonzero(sel.status == 0)
    for n, qi in enumerate(ok):
        for s in np.flatnonzero(sel.accepted[qi]):
            t = q.nbr_type[qi, s]
            rows_type.append(t)
            rows_state.append(ref.clamp(q.nbr_rel[qi, s], em.boxes[t]))
            sample_of.append(n)
        rows_type.append(em.env_index)
        rows_state.append(sel.x_env[qi])
        sample_of.append(n)
    with torch.no_grad():
        out = exported.model(torch.from_numpy(q.robot_type[ok].astype(np.int64)), torch.tensor(sample_of),
                             torch.tensor(np.array(rows_type, np.int64)),
                             torch.from_numpy(np.array(rows_state, np.float32)))
    return ok, out.numpy()


def test_float_c_matches_trained_torch_module(model, cmodel):
    exported = model
    q = random_queries(exported.cfg, 3000, seed=77, wild=0.02)
    c_out, _ = cmodel.predict(q, fixed=False)
    sel = ref.select(exported.em, q)
    ok, t_out = _torch_module_prediction(exported, q, sel)
    np.testing.assert_allclose(c_out[ok], t_out, rtol=1e-5, atol=2e-5)


def _permute_within_types(q, rng):
    """Shuffle each query's given neighbours, keeping the order of types fixed
    relative to ... nothing: any permutation keeps each type group's set intact."""
    q2 = q.take(np.arange(len(q)))
    for i in range(len(q)):
        n = q.n[i]
        perm = rng.permutation(n)
        q2.nbr_type[i, :n] = q.nbr_type[i, perm]
        q2.nbr_rel[i, :n] = q.nbr_rel[i, perm]
    return q2


def test_permutation_invariance(model, cmodel):
    exported = model
    # at most max_neighbors given and all inside the volume: the same set is used
    mx = exported.cfg.model["max_neighbors"]
    q = random_queries(exported.cfg, 4000, seed=5, max_given=mx, inside=1.0, edge=0.0)
    q2 = _permute_within_types(q, np.random.default_rng(0))
    fi, _ = cmodel.predict(q, fixed=True)
    fi2, _ = cmodel.predict(q2, fixed=True)
    assert np.array_equal(fi, fi2)  # exact in fixed point
    ff, _ = cmodel.predict(q, fixed=False)
    ff2, _ = cmodel.predict(q2, fixed=False)
    np.testing.assert_allclose(ff, ff2, rtol=1e-5, atol=1e-4)
    assert (ff != ff2).any() or mx < 2  # float sums are order dependent, hence the tolerance


@pytest.fixture(scope="module")
def default_cmodel(exported):
    return exported.cmodel()


def test_swapping_a_neighbour_type_changes_the_output(exported, default_cmodel):
    cmodel = default_cmodel
    cfg = exported.cfg
    q = random_queries(cfg, 2000, seed=6, max_given=1, inside=1.0, edge=0.0)
    q = q.take(np.flatnonzero(q.n == 1))
    # hovering, with a hovering neighbour 0.3 m above (inside both volumes)
    q.nbr_rel[:, 0] = np.float32([0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
    q.p[:, 0:2] = np.clip(q.p[:, 0:2], -1, 1)
    q.p[:, 2] = np.abs(q.p[:, 2]) % 1.5
    q.v[:] = 0.0
    q2 = q.take(np.arange(len(q)))
    q2.nbr_type[:, 0] = 1 - q.nbr_type[:, 0]
    for fixed in (False, True):
        a, _ = cmodel.predict(q, fixed)
        b, _ = cmodel.predict(q2, fixed)
        assert (a != b).mean() > 0.95
    # large above small pushes down harder than small above small (the learned downwash)
    a, _ = cmodel.predict(q, False)
    b, _ = cmodel.predict(q2, False)
    sel = (q.robot_type == 0) & (q.nbr_type[:, 0] == 0) & (q.p[:, 2] > 0.5)
    assert np.mean(b[sel] - a[sel]) < -3.0


def test_c_api_guards(exported, default_cmodel):
    cmodel = default_cmodel
    ffi, lib = cmodel.ffi, cmodel.lib
    info = ffi.new("ns2_info_t *")
    p = ffi.new("float[3]", [0.0, 0.0, 0.5])
    v = ffi.new("float[3]", [0.0, 0.0, 0.0])
    assert lib.ns2_predict_f32(0, p, v, ffi.NULL, 3, info) == 0.0 and info.status == -3
    assert lib.ns2_predict_q15(0, p, v, ffi.NULL, 3, info) == 0 and info.status == -3
    assert lib.ns2_predict_f32(0, ffi.NULL, v, ffi.NULL, 0, info) == 0.0 and info.status == -2
    assert lib.ns2_predict_f32(7, p, v, ffi.NULL, 0, info) == 0.0 and info.status == -1
    y = lib.ns2_predict_f32(0, p, v, ffi.NULL, 0, ffi.NULL)  # info may be NULL
    assert y == lib.ns2_predict_f32(0, p, v, ffi.NULL, 0, info) and info.status == 0
    assert lib.ns2_predict_q15_g(0, p, v, ffi.NULL, 0, info) == \
        lib.ns2_predict_q15(0, p, v, ffi.NULL, 0, info) * 2.0 ** -lib.NS2_Q_OUT_FRAC


@pytest.mark.parametrize("fixed", [False, True])
def test_sliced_prediction_bit_exact_with_one_shot(cmodel, query_sets, fixed):
    """ns2_job_* (the prediction spread over control ticks) gives the same bits and
    counters as ns2_predict_*, for every slicing, on 25k queries with 0..max+4
    neighbours, NaN/Inf and bad types included."""
    q = query_sets[0]
    one, info1 = cmodel.predict(q, fixed)
    bits = (lambda a: a.view(np.uint16)) if fixed else _bits
    for sl in (1, 3, 4, 17):
        sliced, info = cmodel.predict(q, fixed, slice=sl)
        mismatch = np.flatnonzero(bits(sliced) != bits(one))
        assert mismatch.size == 0, f"slice {sl}: {mismatch.size} mismatches, first at {mismatch[:5]}"
        assert np.array_equal(info, info1)
    assert (info1["status"] != 0).any() and (info1["n_used"] >= 4).any()


def test_sliced_api_guards(default_cmodel):
    cmodel = default_cmodel
    ffi, lib = cmodel.ffi, cmodel.lib
    info = ffi.new("ns2_info_t *")
    p = ffi.new("float[3]", [0.0, 0.0, 0.5])
    v = ffi.new("float[3]", [0.0, 0.0, 0.0])
    nb = ffi.new("ns2_neighbor_t[2]", [{"type": 0, "rel": [0.0, 0.0, 0.3, 0, 0, 0]},
                                       {"type": 1, "rel": [0.05, 0.0, 0.4, 0, 0, 0]}])
    job = ffi.new("ns2_job_t *")  # zeroed: never begun
    assert lib.ns2_job_step_q15(job, 4) == 0
    assert lib.ns2_job_finish_q15(job, info) == 0 and info.status == lib.NS2_ERR_JOB
    assert lib.ns2_job_finish_f32(ffi.NULL, info) == 0.0 and info.status == lib.NS2_ERR_JOB
    assert lib.ns2_job_begin(ffi.NULL, 0, p, v, nb, 2) == lib.NS2_ERR_JOB
    # a begun job: 3 phi inputs (environment + 2), stepped 2 then finished
    assert lib.ns2_job_begin(job, 0, p, v, nb, 2) == 0
    assert lib.ns2_job_step_f32(job, 2) == 1
    assert lib.ns2_job_step_q15(job, 1) == 0  # the other path: refused
    f = lib.ns2_job_finish_f32(job, info)
    assert info.status == 0 and info.n_used == 2
    assert f == lib.ns2_predict_f32(0, p, v, nb, 2, ffi.NULL)
    assert lib.ns2_job_finish_q15(job, info) == 0 and info.status == lib.NS2_ERR_JOB
    # a failed begin keeps its own error through finish
    assert lib.ns2_job_begin(job, 9, p, v, nb, 2) == -1
    assert lib.ns2_job_step_q15(job, 4) == 0
    assert lib.ns2_job_finish_q15(job, info) == 0 and info.status == -1


def test_history_api_guards(history):
    """A network with wake memory: the plain entry points (no own past) refuse with
    NS2_ERR_STATE, as do a NULL or non-finite own past; a neighbour whose past alone
    is not finite is invalid; the generated config carries the lags."""
    cmodel = history.cmodel()
    ffi, lib = cmodel.ffi, cmodel.lib
    assert lib.NS2_HISTORY_LAGS == 3 and lib.NS2_INPUT_DIM == 24 and lib.NS2_HISTORY_MAX_MS == 200
    assert "static const unsigned short ns2_history_ms[NS2_HISTORY_LAGS] = {50, 100, 200};" in \
        (history.gen_dir / "ns2_model_config.h").read_text()
    info = ffi.new("ns2_info_t *")
    p = ffi.new("float[3]", [0.0, 0.0, 0.5])
    v = ffi.new("float[3]", [0.0, 0.0, 0.0])
    past = ffi.new("float[18]", [0.0, 0.0, 0.5, 0.0, 0.0, 0.0] * 3)
    rel = [0.0, 0.0, 0.3, 0.0, 0.0, 0.0] * 4
    nb = ffi.new("ns2_neighbor_t[2]", [{"type": 0, "rel": rel}, {"type": 1, "rel": rel}])
    job = ffi.new("ns2_job_t *")
    assert lib.ns2_predict_f32(0, p, v, nb, 2, info) == 0.0 and info.status == -2
    assert lib.ns2_predict_q15(0, p, v, nb, 2, info) == 0 and info.status == -2
    assert lib.ns2_job_begin(job, 0, p, v, nb, 2) == -2
    assert lib.ns2_predict_f32_hist(0, p, v, ffi.NULL, nb, 2, info) == 0.0 and info.status == -2
    y = lib.ns2_predict_f32_hist(0, p, v, past, nb, 2, info)
    assert info.status == 0 and info.n_used == 2 and y != 0.0
    assert lib.ns2_job_begin_hist(job, 0, p, v, past, nb, 2) == 0 and lib.ns2_job_finish_f32(job, info) == y
    past[13] = float("nan")
    assert lib.ns2_predict_q15_hist(0, p, v, past, nb, 2, info) == 0 and info.status == -2
    past[13] = 0.0
    nb[1].rel[20] = float("inf")
    lib.ns2_predict_q15_hist(0, p, v, past, nb, 2, info)
    assert info.status == 0 and info.n_used == 1 and info.n_invalid == 1
