/*
 * ns2_controller.c - see ns2_controller.h (equation numbers of Neural-Swarm2).
 * Plain C99, no dynamic memory, no recursion.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "ns2_controller.h"

#define NS2_G ((float)NS2_G_MPS2)

static int finite_n(const float *x, int n)
{
    for (int i = 0; i < n; ++i) {
        if (!isfinite(x[i])) {
            return 0;
        }
    }
    return 1;
}

/* x limited to [lo, hi]; NaN gives lo (a defined value, never NaN). */
static float clampf(float x, float lo, float hi)
{
    return x >= lo ? (x <= hi ? x : hi) : lo;
}

/* All n values finite with |x_i| <= lim (false for NaN and +-Inf). */
static int within_n(const float *x, int n, float lim)
{
    for (int i = 0; i < n; ++i) {
        if (!(fabsf(x[i]) <= lim)) {
            return 0;
        }
    }
    return 1;
}

static int positive_n(const float *x, int n)
{
    for (int i = 0; i < n; ++i) {
        if (!(isfinite(x[i]) && x[i] > 0.0f)) {
            return 0;
        }
    }
    return 1;
}

static int dt_ok(float dt)
{
    return dt >= NS2_CTRL_DT_MIN_S && dt <= NS2_CTRL_DT_MAX_S;
}

/* Components within [-2, 2] and squared norm within [0.25, 4]. */
static int quat_ok(const float q[4])
{
    if (!within_n(q, 4, 2.0f)) {
        return 0;
    }
    const float n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    return n2 >= 0.25f && n2 <= 4.0f;
}

static int state_ok(const ns2_ctrl_state_t *s)
{
    return s != NULL && within_n(s->p, 3, NS2_CTRL_P_MAX_M) && within_n(s->v, 3, NS2_CTRL_V_MAX_MS) &&
           quat_ok(s->q) && within_n(s->w, 3, NS2_CTRL_W_MAX_RADS);
}

static int setpoint_ok(const ns2_setpoint_t *sp)
{
    return sp != NULL && within_n(sp->p, 3, NS2_CTRL_P_MAX_M) && within_n(sp->v, 3, NS2_CTRL_V_MAX_MS) &&
           within_n(sp->a, 3, NS2_CTRL_A_MAX_MS2) && within_n(&sp->yaw, 1, NS2_CTRL_YAW_MAX_RAD) &&
           within_n(sp->w, 3, NS2_CTRL_W_MAX_RADS);
}

static int config_ok(const ns2_vehicle_t *veh, const ns2_gains_t *g)
{
    const float veh_pos[7] = {veh->mass_kg, veh->inertia[0], veh->inertia[1], veh->inertia[2],
                              veh->arm_m, veh->kappa_m, veh->lambda};
    const float g_fin[3 * 7 + 4] = {
        g->Lp[0], g->Lp[1], g->Lp[2], g->Kv[0], g->Kv[1], g->Kv[2], g->Gv[0], g->Gv[1], g->Gv[2],
        g->Lq[0], g->Lq[1], g->Lq[2], g->Kw[0], g->Kw[1], g->Kw[2], g->Gw[0], g->Gw[1], g->Gw[2],
        g->Kwd[0], g->Kwd[1], g->Kwd[2], g->int_v_max, g->int_w_max, g->fa_max_N, g->min_thrust_N};
    return positive_n(veh_pos, 7) && positive_n(&veh->f_max_N, 1) && finite_n(veh->psi2, 5) &&
           finite_n(g_fin, 3 * 7 + 4) && g->d_filter > 0.0f && g->d_filter <= 1.0f;
}

/* sin and cos of x (rad) from fixed float polynomials, so that the host and the
 * STM32 builds agree bit for bit (libm's sinf/cosf differ between C libraries).
 * Quadrant reduction with pi/2 split in two parts; Taylor polynomials on
 * |r| <= pi/4 (error < 1e-6 for |x| < 20 rad). */
