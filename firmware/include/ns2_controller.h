/*
 * ns2_controller.h - interaction-aware tracking controller with motor-delay
 * compensation (Neural-Swarm2, section "Interaction-Aware Tracking Controller").
 *
 * Position loop (call at 100 Hz), eqs. (v_ref), (pos_ctrl):
 *   v_r = pd_dot - Lp (p - pd)
 *   f_d = m g e3 + m v_r_dot - fa_hat - (Kv + m Gv) v~ - Kv Gv int(v~),  v~ = v - v_r
 *   T_d = f_d . R e3,  R_d from the direction of f_d and the yaw setpoint,
 *   T_d_dot by numerical differentiation (for the delay compensation).
 * Attitude loop (call at 500 Hz), eqs. (omega_ref), (att_ctrl):
 *   q~ = quat(R_d^T R) with q~0 >= 0,  w_r = R~^T w_d - Lq q~v,
 *   tau_d = J w_r_dot - (J w) x w_r - Kw w~ - Gw int(w~) - Kwd d(w~)/dt
 *   (the Kwd term approximates tau_d_dot / lambda, experiments section).
 * Delay compensation and mixing, eq. (delay_ctrl):
 *   eta_c = [T_d + T_d_dot / lambda; tau_d],  u = B0^-1 eta_c  (motor forces, N)
 *   with thrust priority: the collective thrust is kept (clamped to what four
 *   motors can give) and the torque part scaled down until 0 <= u_i <= f_max.
 *   PWM = psi_2(u_i in grams, V / 4.2) (Table cfprops), clamped to [0, 1].
 *
 * Units: SI (m, m/s, rad, N, N m, kg); fa_hat in newtons, world frame.
 * Quadrotor X: motor i at (x_i, y_i) = arm / sqrt(2) * [(+,-), (-,-), (-,+), (+,+)]
 * (Crazyflie M1..M4), yaw torque +-k f_i with signs [-, +, -, +].
 *
 * Safety (defined outputs, never undefined behaviour):
 *   - non-finite state: all motors off (u = 0, PWM = 0), status NS2_CTRL_BAD_STATE;
 *   - non-finite setpoint: the last valid setpoint is kept, NS2_CTRL_BAD_SETPOINT;
 *   - non-finite fa_hat: treated as 0; |fa_hat| limited to fa_max (NS2_CTRL_FA_LIMITED);
 *   - integrators are clamped (int_v_max, int_w_max); f_d keeps a minimum
 *     upward component so that R_d is always defined.
 */
#ifndef NS2_CONTROLLER_H
#define NS2_CONTROLLER_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Standard gravity (m/s^2) of the controller, the app and the simulator's C kernel:
 * the one value in C, equal to the Python side's ns2codegen.vehicle.G (checked by
 * tests/test_layers.py). */
#define NS2_G_MPS2 9.81

#define NS2_CTRL_OK 0
#define NS2_CTRL_BAD_STATE 1u
#define NS2_CTRL_BAD_SETPOINT 2u
#define NS2_CTRL_FA_LIMITED 4u
#define NS2_CTRL_SATURATED 8u

typedef struct {
    float mass_kg;
    float inertia[3];       /* kg m^2, principal */
    float arm_m;            /* center to motor */
    float kappa_m;          /* yaw torque per thrust, m */
    float lambda;           /* motor delay constant, 1/s */
    float f_max_N;          /* per motor */
    float psi2[5];          /* PWM from (force g, V/4.2): 1, f, v, f^2, f v */
} ns2_vehicle_t;

typedef struct {
    float Lp[3];            /* 1/s */
    float Kv[3];            /* N s/m */
    float Gv[3];            /* 1/s */
    float Lq[3];            /* 1/s */
    float Kw[3];            /* N m s */
    float Gw[3];            /* N m */
    float Kwd[3];           /* N m s^2 */
    float int_v_max;        /* m, per axis */
    float int_w_max;        /* rad, per axis */
    float fa_max_N;         /* limit of the learned force */
    float min_thrust_N;     /* lower bound of f_d . e3 */
    float d_filter;         /* low-pass weight of numerical derivatives, (0, 1] */
} ns2_gains_t;

typedef struct {
    float p[3], v[3];       /* world */
    float q[4];             /* attitude quaternion, body to world, [w x y z] */
    float w[3];             /* body rates, rad/s */
} ns2_ctrl_state_t;

typedef struct {
    float p[3], v[3], a[3]; /* desired position, velocity, acceleration */
    float yaw;              /* rad */
    float w[3];             /* desired body rates (feed-forward), rad/s */
} ns2_setpoint_t;

typedef struct {
    ns2_vehicle_t veh;
    ns2_gains_t g;
    ns2_setpoint_t sp;      /* last valid setpoint */
    float int_v[3];
    float int_w[3];
    float R_d[9];           /* desired attitude, row-major */
    float T_d, T_d_dot;
    float w_r_prev[3], w_r_dot[3];
    float we_prev[3], we_dot[3];
    int has_prev_pos, has_prev_att;
    float u[4];             /* motor forces, N */
    float pwm[4];           /* normalized PWM in [0, 1] */
    uint32_t status;        /* NS2_CTRL_* flags of the last calls */
} ns2_ctrl_t;

void ns2_ctrl_init(ns2_ctrl_t *c, const ns2_vehicle_t *veh, const ns2_gains_t *g);
/* 100 Hz: f_d, T_d, R_d; fa_hat (N, world frame, may be NULL = baseline). */
void ns2_ctrl_position(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                       const float fa_hat[3], float dt);
/* 500 Hz: tau_d, delay compensation, mixing and PWM (battery voltage in V). */
void ns2_ctrl_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float dt, float battery_V);
/* eta = B0 u for motor forces u (N): [T, tau_x, tau_y, tau_z]. */
void ns2_ctrl_wrench(const ns2_vehicle_t *veh, const float u[4], float eta[4]);

#ifdef __cplusplus
}
#endif

#endif /* NS2_CONTROLLER_H */
