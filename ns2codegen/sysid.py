"""System identification of a robot type from load-cell measurements (paper,
"Calibration and System Identification of Different Robots", Table "cfprops").

The quadrotor is mounted upside down on a load cell; all four motors get the same
normalized PWM p; battery voltage V and force F (grams, all four rotors) are logged.
With f = F / 4 (one rotor) and v = V / 4.2 (as everywhere in this package):

  psi_1:  f     = c0 + c1 p + c2 v + c3 p^2 + c4 p v    (force from PWM and voltage)
  psi_2:  p     = c0 + c1 f + c2 v + c3 f^2 + c4 f v    (PWM for a force, controller)
  psi_3:  f_max = c0 + c1 p + c2 v                      (largest force at the operating
                                                        point (p, v), thrust mixing)

each by linear least squares on its monomials (psi_1 and psi_2 on the rows with
p > 0 and F > 0, psi_3 on the rows with a full-throttle probe).  The delay
constant lambda of eq. (delay_model), u_dot = lambda (u_c - u), comes from a
square-wave PWM response: the command held between samples gives exactly
u[k+1] = a u[k] + (1 - a) u_c[k], a = exp(-lambda h_k), with u_c = 4 psi_1(p, v);
F is fitted as g y_lambda + b (gain and offset by least squares for every lambda,
so a small psi_1 error does not bias lambda) and lambda minimizes the squared
residual (bounded scalar search after a logarithmic grid).

Input CSV files (header row, any column order):
  static: pwm, vbat_V, force_g [, force_max_g]   force_max_g: force measured right
          after switching to full PWM from that row's operating point (empty if
          not probed)
  step:   time_s, pwm, vbat_V, force_g           pwm: the command from that sample on
Output: a vehicle parameter file (TOML, [vehicle] table read by
``Config.with_vehicle_files``; the fit report in [sysid]) and one plot per fit.
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from .config import dump_toml
from .data.labels import V_NORM, first_order_delay
from .fileio import atomic_write_bytes
from .errors import Ns2Error


class SysidError(Ns2Error, ValueError):
    """Load-cell data that cannot be used (missing columns, too few rows, ...)."""


# physical range of each column; a value outside it is a corrupt row
COLUMN_RANGE = {"pwm": (0.0, 1.0), "vbat_V": (0.0, 10.0), "force_g": (-1e4, 1e4), "force_max_g": (-1e4, 1e4),
                "time_s": (-1e6, 1e6)}


def read_csv(path: str | Path, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict:
    """Numeric columns of a CSV file; empty optional cells become NaN; values outside
    COLUMN_RANGE are refused."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        raise SysidError(f"cannot read {path}: {e.strerror or e}") from e
    except (UnicodeDecodeError, csv.Error) as e:
        raise SysidError(f"{path}: not a CSV text file: {e}") from e
    if not rows:
        raise SysidError(f"{path}: no data rows")
    extra = [k for k, r in enumerate(rows) if None in r]
    if extra:
        raise SysidError(f"{path}: row {extra[0] + 1} has more cells than the header's columns "
                         f"{[c for c in rows[0] if c is not None]} (a value with a comma?)")
    missing = [c for c in required if c not in rows[0]]
    if missing:
        raise SysidError(f"{path}: missing columns {missing} (has {list(rows[0])})")
    out = {}
    for col in required + tuple(c for c in optional if c in rows[0]):
        try:
            out[col] = np.array([float(r[col]) if (r[col] or "").strip() else math.nan for r in rows])
        except (TypeError, ValueError) as e:
            raise SysidError(f"{path}: column {col!r} has a non-numeric value: {e}") from e
        if col in required and not np.all(np.isfinite(out[col])):
            raise SysidError(f"{path}: column {col!r} has empty or non-finite values")
        lo, hi = COLUMN_RANGE.get(col, (-math.inf, math.inf))
        bad = np.flatnonzero(~((out[col] >= lo) & (out[col] <= hi)) & ~np.isnan(out[col]))
        if len(bad):
            raise SysidError(f"{path}: column {col!r} row {int(bad[0]) + 1} is {out[col][bad[0]]:g}, outside "
                             f"[{lo:g}, {hi:g}]")
    return out


# --- polynomials of Table cfprops ---------------------------------------------
def quad_features(x, v) -> np.ndarray:
    """[1, x, v, x^2, x v] (psi_1 with x = p, psi_2 with x = f)."""
    x, v = np.asarray(x, float), np.asarray(v, float)
    return np.stack([np.ones_like(x), x, v, x * x, x * v], -1)


def lin_features(p, v) -> np.ndarray:
    """[1, p, v] (psi_3)."""
    p, v = np.asarray(p, float), np.asarray(v, float)
    return np.stack([np.ones_like(p), p, v], -1)


