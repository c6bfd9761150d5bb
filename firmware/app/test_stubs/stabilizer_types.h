#pragma once
#include <stdbool.h>
#include <stdint.h>
typedef union { struct { float x; float y; float z; }; float axis[3]; } Axis3f; /* imu_types.h */
typedef struct { uint32_t timestamp; float roll; float pitch; float yaw; } attitude_t;
struct vec3_s { uint32_t timestamp; float x; float y; float z; };
typedef struct vec3_s point_t;
typedef struct vec3_s velocity_t;
typedef struct vec3_s acc_t;
typedef struct {
    uint32_t timestamp;
    union { struct { float q0; float q1; float q2; float q3; }; struct { float x; float y; float z; float w; }; };
} quaternion_t;
typedef struct {
    attitude_t attitude;
    quaternion_t attitudeQuaternion;
    point_t position;
    velocity_t velocity;
    acc_t acc;
} state_t;
typedef struct { Axis3f acc; Axis3f gyro; Axis3f mag; uint64_t interruptTimestamp; } sensorData_t; /* fields used */
typedef enum { modeDisable = 0, modeAbs, modeVelocity } stab_mode_t;
typedef struct {
    uint32_t timestamp;
    attitude_t attitude;      /* deg */
    attitude_t attitudeRate;  /* deg/s */
    quaternion_t attitudeQuaternion;
    float thrust;
    point_t position;         /* m */
    velocity_t velocity;      /* m/s */
    acc_t acceleration;       /* m/s^2 */
    bool velocity_body;
    struct { stab_mode_t x, y, z, roll, pitch, yaw, quat; } mode;
} setpoint_t;
#define STABILIZER_NR_OF_MOTORS 4
typedef enum { controlModeLegacy = 0, controlModeForceTorque = 1, controlModeForce = 2 } control_mode_t;
typedef struct {
    union {
        struct { int16_t roll; int16_t pitch; int16_t yaw; float thrust; };
        struct { float thrustSi; union { float torque[3]; struct { float torqueX; float torqueY; float torqueZ; }; }; };
        float normalizedForces[STABILIZER_NR_OF_MOTORS]; /* 0.0 ... 1.0 */
    };
    control_mode_t controlMode;
} control_t;
#define RATE_500_HZ 500
#define RATE_100_HZ 100
#define RATE_MAIN_LOOP 1000
#define RATE_DO_EXECUTE(RATE_HZ, TICK) ((TICK) % (RATE_MAIN_LOOP / (RATE_HZ)) == 0)
