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
 *   capped as the firmware's powerDistributionCap: a motor over f_max lowers
 *   every motor by the excess (torques kept, collective thrust gives way), then
 *   each u_i is clamped to [0, f_max].
 *   PWM = psi_2(u_i in grams, V / 4.2) (Table cfprops), clamped to [0, 1].
 *
 * Units: SI (m, m/s, rad, N, N m, kg); fa_hat in newtons, world frame.
 * Quadrotor X: motor i at (x_i, y_i) = arm / sqrt(2) * [(+,-), (-,-), (-,+), (+,+)]
 * (Crazyflie M1..M4), yaw torque +-k f_i with signs [-, +, -, +].
 *
 * Safety (defined outputs, never undefined behaviour; every input is checked
 * against the physical limits NS2_CTRL_*_MAX below, not only for NaN/Inf):
 *   - bad state (non-finite or beyond the limits, quaternion norm outside
 *     [0.5, 2], dt outside [NS2_CTRL_DT_MIN_S, NS2_CTRL_DT_MAX_S], battery
 *     voltage outside [0, NS2_CTRL_BAT_MAX_V]): all motors off (u = 0, PWM = 0), status
 *     NS2_CTRL_BAD_STATE, and the controller's memory (integrators, filtered
 *     derivatives) is reset to that of ns2_ctrl_init;
 *   - bad setpoint (non-finite or beyond the limits): the last valid setpoint is
 *     kept, NS2_CTRL_BAD_SETPOINT; the yaw setpoint is taken modulo 2 pi;
 *   - non-finite fa_hat: treated as 0; |fa_hat| limited to fa_max (NS2_CTRL_FA_LIMITED);
 *   - integrators are clamped (int_v_max, int_w_max); f_d keeps a minimum
 *     upward component so that R_d is always defined;
 *   - should the controller's memory ever become non-finite all the same, it is
 *     reset as for a bad state (NS2_CTRL_RESET, motors off for that tick);
 *   - vehicle parameters that cannot fly (mass, inertia, arm, kappa, lambda,
 *     f_max not finite and > 0, psi2 not finite): NS2_CTRL_BAD_CONFIG, motors off.
 * Recovery is bounded: after a bad state or a reset the controller is exactly a
 * freshly initialized one (its outputs from the next good position tick on are
 * bit for bit those of ns2_ctrl_init + the same good inputs), and it reports
 * NS2_CTRL_RECOVERING until NS2_CTRL_RECOVERY_TICKS good attitude ticks have
 * run (the derivative filters have restarted).
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
#define NS2_CTRL_RESET 16u       /* non-finite memory was reset this tick */
#define NS2_CTRL_RECOVERING 32u  /* fewer than NS2_CTRL_RECOVERY_TICKS good ticks since a fault */
#define NS2_CTRL_BAD_CONFIG 64u  /* vehicle parameters unusable: motors stay off */

/* Physical limits of the inputs (beyond them an input is treated as corrupt). */
#define NS2_CTRL_P_MAX_M 1.0e3f       /* |position| per axis, state and setpoint */
#define NS2_CTRL_V_MAX_MS 1.0e2f      /* |velocity| per axis */
#define NS2_CTRL_A_MAX_MS2 1.0e3f     /* |acceleration setpoint| per axis */
#define NS2_CTRL_W_MAX_RADS 1.0e2f    /* |body rate| per axis (gyro range 35 rad/s) */
#define NS2_CTRL_YAW_MAX_RAD 1.0e6f   /* |yaw setpoint| (then taken modulo 2 pi) */
#define NS2_CTRL_DT_MIN_S 1.0e-5f     /* time step range of both loops */
#define NS2_CTRL_DT_MAX_S 1.0f
#define NS2_CTRL_BAT_MAX_V 10.0f      /* battery voltage range [0, 10] V */
#define NS2_CTRL_F_MAX_N 1.0e2f       /* |f_d| per axis given to ns2_ctrl_force */
#define NS2_CTRL_RECOVERY_TICKS 50u   /* attitude ticks (0.1 s at 500 Hz) */

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
    uint32_t recovery_left; /* good attitude ticks still to run after a fault */
    int config_ok;          /* vehicle parameters usable */
} ns2_ctrl_t;

void ns2_ctrl_init(ns2_ctrl_t *c, const ns2_vehicle_t *veh, const ns2_gains_t *g);
/* 100 Hz: f_d, T_d, R_d; fa_hat (N, world frame, may be NULL = baseline). */
void ns2_ctrl_position(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp,
                       const float fa_hat[3], float dt);
/* 100 Hz, for another position law (the simulator's replay of the controller that
 * flew the real flights, paper/c/ctrl_authors.c): T_d, T_d_dot and R_d from a desired
 * force f_d (N, world frame, gravity included) as ns2_ctrl_position does from its
 * own; the same checks of config, state, dt and setpoint (its yaw sets R_d), and a
 * non-finite f_d or one beyond NS2_CTRL_F_MAX_N per axis is a bad state. */
void ns2_ctrl_force(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, const ns2_setpoint_t *sp, const float f_d[3], float dt);
/* 500 Hz: tau_d, delay compensation, mixing and PWM (battery voltage in V). */
void ns2_ctrl_attitude(ns2_ctrl_t *c, const ns2_ctrl_state_t *s, float dt, float battery_V);
/* eta = B0 u for motor forces u (N): [T, tau_x, tau_y, tau_z]. */
void ns2_ctrl_wrench(const ns2_vehicle_t *veh, const float u[4], float eta[4]);

#ifdef __cplusplus
}
#endif

#endif /* NS2_CONTROLLER_H */