def fit_poly(X: np.ndarray, y: np.ndarray, what: str) -> tuple[np.ndarray, dict]:
    """Least squares y = X c; returns c and the residual report."""
    if len(y) < 3 * X.shape[1]:
        raise SysidError(f"{what}: {len(y)} usable rows, need at least {3 * X.shape[1]}")
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise SysidError(f"{what}: the data do not excite every term (vary PWM and battery voltage)")
    c, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ c
    s2 = float(r @ r) / (len(y) - X.shape[1])  # residual variance -> standard errors of c
    se = np.sqrt(s2 * np.diag(np.linalg.inv(X.T @ X)))
    return c, {"rows": int(len(y)), "rms": float(np.sqrt(np.mean(r * r))), "max_abs": float(np.abs(r).max()),
               "r2": float(1.0 - np.sum(r * r) / max(np.sum((y - y.mean()) ** 2), 1e-300)),
               "coef_se": [float(x) for x in se]}


def fit_static(data: dict) -> dict:
    """psi_1, psi_2 and (with force_max_g) psi_3 from the static load-cell rows."""
    p, v, f = data["pwm"], data["vbat_V"] / V_NORM, data["force_g"] / 4.0
    if np.any(p < 0) or np.any(p > 1):
        raise SysidError("pwm must be normalized to [0, 1]")
    on = (p > 0) & (f > 0)
    out = {}
    out["psi1"], out["psi1_fit"] = fit_poly(quad_features(p[on], v[on]), f[on], "psi_1")
    out["psi2"], out["psi2_fit"] = fit_poly(quad_features(f[on], v[on]), p[on], "psi_2")
    fmax = data.get("force_max_g")
    if fmax is not None and np.isfinite(fmax).any():
        probe = np.isfinite(fmax)
        out["psi3"], out["psi3_fit"] = fit_poly(lin_features(p[probe], v[probe]), fmax[probe] / 4.0, "psi_3")
    return out


# --- motor delay ----------------------------------------------------------------
def first_order(t: np.ndarray, u_c: np.ndarray, lam: float) -> np.ndarray:
    """u of u_dot = lam (u_c - u) at the (possibly uneven) sample times t."""
    return first_order_delay(u_c, np.exp(-lam * np.diff(t)))


def fit_lambda(data: dict, psi1, lam_range=(1.0, 200.0)) -> tuple[float, dict]:
    """lambda (1/s) from a square-wave step response (see the module docstring)."""
    from scipy.optimize import minimize_scalar

    t, p, v, F = data["time_s"], data["pwm"], data["vbat_V"] / V_NORM, data["force_g"]
    if len(t) < 20 or np.any(np.diff(t) <= 0):
        raise SysidError("step data: need at least 20 rows with increasing time_s")
    if np.ptp(p) < 0.05:
        raise SysidError("step data: the PWM command does not change (need a square wave)")
    u_c = 4.0 * np.clip(quad_features(p, v) @ np.asarray(psi1, float), 0.0, None) * (p > 0)

    def fit(lam: float):
        y = first_order(t, u_c, lam)
        A = np.stack([y, np.ones_like(y)], 1)
        gb, *_ = np.linalg.lstsq(A, F, rcond=None)
        return F - A @ gb, gb

    sse = lambda lam: float(np.sum(fit(math.exp(lam))[0] ** 2))  # noqa: E731
    grid = np.linspace(math.log(lam_range[0]), math.log(lam_range[1]), 40)
    k = int(np.argmin([sse(x) for x in grid]))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    lam = math.exp(minimize_scalar(sse, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6}).x)
    if not (lam_range[0] * 1.01 < lam < lam_range[1] * 0.99):
        raise SysidError(f"step data: lambda {lam:.3g} at the search bound {lam_range}: no first-order step")
    r, (gain, offset) = fit(lam)
    return lam, {"rows": int(len(t)), "rms_g": float(np.sqrt(np.mean(r * r))), "max_abs_g": float(np.abs(r).max()),
                 "gain": float(gain), "offset_g": float(offset), "time_constant_s": 1.0 / lam}


