/* ns2_app_config.h - inference paths compiled into the app: NS2_APP_FIXED,
 * NS2_APP_FLOAT (0/1; the Makefile's NS2_INFER=fixed|float|both).  Fixed point
 * only by default: both paths do not fit the flash budget (docs/app.md). */
#ifndef NS2_APP_CONFIG_H
#define NS2_APP_CONFIG_H

#ifndef NS2_APP_FIXED
#define NS2_APP_FIXED 1
#endif
#ifndef NS2_APP_FLOAT
#define NS2_APP_FLOAT 0
#endif
#if !NS2_APP_FIXED && !NS2_APP_FLOAT
#error "ns2 app: no inference path (NS2_INFER=fixed, float or both)"
#endif
/* the drone's code path (ns2_pilot) uses the paths compiled in */
#define NS2_PILOT_Q15 NS2_APP_FIXED
#define NS2_PILOT_F32 NS2_APP_FLOAT

#endif /* NS2_APP_CONFIG_H */