static void sincos_det(float x, float *s, float *c)
{
    const float k = roundf(x * 0.63661977f);
    const float r = (x - k * 1.5707963f) - k * 7.5497899e-8f;
    const float r2 = r * r;
    const float sr = r * (1.0f + r2 * (-1.6666667e-1f + r2 * (8.3333333e-3f + r2 * (-1.9841270e-4f + r2 * 2.7557319e-6f))));
    const float cr = 1.0f + r2 * (-0.5f + r2 * (4.1666667e-2f + r2 * (-1.3888889e-3f + r2 * 2.4801587e-5f)));
    const int q = (int)(k - 4.0f * floorf(k * 0.25f)); /* k mod 4 in 0..3 */
    *s = q == 0 ? sr : (q == 1 ? cr : (q == 2 ? -sr : -cr));
    *c = q == 0 ? cr : (q == 1 ? -sr : (q == 2 ? -cr : sr));
}

static void cross(const float a[3], const float b[3], float out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static float norm3(const float a[3])
{
    return sqrtf(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
}

/* Unit quaternion [w x y z] (normalized here) to row-major R (body to world). */
static void quat_to_R(const float q_in[4], float R[9])
{
    float n = sqrtf(q_in[0] * q_in[0] + q_in[1] * q_in[1] + q_in[2] * q_in[2] + q_in[3] * q_in[3]);
    n = n > 0.0f ? n : 1.0f;
    const float w = q_in[0] / n, x = q_in[1] / n, y = q_in[2] / n, z = q_in[3] / n;
    R[0] = 1.0f - 2.0f * (y * y + z * z);
    R[1] = 2.0f * (x * y - w * z);
    R[2] = 2.0f * (x * z + w * y);
    R[3] = 2.0f * (x * y + w * z);
    R[4] = 1.0f - 2.0f * (x * x + z * z);
    R[5] = 2.0f * (y * z - w * x);
    R[6] = 2.0f * (x * z - w * y);
    R[7] = 2.0f * (y * z + w * x);
    R[8] = 1.0f - 2.0f * (x * x + y * y);
}

/* Rotation matrix to quaternion [w x y z] with w >= 0 (constrained error quaternion). */
static void R_to_quat(const float R[9], float q[4])
{
    const float tr = R[0] + R[4] + R[8];
    if (tr > 0.0f) {
        const float s = 2.0f * sqrtf(tr + 1.0f);
        q[0] = 0.25f * s;
        q[1] = (R[7] - R[5]) / s;
        q[2] = (R[2] - R[6]) / s;
        q[3] = (R[3] - R[1]) / s;
    } else if (R[0] > R[4] && R[0] > R[8]) {
        const float s = 2.0f * sqrtf(1.0f + R[0] - R[4] - R[8]);
        q[0] = (R[7] - R[5]) / s;
        q[1] = 0.25f * s;
        q[2] = (R[1] + R[3]) / s;
        q[3] = (R[2] + R[6]) / s;
    } else if (R[4] > R[8]) {
        const float s = 2.0f * sqrtf(1.0f + R[4] - R[0] - R[8]);
        q[0] = (R[2] - R[6]) / s;
        q[1] = (R[1] + R[3]) / s;
        q[2] = 0.25f * s;
        q[3] = (R[5] + R[7]) / s;
    } else {
        const float s = 2.0f * sqrtf(1.0f + R[8] - R[0] - R[4]);
        q[0] = (R[3] - R[1]) / s;
        q[1] = (R[2] + R[6]) / s;
        q[2] = (R[5] + R[7]) / s;
        q[3] = 0.25f * s;
    }
    if (q[0] < 0.0f) {
        for (int i = 0; i < 4; ++i) {
            q[i] = -q[i];
        }
    }
}

static void motors_off(ns2_ctrl_t *c)
{
    for (int i = 0; i < 4; ++i) {
        c->u[i] = 0.0f;
        c->pwm[i] = 0.0f;
    }
}

/* The controller's memory as after ns2_ctrl_init (the setpoint is kept). */
static void reset_memory(ns2_ctrl_t *c)
{
    for (int i = 0; i < 3; ++i) {
        c->int_v[i] = c->int_w[i] = 0.0f;
        c->w_r_prev[i] = c->w_r_dot[i] = c->we_prev[i] = c->we_dot[i] = 0.0f;
    }
    for (int i = 0; i < 9; ++i) {
        c->R_d[i] = (i % 4 == 0) ? 1.0f : 0.0f;
    }
    c->T_d = c->veh.mass_kg * NS2_G;
    c->T_d_dot = 0.0f;
    c->has_prev_pos = c->has_prev_att = 0;
}

/* A bad input or non-finite memory: motors off, memory reset, recovery restarts. */
static void fault(ns2_ctrl_t *c, uint32_t flag)
{
    reset_memory(c);
    motors_off(c);
    c->recovery_left = NS2_CTRL_RECOVERY_TICKS;
    c->status |= flag | NS2_CTRL_RECOVERING;
}

void ns2_ctrl_init(ns2_ctrl_t *c, const ns2_vehicle_t *veh, const ns2_gains_t *g)
{
    memset(c, 0, sizeof *c);
    c->veh = *veh;
    c->g = *g;
    c->config_ok = config_ok(veh, g);
    reset_memory(c);
    if (!c->config_ok) {
        c->T_d = 0.0f;
        c->status = NS2_CTRL_BAD_CONFIG;
    }
}

void ns2_ctrl_wrench(const ns2_vehicle_t *veh, const float u[4], float eta[4])
{
    const float a = veh->arm_m * 0.70710678f;
    eta[0] = u[0] + u[1] + u[2] + u[3];
    eta[1] = a * (-u[0] - u[1] + u[2] + u[3]);
    eta[2] = a * (-u[0] + u[1] + u[2] - u[3]);
    eta[3] = veh->kappa_m * (-u[0] + u[1] - u[2] + u[3]);
}

/* The checks every position tick begins with: config, state, dt (0: motors off,
 * stop here) and the setpoint (a bad one keeps the last valid). */
static int position_begin(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, float dt)
{
    c->status = 0;
    if (!c->config_ok) {
        c->status = NS2_CTRL_BAD_CONFIG;
        motors_off(c);
        return 0;
    }
    if (!state_ok(s) || !dt_ok(dt)) {
        fault(c, NS2_CTRL_BAD_STATE);
        return 0;
    }
    if (setpoint_ok(sp)) {
        c->sp = *sp;
        c->sp.yaw = fmodf(sp->yaw, 6.28318548f); /* exact; |yaw| < 2 pi for sincos_det */
    } else {
        c->status |= NS2_CTRL_BAD_SETPOINT;
    }
    return 1;
}

static void force_to_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float f_d[3], float dt);

/* eq. (pos_ctrl) with (v_ref); sets T_d, T_d_dot and R_d. */
void ns2_ctrl_position(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                       const float fa_hat[3], float dt)
{
    const ns2_gains_t *g = &c->g;
    const float m = c->veh.mass_kg;
    if (!position_begin(c, s, sp, dt)) {
        return;
    }
    float fa[3] = {0.0f, 0.0f, 0.0f};
    if (fa_hat != NULL && finite_n(fa_hat, 3)) {
        const float n = norm3(fa_hat);
        const float k = n > g->fa_max_N ? g->fa_max_N / n : 1.0f;
        if (k < 1.0f) {
            c->status |= NS2_CTRL_FA_LIMITED;
        }
        for (int i = 0; i < 3; ++i) {
            fa[i] = fa_hat[i] * k;
        }
    }
    float f_d[3];
    for (int i = 0; i < 3; ++i) {
        const float pe = s->p[i] - c->sp.p[i];
        const float v_r = c->sp.v[i] - g->Lp[i] * pe;
        const float v_r_dot = c->sp.a[i] - g->Lp[i] * (s->v[i] - c->sp.v[i]);
        const float ve = s->v[i] - v_r;
        c->int_v[i] = clampf(c->int_v[i] + ve * dt, -g->int_v_max, g->int_v_max);
        f_d[i] = m * v_r_dot - fa[i] - (g->Kv[i] + m * g->Gv[i]) * ve - g->Kv[i] * g->Gv[i] * c->int_v[i];
    }
    f_d[2] += m * NS2_G;
    force_to_attitude(c, s, f_d, dt);
}

void ns2_ctrl_force(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, const float f_d[3], float dt)
{
    if (!position_begin(c, s, sp, dt)) {
        return;
    }
    if (f_d == NULL || !finite_n(f_d, 3) || !within_n(f_d, 3, NS2_CTRL_F_MAX_N)) {
        fault(c, NS2_CTRL_BAD_STATE);
        return;
    }
    float f[3] = {f_d[0], f_d[1], f_d[2]};
    force_to_attitude(c, s, f, dt);
}

/* T_d, T_d_dot and R_d from f_d (f_d . e3 raised to min_thrust_N first). */
static void force_to_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float f_d[3], float dt)
{
    const ns2_gains_t *g = &c->g;
    if (f_d[2] < g->min_thrust_N) {
        f_d[2] = g->min_thrust_N;
    }
    float R[9];
    quat_to_R(s->q, R);
    const float T_new = f_d[0] * R[2] + f_d[1] * R[5] + f_d[2] * R[8]; /* f_d . R e3 */
    if (c->has_prev_pos) {
        const float raw = (T_new - c->T_d) / dt;
        c->T_d_dot += g->d_filter * (raw - c->T_d_dot);
    }
    c->T_d = T_new;
    c->has_prev_pos = 1;
    /* desired attitude: z_d along f_d, x_d towards the yaw setpoint */
    const float fn = norm3(f_d);
    const float z_d[3] = {f_d[0] / fn, f_d[1] / fn, f_d[2] / fn};
    float sy, cy;
    sincos_det(c->sp.yaw, &sy, &cy);
    const float x_c[3] = {cy, sy, 0.0f};
    float y_d[3], x_d[3];
    cross(z_d, x_c, y_d);
    const float yn = norm3(y_d); /* > 0: z_d has a positive z component */
    for (int i = 0; i < 3; ++i) {
        y_d[i] /= yn;
    }
    cross(y_d, z_d, x_d);
    for (int i = 0; i < 3; ++i) {
        c->R_d[3 * i + 0] = x_d[i];
        c->R_d[3 * i + 1] = y_d[i];
        c->R_d[3 * i + 2] = z_d[i];
    }
    if (!finite_n(c->int_v, 3) || !isfinite(c->T_d) || !isfinite(c->T_d_dot) || !finite_n(c->R_d, 9)) {
        fault(c, NS2_CTRL_RESET);
    } else if (c->recovery_left > 0u) {
        c->status |= NS2_CTRL_RECOVERING;
    }
}