# --- the whole identification ---------------------------------------------------------
def identify(name: str, static: dict, step: dict | None = None, mass_g: float | None = None) -> dict:
    """Vehicle parameters of robot type ``name`` and the fit report."""
    res = fit_static(static)
    veh = {"name": name}
    if mass_g is not None:
        veh["mass_g"] = float(mass_g)
    veh["psi1"] = [round(float(c), 6) for c in res["psi1"]]
    veh["psi2"] = [round(float(c), 6) for c in res["psi2"]]
    report = {"psi1": res["psi1_fit"], "psi2": res["psi2_fit"]}
    if "psi3" in res:
        veh["psi3"] = [round(float(c), 6) for c in res["psi3"]]
        report["psi3"] = res["psi3_fit"]
        if mass_g is not None:  # Table cfprops' "max thrust": 4 psi_3 at the hover operating point
            v_op = float(np.median(static["vbat_V"])) / V_NORM
            p_hover = float(quad_features(mass_g / 4.0, v_op) @ res["psi2"])
            veh["max_thrust_g"] = round(4.0 * float(lin_features(p_hover, v_op) @ res["psi3"]), 3)
            report["max_thrust"] = {"pwm_hover": p_hover, "vbat_V": v_op * V_NORM}
    if step is not None:
        lam, report["lambda"] = fit_lambda(step, res["psi1"])
        veh["lambda"] = round(lam, 4)
    return {"vehicle": veh, "sysid": report, "fits": res}


def write_results(out: str | Path, result: dict, static: dict, step: dict | None = None) -> list[Path]:
    """The vehicle parameter file ``out`` and the plots next to it; returns all paths."""
    out = Path(out)
    if not out.parent.is_dir():
        from .fileio import OutputError

        raise OutputError(f"output folder {out.parent} does not exist")
    text = dump_toml({"vehicle": result["vehicle"], "sysid": _flat(result["sysid"])},
                     "Vehicle parameters from `ns2 sysid` (Neural-Swarm2 Table cfprops); use with\n"
                     "--vehicle FILE (replaces these parameters of the robot type in the config).")
    paths = [out]
    atomic_write_bytes(out, text.encode())
    for tag, fig in _plots(result, static, step).items():
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        path = out.with_name(f"{out.stem}_{tag}.png")
        atomic_write_bytes(path, buf.getvalue())
        paths.append(path)
    return paths


def _flat(report: dict) -> dict:
    """[sysid] table: one key per fit figure, e.g. psi1_rms."""
    return {f"{fit}_{k}": v for fit, d in report.items() for k, v in d.items()}


def _plots(result: dict, static: dict, step: dict | None) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fits, figs = result["fits"], {}
    p, V, f = static["pwm"], static["vbat_V"], static["force_g"] / 4.0
    v_levels = np.quantile(V, [0.1, 0.5, 0.9])
    specs = [("psi1", p, f, "normalized PWM p", "force per rotor f (g)", quad_features, "psi1"),
             ("psi2", f, p, "force per rotor f (g)", "normalized PWM p", quad_features, "psi2")]
    fmax = static.get("force_max_g")
    if "psi3" in fits:
        probe = np.isfinite(fmax)
        specs.append(("psi3", p[probe], fmax[probe] / 4.0, "normalized PWM p", "max force per rotor (g)",
                      lin_features, "psi3"))
    for tag, x, y, xl, yl, feats, key in specs:
        fig, ax = plt.subplots(figsize=(6, 4))
        c = V[probe] if tag == "psi3" else V
        sc = ax.scatter(x, y, c=c, s=6, cmap="viridis", label="load cell")
        xs = np.linspace(x.min(), x.max(), 100)
        for vl in v_levels:
            ax.plot(xs, feats(xs, np.full_like(xs, vl / V_NORM)) @ fits[key], "-", lw=1.5,
                    label=f"{tag} at {vl:.2f} V")
        fig.colorbar(sc, ax=ax, label="battery voltage (V)")
        fit = result["sysid"][tag]
        ax.set(xlabel=xl, ylabel=yl, title=f"{tag}: rms residual {fit['rms']:.3g}, R^2 {fit['r2']:.4f}")
        ax.legend(fontsize=7)
        fig.tight_layout()
        figs[tag] = fig
    if step is not None and "lambda" in result["vehicle"]:
        lam = result["vehicle"]["lambda"]
        rep = result["sysid"]["lambda"]
        t = step["time_s"]
        u_c = 4.0 * np.clip(quad_features(step["pwm"], step["vbat_V"] / V_NORM) @ fits["psi1"], 0.0, None)
        model = rep["gain"] * first_order(t, u_c, lam) + rep["offset_g"]
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.plot(t, step["force_g"], ".", ms=3, label="load cell")
        ax.plot(t, model, "-", label=f"first-order delay, lambda = {lam:.3g} 1/s")
        ax.set(xlabel="time (s)", ylabel="force (g)", title=f"step response: rms residual {rep['rms_g']:.3g} g")
        ax.legend(fontsize=8)
        fig.tight_layout()
        figs["lambda"] = fig
    for fig in figs.values():
        plt.close(fig)
    return figs

