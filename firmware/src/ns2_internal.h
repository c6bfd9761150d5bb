/* ns2_internal.h - helpers shared by the library's translation units. */
#ifndef NS2_INTERNAL_H
#define NS2_INTERNAL_H

#include "ns2_deepset.h"

/* Weight-table placement.  By default the generated tables are const data in
 * flash (.rodata).  -DNS2_RAM_Q15_PHI / _Q15_RHO / _F32_PHI / _F32_RHO put the
 * phi or rho tables of the fixed-point or float path into the initialised-data
 * section .data.ns2_tables instead: the linker places it in SRAM with its
 * initial values in flash, and the start-up code copies it (Crazyflie's and
 * firmware/target's linker scripts both collect .data.* into .data).  SRAM has
 * no wait states; flash at 168 MHz has five behind the ART accelerator, whose
 * 8-line data cache cannot hold a streamed table (docs/target.md).  The values,
 * and so every result, are the same wherever the tables are. */
#define NS2_RAM_TABLE __attribute__((section(".data.ns2_tables")))
#ifdef NS2_RAM_Q15_PHI
#define NS2_TABLE_Q15_PHI NS2_RAM_TABLE
#endif
#ifdef NS2_RAM_Q15_RHO
#define NS2_TABLE_Q15_RHO NS2_RAM_TABLE
#endif
#ifdef NS2_RAM_F32_PHI
#define NS2_TABLE_F32_PHI NS2_RAM_TABLE
#endif
#ifdef NS2_RAM_F32_RHO
#define NS2_TABLE_F32_RHO NS2_RAM_TABLE
#endif

/* n rounded up to a multiple of four (row blocks and input quads of the kernels) */
#define NS2_PAD4(n) ((((n) + 3) / 4) * 4)

/* Validate the query, build the clamped environment input x_env = [-p; -v]
 * (then -own_past with history) and select the neighbours (their indices into
 * neighbors[] go to idx).  Returns info->status. */
int32_t ns2_prepare(uint8_t robot_type, const float p[3], const float v[3], const float *own_past,
                    const ns2_neighbor_t *neighbors, uint16_t n_neighbors,
                    float x_env[NS2_INPUT_DIM], uint16_t idx[NS2_MAX_NEIGHBORS], uint16_t *n_used,
                    ns2_info_t *info);

/* ns2_job_t.path: not begun or failed (a zeroed job is not begun); stepped by
 * f32 / q15; begun but not stepped yet */
#define NS2_JOB_NONE 0u
#define NS2_JOB_F32 1u
#define NS2_JOB_Q15 2u
#define NS2_JOB_FRESH 3u

/* 1 when the job may be stepped by path (NS2_JOB_F32/_Q15): begun without
 * error and not stepped by the other path (the first step claims it). */
int ns2_job_claim(ns2_job_t *job, uint8_t path);

/* Copy the job's counters and status to info (may be NULL); status NS2_ERR_JOB
 * for a NULL job, or for one that could not be claimed but has no error of its own. */
void ns2_job_info(const ns2_job_t *job, int claimed, ns2_info_t *info);

#endif /* NS2_INTERNAL_H */