/* Motor forces from eta_c, capped as the Crazyflie firmware caps them
 * (power_distribution_quadrotor.c, powerDistributionCap): when a motor would
 * exceed f_max every motor is lowered by the excess, so the torques are kept and
 * the collective thrust gives way; then each force is clamped to [0, f_max].
 * Returns 1 when the command was capped or clamped. */
static int mix(const ns2_vehicle_t *veh, const float eta[4], float u[4])
{
    static const float sx[4] = {-1.0f, -1.0f, 1.0f, 1.0f};
    static const float sy[4] = {-1.0f, 1.0f, 1.0f, -1.0f};
    static const float sz[4] = {-1.0f, 1.0f, -1.0f, 1.0f};
    const float a = veh->arm_m * 0.70710678f;
    const float f_max = veh->f_max_N;
    const float uT = clampf(eta[0], 0.0f, 4.0f * f_max) * 0.25f;
    float highest = 0.0f;
    int clamped = eta[0] > 4.0f * f_max || eta[0] < 0.0f;
    for (int i = 0; i < 4; ++i) {
        u[i] = uT + 0.25f * (sx[i] * eta[1] / a + sy[i] * eta[2] / a + sz[i] * eta[3] / veh->kappa_m);
        if (u[i] > highest) { /* false for NaN: NaN never lowers the motors */
            highest = u[i];
        }
    }
    const float reduction = highest > f_max ? highest - f_max : 0.0f;
    for (int i = 0; i < 4; ++i) {
        const float f = u[i] - reduction;
        clamped |= !(f >= 0.0f && f <= f_max);
        u[i] = clampf(f, 0.0f, f_max);
    }
    return reduction > 0.0f || clamped;
}

