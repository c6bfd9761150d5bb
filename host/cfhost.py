"""Host build of the real Crazyflie's estimator and stock controller next to the ns2
library: the simulator's flight kernel (host/ns2_fly.c).

From crazyflie-firmware (``ns2host.crazyflie.firmware_dir()``), compiled as its Python
bindings do (``bindings/setup.py``: the same include folders, ``-fno-strict-aliasing
-DUNIT_TEST_MODE``) plus ``-include autoconf.h`` of the configuration the app flies with
(``ns2host.cfapp.app_config()``), as its Kbuild does:
  the extended Kalman filter  src/modules/src/kalman_core/{kalman_core,mm_position}.c,
                              axis3fSubSampler.c and the CMSIS-DSP matrix functions;
  the IMU low-pass filters    src/utils/src/filter.c (lpf2p);
  the Mellinger controller    controller_mellinger.c, power_distribution_quadrotor.c and
                              motorsCompensateBatteryVoltage (taken verbatim from
                              src/drivers/src/motors.c, whose other code drives timers),
                              the one piece compiled with the stock configuration
                              (``cfapp.stock_config()``): a Crazyflie flying Mellinger
                              flies the stock firmware, whose battery compensation is on;
                              app-config turns it off for the app's psi_2, and with it
                              the function returns its input unchanged.
The ns2 library (firmware/src, ns2_pilot.c included) is compiled with its own strict
flags (ns2host.cbuild.compile_objects) against one export folder.  A robot may fly a
position law of its own (NS2_FLY_LAW, host/ns2_fly.h): its C comes with it as a
``FlyLaw`` and is compiled into the kernel.  One cffi module per export folder and set
of laws, cached under build/host/<hash>.
"""
from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from .cbuild import (CDEF, HOST_HEADERS, REPO, _key, _module, compile_error, compile_objects, content_hash,
                     flags, host_cc, require_export)
from .cfapp import app_config, stock_config
from .crazyflie import extract_function, firmware_dir

FW_INCLUDES = [  # bindings/setup.py
    "src/modules/interface", "src/modules/interface/controller", "src/modules/interface/kalman_core",
    "src/modules/interface/outlierfilter", "src/hal/interface", "src/utils/interface",
    "src/utils/interface/lighthouse", "src/config", "src/drivers/interface", "src/platform/interface",
    "vendor/CMSIS/CMSIS/DSP/Include", "vendor/CMSIS/CMSIS/Core/Include",
]
FW_SOURCES = [
    "src/modules/src/kalman_core/kalman_core.c",
    "src/modules/src/kalman_core/mm_position.c",
    "src/modules/src/axis3fSubSampler.c",
    "src/utils/src/filter.c",
    "src/utils/src/num.c",
    "src/modules/src/controller/controller_mellinger.c",
    "src/modules/src/power_distribution_quadrotor.c",
    "vendor/CMSIS/CMSIS/DSP/Source/MatrixFunctions/arm_mat_mult_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/MatrixFunctions/arm_mat_scale_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/MatrixFunctions/arm_mat_trans_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/FastMathFunctions/arm_cos_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/FastMathFunctions/arm_sin_f32.c",
    "vendor/CMSIS/CMSIS/DSP/Source/CommonTables/arm_common_tables.c",
]
FW_FLAGS = ["-std=gnu11", "-O2", "-fPIC", "-fno-strict-aliasing", "-Wno-address-of-packed-member",
            "-DUNIT_TEST_MODE"]
# (file, function) copied out of firmware files that cannot be compiled for the host whole
FW_EXTRACTED = [("src/drivers/src/motors.c", "motorsCompensateBatteryVoltage")]
FW_EXTRACTED_DEFINES = [("src/drivers/interface/motors.h", "NBR_OF_MOTORS")]  # motors.h needs the STM32 HAL
EXTRACT_PRELUDE = '#include <math.h>\n#include <stdint.h>\n#include "platform_defaults.h"\n#include "cfassert.h"\n'
HOST_FLY = ["host/ns2_fly.c", "host/ns2_sim.c"]


