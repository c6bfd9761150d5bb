/*
 * ns2_sim.c - host-only simulator kernel: one RK4 step of eq. (dynamics) for n
 * robots (double precision; the Python side, host/sim/dynamics.py, holds the
 * parameters and the state layout).
 *
 * Per robot, x = [p(3) v(3) q(4, w x y z) w(3) u(4)] (17 doubles) and
 * par = [m, Jx, Jy, Jz, lambda, B0 (4x4 row-major)] (21 doubles):
 *   p_dot = v,  m v_dot = m g + R e3 T + f_a,  q_dot = 1/2 q (x) [0; w],
 *   J w_dot = (J w) x w + tau + tau_a,  [T; tau] = B0 u,  u_dot = lambda (u_c - u).
 * f_a (world), tau_a (body) and u_c are held over the step.
 */
#include <math.h>
#include <stdint.h>

#include "ns2_controller.h"

#define NS2_SIM_X 17
#define NS2_SIM_PAR 21

static void deriv(const double *x, const double *par, const double *u_c, const double *f_a,
                  const double *tau_a, double *d)
{
    const double m = par[0], Jx = par[1], Jy = par[2], Jz = par[3], lam = par[4];
    const double *B0 = &par[5];
    const double *u = &x[13];
    double eta[4];
    for (int r = 0; r < 4; ++r) {
        eta[r] = B0[4 * r] * u[0] + B0[4 * r + 1] * u[1] + B0[4 * r + 2] * u[2] + B0[4 * r + 3] * u[3];
    }
    const double qw = x[6], qx = x[7], qy = x[8], qz = x[9];
    const double wx = x[10], wy = x[11], wz = x[12];
    const double inv_n2 = 1.0 / (qw * qw + qx * qx + qy * qy + qz * qz);
    const double a = eta[0] / m;
    d[0] = x[3];
    d[1] = x[4];
    d[2] = x[5];
    d[3] = 2.0 * (qx * qz + qw * qy) * inv_n2 * a + f_a[0] / m;
    d[4] = 2.0 * (qy * qz - qw * qx) * inv_n2 * a + f_a[1] / m;
    d[5] = (1.0 - 2.0 * (qx * qx + qy * qy) * inv_n2) * a + f_a[2] / m - NS2_G_MPS2;
    d[6] = -0.5 * (qx * wx + qy * wy + qz * wz);
    d[7] = 0.5 * (qw * wx + qy * wz - qz * wy);
    d[8] = 0.5 * (qw * wy + qz * wx - qx * wz);
    d[9] = 0.5 * (qw * wz + qx * wy - qy * wx);
    d[10] = ((Jy * wy) * wz - (Jz * wz) * wy + eta[1] + tau_a[0]) / Jx;
    d[11] = ((Jz * wz) * wx - (Jx * wx) * wz + eta[2] + tau_a[1]) / Jy;
    d[12] = ((Jx * wx) * wy - (Jy * wy) * wx + eta[3] + tau_a[2]) / Jz;
    for (int i = 0; i < 4; ++i) {
        d[13 + i] = lam * (u_c[i] - u[i]);
    }
}

void ns2_sim_rk4(uint32_t n, double *x, const double *par, const double *u_c, const double *f_a,
                 const double *tau_a, double dt)
{
    for (uint32_t r = 0; r < n; ++r) {
        double *xr = &x[NS2_SIM_X * r];
        const double *pr = &par[NS2_SIM_PAR * r];
        const double *uc = &u_c[4 * r], *fa = &f_a[3 * r], *ta = &tau_a[3 * r];
        double k1[NS2_SIM_X], k2[NS2_SIM_X], k3[NS2_SIM_X], k4[NS2_SIM_X], y[NS2_SIM_X];
        deriv(xr, pr, uc, fa, ta, k1);
        for (int i = 0; i < NS2_SIM_X; ++i) {
            y[i] = xr[i] + 0.5 * dt * k1[i];
        }
        deriv(y, pr, uc, fa, ta, k2);
        for (int i = 0; i < NS2_SIM_X; ++i) {
            y[i] = xr[i] + 0.5 * dt * k2[i];
        }
        deriv(y, pr, uc, fa, ta, k3);
        for (int i = 0; i < NS2_SIM_X; ++i) {
            y[i] = xr[i] + dt * k3[i];
        }
        deriv(y, pr, uc, fa, ta, k4);
        for (int i = 0; i < NS2_SIM_X; ++i) {
            xr[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        const double qn = sqrt(xr[6] * xr[6] + xr[7] * xr[7] + xr[8] * xr[8] + xr[9] * xr[9]);
        for (int i = 6; i < 10; ++i) {
            xr[i] /= qn;
        }
    }
}
