/* ns2_internal.h - helpers shared by the library's translation units. */
#ifndef NS2_INTERNAL_H
#define NS2_INTERNAL_H

#include "ns2_deepset.h"

/* n rounded up to a multiple of four (row blocks and input quads of the kernels) */
#define NS2_PAD4(n) ((((n) + 3) / 4) * 4)

/* Validate the query, build the clamped environment input x_env = [-p; -v] and
 * select the neighbours (their indices into neighbors[] go to idx).
 * Returns info->status. */
int32_t ns2_prepare(uint8_t robot_type, const float p[3], const float v[3],
                    const ns2_neighbor_t *neighbors, uint16_t n_neighbors,
                    float x_env[6], uint16_t idx[NS2_MAX_NEIGHBORS], uint16_t *n_used,
                    ns2_info_t *info);

#endif /* NS2_INTERNAL_H */