@dataclass(frozen=True)
class FlyLaw:
    """A position law's C for the flight kernel (NS2_FLY_LAW): its sources and header
    (compiled with the kernel's strict flags, the header's folder on the include path),
    the cffi declarations of its types and functions (``cdef``, after the kernel's) and
    ``function``, its ns2_fly_law_fn."""
    sources: tuple[Path, ...]
    header: Path
    cdef: str
    function: str

FLY_CDEF = CDEF + """
typedef struct { uint8_t enable; uint8_t fixed; uint8_t self_type; uint8_t phi_per_tick; uint16_t max_age_ms;
                 float fa_limit_g; } ns2_pilot_cfg_t;
typedef struct { ns2_pilot_cfg_t cfg; ns2_gains_t gains; ns2_ctrl_t ctrl; ns2_peers_t peers; ns2_job_t job;
                 uint8_t job_begun; float fa_hat_g; int32_t status; uint16_t n_used; float e[3];
                 ns2_label_t label; ns2_adapt_cfg_t adapt_cfg; ns2_adapt_t adapt; float fa_used_g; ...; } ns2_pilot_t;
void ns2_pilot_default_cfg(ns2_pilot_cfg_t *cfg, uint8_t self_type);
void ns2_pilot_init(ns2_pilot_t *pl, const ns2_pilot_cfg_t *cfg, const ns2_vehicle_t *veh, const ns2_gains_t *g);
void ns2_pilot_reset(ns2_pilot_t *pl, const ns2_vehicle_t *veh);
int32_t ns2_pilot_peer(ns2_pilot_t *pl, uint8_t id, uint8_t type, uint32_t t_ms, const float p[3]);
void ns2_pilot_tick(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, int do_pos,
                    uint8_t self_id, uint32_t now_ms, float battery_V);
void ns2_pilot_step(ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, uint32_t tick,
                    uint8_t self_id, uint32_t now_ms, float battery_V);
#define NS2_FLY_MAX_ROBOTS ...
#define NS2_FLY_MAX_PEERS ...
#define NS2_FLY_PILOT ...
#define NS2_FLY_MELLINGER ...
#define NS2_FLY_LAW ...
typedef void (*ns2_fly_law_fn)(void *ctx, ns2_pilot_t *pl, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                               float dt);
typedef struct { uint32_t kind; uint8_t id, type; double par[21]; double psi1[5]; float p0[3];
                 float bias_acc_g[3], bias_gyro_dps[3]; float acc_scale; float sd_acc_g, sd_gyro_dps; float ext_pos_std_m;
                 ns2_vehicle_t veh; ns2_gains_t gains; ns2_pilot_cfg_t pilot_cfg; ns2_fly_law_fn law; void *law_ctx;
                 uint32_t pwm_exact; double psi1_nominal[5]; uint32_t use_type_table;
                 uint32_t type_table[16]; ns2_adapt_cfg_t adapt_cfg; } ns2_fly_init_t;
typedef struct { uint32_t kind; uint8_t id, type; double psi1[5]; float sd_acc_g, sd_gyro_dps; ns2_pilot_t pilot; float pwm[4];
                 uint32_t use_type_table; uint32_t type_table[16]; ...; }
    ns2_fly_robot_t;
typedef struct { uint32_t tick; const float *p; const uint8_t *rx; } ns2_fly_frame_t;
typedef struct { ns2_ctrl_state_t s; ns2_setpoint_t sp; uint32_t do_pos, now_ms; float battery_V; uint32_t n_peers;
                 uint8_t peer_id[...]; uint8_t peer_type[...]; uint32_t peer_t[...]; float peer_p[...][3];
                 float pwm[4]; float fa_hat_g; uint16_t n_used; float fa_used_g; float label_g; float theta[2]; }
    ns2_fly_trace_t;
void ns2_fly_init(ns2_fly_robot_t *r, const ns2_fly_init_t *in);
uint32_t ns2_fly_run(ns2_fly_robot_t *rob, uint32_t n, double *x, const double *f_a, const double *tau_a,
                     uint32_t ms0, uint32_t ticks,
                     const float *noise, const ns2_setpoint_t *sp, const ns2_fly_frame_t *frame, const float *battery_V,
                     ns2_fly_trace_t *tr, uint32_t tr_robot, uint32_t tr_max);
void ns2_fly_estimate(const ns2_fly_robot_t *r, float out[13]);
float ns2_adapt_trace(const ns2_adapt_t *a);
float motorsCompensateBatteryVoltage(uint32_t id, float iThrust, float supplyVoltage);
"""


