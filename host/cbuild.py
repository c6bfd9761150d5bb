"""Host build of the firmware library through cffi.

The very same ``firmware/src`` files that go to the STM32 are compiled here with
the flags of ``firmware/flags.mk`` (warnings as errors), against the generated
headers of one export folder, and linked into a cffi extension together with
the host-only batch helpers of ``host/ns2_host.c``.  Builds are cached under
``build/host/<hash of sources, headers and flags>``.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np
from ns2codegen.errors import Ns2Error

from .crazyflie import BUILD, REPO  # the source checkout (see firmware_sources)

BUILD_ROOT = BUILD / "host"
GENERATED = ("ns2_model_config.h", "ns2_model_float.h", "ns2_model_fixed.h")
# host-only helpers, plus the controller and adaptation vector loops shared with the QEMU image
HOST_SOURCES = ["host/ns2_host.c", "firmware/target/ns2_ctrl_vectors.c", "firmware/target/ns2_adapt_vectors.c"]
# the headers of what CDEF declares
HOST_HEADERS = ("ns2_deepset.h", "ns2_peers.h", "ns2_controller.h", "ns2_ctrl_vectors.h", "ns2_adapt_vectors.h",
                "ns2_host.h")

CDEF = """
typedef struct { uint8_t type; float rel[...]; } ns2_neighbor_t;
typedef struct { int32_t status; uint16_t n_used; uint16_t n_invalid; uint16_t n_outside;
                 uint16_t n_truncated; } ns2_info_t;