static float pwm_of(const ns2_vehicle_t *veh, float u_N, float battery_V)
{
    if (!(u_N > 0.0f)) {
        return 0.0f;
    }
    const float f = u_N * (1000.0f / NS2_G); /* grams */
    const float v = battery_V / 4.2f;
    const float *k = veh->psi2;
    return clampf(k[0] + k[1] * f + k[2] * v + k[3] * f * f + k[4] * f * v, 0.0f, 1.0f);
}

/* eqs. (omega_ref), (att_ctrl), (delay_ctrl). */
void ns2_ctrl_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float dt, float battery_V)
{
    const ns2_gains_t *g = &c->g;
    const float *J = c->veh.inertia;
    if (c->status & (NS2_CTRL_BAD_STATE | NS2_CTRL_RESET | NS2_CTRL_BAD_CONFIG)) {
        motors_off(c); /* until the next good position tick */
        return;
    }
    if (s == NULL || !quat_ok(s->q) || !within_n(s->w, 3, NS2_CTRL_W_MAX_RADS) || !dt_ok(dt) ||
        !(battery_V >= 0.0f && battery_V <= NS2_CTRL_BAT_MAX_V)) {
        fault(c, NS2_CTRL_BAD_STATE);
        return;
    }
    float R[9], Re[9], qe[4];
    quat_to_R(s->q, R);
    for (int i = 0; i < 3; ++i) { /* R~ = R_d^T R */
        for (int j = 0; j < 3; ++j) {
            Re[3 * i + j] = c->R_d[i] * R[j] + c->R_d[3 + i] * R[3 + j] + c->R_d[6 + i] * R[6 + j];
        }
    }
    R_to_quat(Re, qe);
    float w_r[3], we[3], Jw[3], Jw_x_wr[3], tau[3];
    for (int i = 0; i < 3; ++i) { /* w_r = R~^T w_d - Lq q~v */
        w_r[i] = Re[i] * c->sp.w[0] + Re[3 + i] * c->sp.w[1] + Re[6 + i] * c->sp.w[2] - g->Lq[i] * qe[1 + i];
    }
    for (int i = 0; i < 3; ++i) {
        if (c->has_prev_att) {
            c->w_r_dot[i] += g->d_filter * ((w_r[i] - c->w_r_prev[i]) / dt - c->w_r_dot[i]);
        }
        c->w_r_prev[i] = w_r[i];
        we[i] = s->w[i] - w_r[i];
        c->int_w[i] = clampf(c->int_w[i] + we[i] * dt, -g->int_w_max, g->int_w_max);
        if (c->has_prev_att) {
            c->we_dot[i] += g->d_filter * ((we[i] - c->we_prev[i]) / dt - c->we_dot[i]);
        }
        c->we_prev[i] = we[i];
        Jw[i] = J[i] * s->w[i];
    }
    c->has_prev_att = 1;
    cross(Jw, w_r, Jw_x_wr);
    for (int i = 0; i < 3; ++i) {
        tau[i] = J[i] * c->w_r_dot[i] - Jw_x_wr[i] - g->Kw[i] * we[i] - g->Gw[i] * c->int_w[i] -
                 g->Kwd[i] * c->we_dot[i];
    }
    const float eta_c[4] = {c->T_d + c->T_d_dot / c->veh.lambda, tau[0], tau[1], tau[2]};
    if (mix(&c->veh, eta_c, c->u)) {
        c->status |= NS2_CTRL_SATURATED;
    }
    for (int i = 0; i < 4; ++i) {
        c->pwm[i] = pwm_of(&c->veh, c->u[i], battery_V);
    }
    if (!finite_n(c->int_w, 3) || !finite_n(c->w_r_dot, 3) || !finite_n(c->we_dot, 3) ||
        !finite_n(c->w_r_prev, 3) || !finite_n(c->we_prev, 3) || !finite_n(c->u, 4)) {
        fault(c, NS2_CTRL_RESET);
    } else if (c->recovery_left > 0u) {
        c->recovery_left--;
        c->status |= NS2_CTRL_RECOVERING;
    }
}