def _run(cmd: list[str]) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise compile_error(" ".join(cmd[-3:]), cmd, r)


def load_fly(gen_dir: str | Path, laws: tuple[FlyLaw, ...] = ()):
    """Build (or reuse) the flight kernel for the export in ``gen_dir``, with the C of
    ``laws`` (FlyLaw: the position laws its robots may fly) compiled in; returns (ffi, lib)."""
    return _load_fly(require_export(gen_dir), tuple(sorted(set(laws), key=repr)))


@lru_cache(maxsize=None)
def _load_fly(gen_dir: Path, laws: tuple[FlyLaw, ...]):
    from cffi import FFI

    fw, auto = firmware_dir(), app_config() / "include" / "generated"
    stock = stock_config() / "include" / "generated"  # the Mellinger robots' battery compensation
    f = flags()
    fw_inc = [f"-I{fw / i}" for i in FW_INCLUDES] + [f"-I{auto}"]
    law_dirs = list(dict.fromkeys(law.header.parent for law in laws))
    ns2_inc = ([f"-I{REPO / i}" for i in f["NS2_INCLUDES"]] + [f"-I{gen_dir}", f"-I{REPO / 'host'}"]
               + [f"-I{d}" for d in law_dirs])
    law_sources = [s for law in laws for s in law.sources]
    cdef = FLY_CDEF + "".join(law.cdef for law in laws)
    key = content_hash([_key(gen_dir, f), cdef, repr(FW_FLAGS), *[fw / s for s in FW_SOURCES],
                        *[fw / s for s, _ in FW_EXTRACTED + FW_EXTRACTED_DEFINES], *[REPO / s for s in HOST_FLY],
                        REPO / "host" / "ns2_fly.h", auto / "autoconf.h", stock / "autoconf.h",
                        *law_sources, *[law.header for law in laws], repr([law.function for law in laws])], 18)

    def build(tmp: Path, name: str) -> None:
        objs = compile_objects(gen_dir, tmp, host_cc(), ["-fPIC"], f)
        extracted = tmp / "cf_extracted.c"
        defines = "".join(next(ln for ln in (fw / h).read_text().splitlines()
                               if re.match(rf"\s*#define\s+{d}\b", ln)).strip() + "\n" for h, d in FW_EXTRACTED_DEFINES)
        extracted.write_text(EXTRACT_PRELUDE + defines + "".join(extract_function(fw / s, fn) for s, fn in FW_EXTRACTED))
        for src, conf in [(fw / s, auto) for s in FW_SOURCES] + [(extracted, stock)]:
            obj = tmp / f"cf_{src.stem}.o"
            inc = [f"-I{fw / i}" for i in FW_INCLUDES] + [f"-I{conf}"]
            _run([host_cc(), *FW_FLAGS, *inc, "-include", "autoconf.h", "-c", str(src), "-o", str(obj)])
            objs.append(obj)
        for k, src in enumerate([REPO / s for s in HOST_FLY] + law_sources):
            obj = tmp / f"{src.stem}.o" if k < len(HOST_FLY) else tmp / f"law{k}_{src.stem}.o"
            # firmware headers as system headers: their warnings are not ours
            _run([host_cc(), *FW_FLAGS, "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-Wconversion",
                  "-Wdouble-promotion", *[a.replace("-I", "-isystem", 1) for a in fw_inc], *ns2_inc, "-include", "autoconf.h", "-c", str(src), "-o", str(obj)])
            objs.append(obj)
        ffi = FFI()
        ffi.cdef(cdef)
        # each law's function checked against ns2_fly_law_fn by the compiler
        checks = "".join(f"ns2_fly_law_fn ns2_fly_law_check_{k}(void) {{ return {law.function}; }}\n"
                         for k, law in enumerate(laws))
        ffi.set_source(name, '#include "autoconf.h"\n' + "".join(f'#include "{x}"\n' for x in (
                           *HOST_HEADERS, "ns2_fly.h", *[law.header.name for law in laws])) + checks,
                       include_dirs=[str(fw / i) for i in FW_INCLUDES] + [str(auto)]
                       + [str(REPO / i) for i in f["NS2_INCLUDES"]] + [str(gen_dir), str(REPO / "host"),
                                                                        str(REPO / "firmware" / "target")]
                       + [str(d) for d in law_dirs],
                       extra_objects=[str(o) for o in objs], libraries=["m"],
                       extra_compile_args=["-std=gnu11", "-O2", "-ffp-contract=off", "-fno-strict-aliasing",
                                           "-DUNIT_TEST_MODE", "-Wno-address-of-packed-member",
                                           "-Wno-pointer-to-int-cast", "-Werror=incompatible-pointer-types"])
        ffi.compile(tmpdir=str(tmp), verbose=False)

    return _module("fly_" + key, "_ns2_fly", build)


