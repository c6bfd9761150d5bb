#pragma once
#include <stdint.h>
typedef struct { uint32_t timestamp; float x; float y; float z; } point_t;
typedef struct { uint32_t timestamp; float x; float y; float z; } velocity_t;
typedef struct { point_t position; velocity_t velocity; } state_t;      /* fields used */
typedef struct { uint32_t timestamp; point_t position; } setpoint_t;    /* fields used */
typedef struct { uint64_t interruptTimestamp; } sensorData_t;          /* fields used */
typedef enum { controlModeLegacy = 0 } control_mode_t;
typedef struct {
    int16_t roll;
    int16_t pitch;
    int16_t yaw;
    float thrust;
    control_mode_t controlMode;
} control_t; /* the legacy-mode members of the firmware's union */
#define RATE_100_HZ 100
#define RATE_MAIN_LOOP 1000
#define RATE_DO_EXECUTE(RATE_HZ, TICK) ((TICK) % (RATE_MAIN_LOOP / (RATE_HZ)) == 0)