#define NS2_NUM_ROBOT_TYPES ...
#define NS2_NUM_NEIGHBOR_TYPES ...
#define NS2_ENV_TYPE ...
#define NS2_MAX_NEIGHBORS ...
#define NS2_HIDDEN ...
#define NS2_INPUT_DIM ...
#define NS2_HISTORY_LAGS ...
#define NS2_HISTORY_MAX_MS ...
#define NS2_Q_OUT_FRAC ...
#define NS2_ERR_JOB ...
float ns2_predict_f32(uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
int16_t ns2_predict_q15(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
float ns2_predict_q15_g(uint8_t robot_type, const float p[3], const float v[3],
                        const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
float ns2_predict_f32_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                           const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
int16_t ns2_predict_q15_hist(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                             const ns2_neighbor_t *neighbors, uint16_t n_neighbors, ns2_info_t *info);
uint16_t ns2_select_neighbors(uint8_t robot_type, const ns2_neighbor_t *neighbors,
                              uint16_t n_neighbors, uint16_t *idx, ns2_info_t *info);
typedef struct { ns2_info_t info; uint8_t robot_type; uint8_t path; uint16_t n_inputs; uint16_t next; ...; } ns2_job_t;
int32_t ns2_job_begin(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                      const ns2_neighbor_t *neighbors, uint16_t n_neighbors);
int32_t ns2_job_begin_hist(ns2_job_t *job, uint8_t robot_type, const float p[3], const float v[3],
                           const float *own_past, const ns2_neighbor_t *neighbors, uint16_t n_neighbors);
uint16_t ns2_job_step_f32(ns2_job_t *job, uint16_t max_phi);
uint16_t ns2_job_step_q15(ns2_job_t *job, uint16_t max_phi);
float ns2_job_finish_f32(ns2_job_t *job, ns2_info_t *info);
int16_t ns2_job_finish_q15(ns2_job_t *job, ns2_info_t *info);
#define NS2_PEERS_MAX ...
#define NS2_PEERS_RESTARTED ...
#define NS2_PEERS_STALE_MS ...
#define NS2_PEERS_REORDER_MS ...
#define NS2_TYPE_TABLE_WORDS ...
#define NS2_CTRL_BAD_STATE ...
#define NS2_CTRL_BAD_SETPOINT ...
#define NS2_CTRL_SATURATED ...
#define NS2_CTRL_RESET ...
#define NS2_CTRL_RECOVERING ...
#define NS2_CTRL_BAD_CONFIG ...
#define NS2_CTRL_RECOVERY_TICKS ...
typedef struct { uint8_t id; uint8_t type; uint8_t samples; uint32_t t_ms; float p[3]; float v[3]; ...; } ns2_peer_t;
typedef struct { ns2_peer_t peer[...]; uint8_t count; float alpha; } ns2_peers_t;
void ns2_peers_init(ns2_peers_t *s, float alpha);
int32_t ns2_peers_update(ns2_peers_t *s, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3]);
uint8_t ns2_type_table_get(const uint32_t table[16], uint8_t id, uint8_t n_types);
uint16_t ns2_peers_neighbors(const ns2_peers_t *s, uint8_t self_id, const float p[3], const float v[3],
                             uint32_t now_ms, uint32_t max_age_ms, ns2_neighbor_t *out, uint16_t max);
#define NS2_PEERS_HIST ...
#define NS2_PEERS_HIST_PERIOD_MS ...
void ns2_peers_record(ns2_peers_t *s, const float p[3], const float v[3]);
void ns2_peers_own_past(const ns2_peers_t *s, const float p[3], const float v[3], float *own_past);
typedef struct { float mass_kg; float inertia[3]; float arm_m; float kappa_m; float lambda; float f_max_N;
                 float psi2[5]; } ns2_vehicle_t;
typedef struct { float Lp[3]; float Kv[3]; float Gv[3]; float Lq[3]; float Kw[3]; float Gw[3]; float Kwd[3];
                 float int_v_max; float int_w_max; float fa_max_N; float min_thrust_N; float d_filter; } ns2_gains_t;
typedef struct { float p[3]; float v[3]; float q[4]; float w[3]; } ns2_ctrl_state_t;
typedef struct { float p[3]; float v[3]; float a[3]; float yaw; float w[3]; } ns2_setpoint_t;
typedef struct { ns2_vehicle_t veh; ns2_gains_t g; ns2_setpoint_t sp; float int_v[3]; float int_w[3]; float R_d[9];
                 float T_d; float T_d_dot; float u[4]; float pwm[4]; uint32_t status; ...; } ns2_ctrl_t;
void ns2_ctrl_init(ns2_ctrl_t *c, const ns2_vehicle_t *veh, const ns2_gains_t *g);
void ns2_ctrl_position(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                       const float fa_hat[3], float dt);
void ns2_ctrl_force(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, const float f_d[3], float dt);
void ns2_ctrl_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float dt, float battery_V);
void ns2_ctrl_wrench(const ns2_vehicle_t *veh, const float u[4], float eta[4]);
typedef struct { ns2_ctrl_state_t s; ns2_setpoint_t sp; float fa[3]; float dt_pos, dt_att, battery_V;
                 uint32_t flags; } ns2_step_in_t;
typedef struct { float u[4]; float pwm[4]; float T_d, T_d_dot; uint32_t status; } ns2_step_out_t;
void ns2_ctrl_run_steps(ns2_ctrl_t *c, const ns2_step_in_t *in, ns2_step_out_t *out, uint32_t n);
typedef struct { float mass_kg; float lambda; float psi1[5]; float h_s; float min_z_m; float min_r33; } ns2_label_cfg_t;
typedef struct { ns2_label_cfg_t cfg; float label_N; float label_g; uint32_t status; ...; } ns2_label_t;
typedef struct { uint8_t enable; uint8_t gate_neighbours; float forget; float p0; float p_max; float bias_max_g;
                 float scale_max; float fa_max_g; float label_max_g; float wake_g; float track_gain; } ns2_adapt_cfg_t;
typedef struct { float theta[2]; float P[3]; float term_g; float out_g; uint32_t status; uint32_t updates; ...; }
    ns2_adapt_t;
typedef struct { float vz, z, q[4], pwm[4], battery_V; float nn_g; float s_h; ns2_adapt_cfg_t cfg; uint32_t flags; }
    ns2_adapt_in_t;
typedef struct { float label_N, label_g; float out_g, term_g; float theta[2]; float P[3];
                 uint32_t label_status, adapt_status, updates; } ns2_adapt_out_t;
void ns2_label_init(ns2_label_t *l, const ns2_label_cfg_t *cfg);
void ns2_adapt_reset(ns2_adapt_t *a, const ns2_adapt_cfg_t *cfg);
void ns2_adapt_default_cfg(ns2_adapt_cfg_t *cfg);
int ns2_adapt_cfg_ok(const ns2_adapt_cfg_t *cfg);
float ns2_label_exp_neg(float x);
void ns2_adapt_run_steps(ns2_label_t *l, ns2_adapt_t *a, const ns2_adapt_in_t *in, ns2_adapt_out_t *out,
                         uint32_t n);
void ns2_host_predict_batch(int fixed, uint16_t slice, uint32_t n_queries, const uint8_t *robot_type,
                            const float *p, const float *v, const float *past, const uint32_t *offsets,
                            const ns2_neighbor_t *neighbors, float *out_f, int16_t *out_q,
                            ns2_info_t *infos);
void ns2_host_ctrl_tick(ns2_ctrl_t *ctrls, uint32_t n, const ns2_ctrl_state_t *states,
                        const ns2_setpoint_t *setpoints, const float *fa, int do_pos, float dt_pos,
                        float dt_att, float battery_V, float *pwm_out);
double ns2_host_ns_per_call(int fixed, uint32_t reps, uint8_t robot_type, const float p[3],
                            const float v[3], const ns2_neighbor_t *neighbors, uint16_t n);
"""


class BuildError(Ns2Error, RuntimeError):
    """The C library does not compile (the message: one line, the first compiler
    error; ``details`` the whole command and output)."""

    def __init__(self, message: str, details: str = ""):
        super().__init__(message)
        self.details = details


def require_export(gen_dir: str | Path) -> Path:
    """The export folder, resolved, after checking that its generated headers are there."""
    gen_dir = Path(gen_dir).resolve()
    for g in GENERATED:
        if not (gen_dir / g).is_file():
            raise BuildError(f"{gen_dir / g} missing: run `ns2 export` first")
    return gen_dir


def compile_error(what: str, cmd: list[str], r) -> BuildError:
    out = r.stdout + r.stderr
    first = next((l for l in out.splitlines() if "error" in l), out.strip().splitlines()[0] if out.strip() else "")
    return BuildError(f"{what} does not compile: {first.strip()}", f"{' '.join(cmd)}\n{out}")


def firmware_sources() -> Path:
    """The checkout's ``firmware/`` folder: ns2host compiles the C sources of a source
    checkout, which an installed wheel does not carry."""
    fw = REPO / "firmware"
    if not (fw / "flags.mk").is_file():
        raise BuildError(f"{fw}/flags.mk not found: the host build, target tools and simulator compile the "
                         f"firmware C of a source checkout (clone the repository, pip install -e '.[all]')")
    return fw


def flags() -> dict[str, list[str]]:
    """Variables of firmware/flags.mk as lists."""
    out = {}
    for line in (firmware_sources() / "flags.mk").read_text().splitlines():
        m = re.match(r"^(NS2_\w+)\s*:=\s*(.*)$", line)
        if m:
            out[m.group(1)] = m.group(2).split()
    return out


def host_cc() -> str:
    return os.environ.get("CC", "gcc")


def content_hash(parts, n: int) -> str:
    """The first ``n`` hex digits of the sha256 of ``parts`` in order, the key of every
    host build's cache: a file (Path) counts by its name and bytes, a str by its UTF-8
    bytes, bytes as they are."""
    h = hashlib.sha256()
    for p in parts:
        h.update(p.name.encode() + p.read_bytes() if isinstance(p, Path) else p.encode() if isinstance(p, str) else p)
    return h.hexdigest()[:n]


def cached(final: Path, build, product: str | None = "") -> Path:
    """The build cache of every host build (the cffi modules here and in cfhost.py, the
    firmware builds of cfapp.py, the ELFs of stabilizer.py and target.py, the fuzz
    driver): ``final``, named by the content_hash of every input, made once by
    ``build(out)`` into a fresh temporary folder beside it and put in place by one rename
    (atomic on the one file system: nothing half-written is ever at ``final``).
    product None: ``final`` is a file, which ``build`` writes as ``out / final.name``;
    else ``final`` is the folder ``out``, complete when ``final / product`` exists ("": the
    folder itself).  Of concurrent builders the first rename wins; the others' builds are
    dropped.  Returns ``final``."""
    def done() -> bool:
        return final.is_file() if product is None else (final / product).exists()

    if done():
        return final
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".tmp-{final.name}-"))
    try:
        build(tmp)
        try:
            if product is None:
                os.replace(tmp / final.name, final)
            else:
                os.rename(tmp, final)
        except OSError:  # a concurrent builder put its own in place first
            if not done():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def _key(gen_dir: Path, f: dict) -> str:
    files = [REPO / s for s in f["NS2_SOURCES"]] + sorted((REPO / "firmware" / "include").glob("*.h")) \
        + sorted((REPO / "firmware" / "src").glob("*.h")) + [REPO / s for s in HOST_SOURCES] \
        + [REPO / "host" / "ns2_host.h"] + sorted((REPO / "firmware" / "target").glob("ns2_*_vectors.h")) \
        + [gen_dir / g for g in GENERATED]
    return content_hash([*files, repr(sorted(f.items())), CDEF, host_cc()], 20)


def compile_objects(gen_dir: Path, out: Path, cc: str, extra: list[str], f: dict) -> list[Path]:
    """Compile the firmware sources with the library's strict flags."""
    inc = [f"-I{REPO / i}" for i in f["NS2_INCLUDES"]] + [f"-I{gen_dir}"]
    objs = []
    for src in f["NS2_SOURCES"] + HOST_SOURCES:
        obj = out / (Path(src).stem + ".o")
        cmd = [cc, *f["NS2_STD_FLAGS"], *f["NS2_OPT_FLAGS"], *f["NS2_WARN_FLAGS"], *extra, *inc,
               f"-I{REPO / 'host'}", f"-I{REPO / 'firmware' / 'target'}", "-c", str(REPO / src), "-o", str(obj)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error(f"{src} with the headers of {gen_dir}", cmd, r)
        objs.append(obj)
    return objs


def _module(key: str, prefix: str, build) -> tuple:
    """Build a cffi module once into BUILD_ROOT/<key> (``build(tmp, name)`` compiles it;
    cached) and import it."""
    name = f"{prefix}_{key}"
    final = cached(BUILD_ROOT / key, lambda out: build(out, name))
    so = next(final.glob(f"{name}*.so"))
    spec = importlib.util.spec_from_file_location(name, so)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod.ffi, mod.lib


@lru_cache(maxsize=None)
def load(gen_dir: str | Path):
    """Build (or reuse) the host library for the headers in ``gen_dir``; returns (ffi, lib)."""
    from cffi import FFI

    gen_dir = require_export(gen_dir)
    f = flags()

    def build(tmp: Path, name: str) -> None:
        objs = compile_objects(gen_dir, tmp, host_cc(), ["-fPIC"], f)
        ffi = FFI()
        ffi.cdef(CDEF)
        ffi.set_source(name, "".join(f'#include "{h}"\n' for h in HOST_HEADERS),
                       include_dirs=[str(REPO / i) for i in f["NS2_INCLUDES"]] + [str(gen_dir), str(REPO / "host"),
                                     str(REPO / "firmware" / "target")],
                       extra_objects=[str(o) for o in objs],
                       extra_compile_args=["-std=c99", "-O2", "-ffp-contract=off"])
        ffi.compile(tmpdir=str(tmp), verbose=False)

    return _module(_key(gen_dir, f), "_ns2_host", build)


SIM_CDEF = """
void ns2_sim_rk4(uint32_t n, double *x, const double *par, const double *u_c, const double *f_a,
                 const double *tau_a, double dt);
"""


@lru_cache(maxsize=None)
def load_sim():
    """The simulator's C kernel (host/ns2_sim.c, no model needed); returns (ffi, lib)."""
    from cffi import FFI

    src, header = REPO / "host" / "ns2_sim.c", REPO / "firmware" / "include" / "ns2_controller.h"
    f = flags()
    key = "sim_" + content_hash([src.read_bytes(), header.read_bytes(), SIM_CDEF, host_cc()], 16)

    def build(tmp: Path, name: str) -> None:
        obj = tmp / "ns2_sim.o"
        cmd = [host_cc(), "-std=c99", "-O2", *f["NS2_WARN_FLAGS"], "-fPIC", f"-I{header.parent}", "-c", str(src),
               "-o", str(obj)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise compile_error(str(src), cmd, r)
        ffi = FFI()
        ffi.cdef(SIM_CDEF)
        ffi.set_source(name, "#include <stdint.h>\n" + SIM_CDEF, extra_objects=[str(obj)],
                       extra_compile_args=["-std=c99", "-O2"], libraries=["m"])
        ffi.compile(tmpdir=str(tmp), verbose=False)

    return _module(key, "_ns2_sim", build)


def fill_vehicle(v, veh) -> None:
    """cdata ``ns2_vehicle_t`` from an ns2codegen.vehicle.Vehicle."""
    v.mass_kg, v.inertia, v.arm_m, v.kappa_m = veh.mass, list(veh.inertia), veh.arm, veh.kappa
    setattr(v, "lambda", veh.lam)  # 'lambda' is a Python keyword
    v.f_max_N, v.psi2 = veh.f_max, list(veh.psi2)


def fill_gains(g, gains: dict) -> None:
    """cdata ``ns2_gains_t`` from a dict of its fields (ns2codegen.vehicle.default_gains)."""
    for k, val in gains.items():
        setattr(g, k, val)


# The app's type table (firmware/include/ns2_peers.h): the robot type of every radio
# id 0..255, TYPE_BITS bits per id in TYPE_TABLE_WORDS uint32 words, PARAM ns2type.t0..t15
TYPE_BITS = 2
TYPE_TABLE_WORDS = 16
TYPE_TABLE_MAX_TYPES = 1 << TYPE_BITS
RADIO_IDS = 256


def type_table(types_by_id) -> list[int]:
    """The type table's words (ns2_type_table_get decodes them) of ``{radio id: robot
    type index}`` (or (id, type) pairs); ids not given are type 0."""
    items = types_by_id.items() if isinstance(types_by_id, dict) else types_by_id
    words = [0] * TYPE_TABLE_WORDS
    per_word = 32 // TYPE_BITS
    for rid, t in items:
        rid, t = int(rid), int(t)
        if not (0 <= rid < RADIO_IDS and 0 <= t < TYPE_TABLE_MAX_TYPES):
            raise ValueError(f"radio id {rid} (0..{RADIO_IDS - 1}) or robot type {t} "
                             f"(0..{TYPE_TABLE_MAX_TYPES - 1}) out of the type table's range")
        shift = TYPE_BITS * (rid % per_word)
        w = rid // per_word
        words[w] = (words[w] & ~(((1 << TYPE_BITS) - 1) << shift)) | (t << shift)
    return words


class CModel:
    """The firmware inference, built for the host, with numpy batch calls."""

    def __init__(self, gen_dir: str | Path):
        self.ffi, self.lib = load(gen_dir)
        ffi = self.ffi
        self.input_dim = int(self.lib.NS2_INPUT_DIM)
        self.lags = int(self.lib.NS2_HISTORY_LAGS)
        size = 4 + 4 * self.input_dim
        assert ffi.sizeof("ns2_neighbor_t") == size and ffi.offsetof("ns2_neighbor_t", "rel") == 4
        self.nbr_dtype = np.dtype({"names": ["type", "rel"], "formats": [np.uint8, (np.float32, self.input_dim)],
                                   "offsets": [0, 4], "itemsize": size})
        self.info_dtype = np.dtype({"names": ["status", "n_used", "n_invalid", "n_outside", "n_truncated"],
                                    "formats": [np.int32] + [np.uint16] * 4,
                                    "offsets": [0, 4, 6, 8, 10], "itemsize": ffi.sizeof("ns2_info_t")})

    def controller(self, vehicles) -> object:
        """``ns2_ctrl_t[len(vehicles)]``, each initialised (``ns2_ctrl_init``) for one
        ns2codegen.vehicle.Vehicle with its default gains, as the app does."""
        from ns2codegen.vehicle import default_gains

        ffi, lib = self.ffi, self.lib
        ctrl = ffi.new("ns2_ctrl_t[]", len(vehicles))
        for i, veh in enumerate(vehicles):
            v, g = ffi.new("ns2_vehicle_t *"), ffi.new("ns2_gains_t *")
            fill_vehicle(v, veh)
            fill_gains(g, default_gains(veh))
            lib.ns2_ctrl_init(ffi.addressof(ctrl, i), v, g)
        return ctrl

    def neighbors(self, types, rels) -> np.ndarray:
        a = np.zeros(len(types), self.nbr_dtype)
        a["type"] = types
        a["rel"] = rels
        return a

    def _ptr(self, ctype: str, a: np.ndarray):
        return self.ffi.cast(ctype, self.ffi.from_buffer(a))

    def predict(self, q, fixed: bool, slice: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Run queries.Queries through the C; returns (outputs, info records).
        slice > 0: through the sliced API (ns2_job_*), slice phi evaluations per step.
        A model with wake memory gets q.past through the *_hist entry points."""
        if q.lags != self.lags or q.nbr_rel.shape[-1] != self.input_dim:
            raise ValueError(f"queries with {q.lags} history lags and {q.nbr_rel.shape[-1]} inputs per neighbour "
                             f"for a C model with {self.lags} lags and NS2_INPUT_DIM {self.input_dim}")
        given = q.given()
        counts = given.sum(1)
        offsets = np.zeros(len(q) + 1, np.uint32)
        np.cumsum(counts, out=offsets[1:])
        nb = self.neighbors(q.nbr_type[given], q.nbr_rel[given])
        if nb.size == 0:
            nb = np.zeros(1, self.nbr_dtype)
        rt = np.ascontiguousarray(q.robot_type, np.uint8)
        p = np.ascontiguousarray(q.p, np.float32)
        v = np.ascontiguousarray(q.v, np.float32)
        past = np.ascontiguousarray(q.past, np.float32) if self.lags else None
        out_f = np.zeros(len(q), np.float32)
        out_q = np.zeros(len(q), np.int16)
        infos = np.zeros(len(q), self.info_dtype)
        self.lib.ns2_host_predict_batch(int(fixed), slice, len(q), self._ptr("uint8_t *", rt), self._ptr("float *", p),
                                        self._ptr("float *", v),
                                        self.ffi.NULL if past is None else self._ptr("float *", past),
                                        self._ptr("uint32_t *", offsets),
                                        self._ptr("ns2_neighbor_t *", nb), self._ptr("float *", out_f),
                                        self._ptr("int16_t *", out_q), self._ptr("ns2_info_t *", infos))
        return (out_q if fixed else out_f), infos

    def ns_per_call(self, fixed: bool, reps: int, robot_type: int, p, v, types, rels) -> float:
        nb = self.neighbors(types, rels) if len(types) else np.zeros(1, self.nbr_dtype)
        pp = np.ascontiguousarray(p, np.float32)
        vv = np.ascontiguousarray(v, np.float32)
        return self.lib.ns2_host_ns_per_call(int(fixed), reps, robot_type, self._ptr("float *", pp),
                                             self._ptr("float *", vv), self._ptr("ns2_neighbor_t *", nb),
                                             len(types))