PPTRAJ_CDEF = """
int ns2_pptraj_eval(const uint8_t *mem, uint32_t mem_size, uint32_t offset, uint8_t n_pieces, float t, float out[7]);
"""
# The high-level commander's view of an uploaded trajectory (crtp_commander_high_level.c):
# the pieces are the trajectory memory's bytes at the definition's offset, cast to
# struct poly4d; piecewise_eval of the firmware's pptraj.c evaluates them.
PPTRAJ_SOURCE = r"""
#include <string.h>
#include "pptraj.h"
int ns2_pptraj_eval(const uint8_t *mem, uint32_t mem_size, uint32_t offset, uint8_t n_pieces, float t, float out[7])
{
    static uint8_t trajectories_memory[1u << 16] __attribute__((aligned(4)));
    if (mem_size > sizeof(trajectories_memory) || offset + (uint32_t)n_pieces * sizeof(struct poly4d) > mem_size) {
        return -1;
    }
    memcpy(trajectories_memory, mem, mem_size);
    struct piecewise_traj tr = {0};
    tr.timescale = 1.0f;
    tr.n_pieces = n_pieces;
    tr.pieces = (struct poly4d *)&trajectories_memory[offset];
    struct traj_eval ev = piecewise_eval(&tr, t);
    const float v[7] = {ev.pos.x, ev.pos.y, ev.pos.z, ev.vel.x, ev.vel.y, ev.vel.z, ev.yaw};
    memcpy(out, v, sizeof v);
    return 0;
}
"""


def load_pptraj():
    """The firmware's own pptraj.c (its piecewise polynomial evaluation) on the host,
    with ``ns2_pptraj_eval`` reading pieces from trajectory-memory bytes as the
    high-level commander does; returns (ffi, lib)."""
    from cffi import FFI

    fw = firmware_dir()
    src = fw / "src/modules/src/pptraj.c"
    key = content_hash([src.read_bytes(), (fw / "src/modules/interface/pptraj.h").read_bytes(), PPTRAJ_CDEF,
                        PPTRAJ_SOURCE, repr(FW_FLAGS)], 18)

    def build(tmp: Path, name: str) -> None:
        ffi = FFI()
        ffi.cdef(PPTRAJ_CDEF)
        ffi.set_source(name, PPTRAJ_SOURCE, sources=[str(src)], include_dirs=[str(fw / i) for i in FW_INCLUDES],
                       libraries=["m"], extra_compile_args=[*FW_FLAGS, "-ffp-contract=off"])
        ffi.compile(tmpdir=str(tmp), verbose=False)

    return _module("pptraj_" + key, "_ns2_pptraj", build)
