/*
 * fastsw_batch.c - the batch driver shared by every kernel (see fastsw_batch.h).
 */
#include "fastsw_batch.h"

/** Store point number k into the caller's outputs. */
static void collect(const FastswPoint *point, size_t k, uint32_t *out_index, FastswPoint *out_points)
{
    if (out_index != NULL) {
        out_index[k] = point->index;
    }
    if (out_points != NULL) {
        out_points[k] = *point;
    }
}

size_t fastsw_run_batch(void *state, const FastswKernel *kernel, uint32_t dim, const uint32_t *t,
                        const float *y, size_t m, uint32_t *out_index, FastswPoint *out_points,
                        size_t *rejected)
{
    FastswPoint point;
    size_t i, k = 0u, bad = 0u;

    for (i = 0u; i < m; i++) {
        const FastswStatus status = kernel->update(state, t[i], y + i * dim, &point);
        if (status == FASTSW_POINT) {
            collect(&point, k++, out_index, out_points);
        } else if (status == FASTSW_REJECTED) {
            bad++;
        }
    }
    if (k < m && kernel->flush(state, &point) == FASTSW_POINT) {
        collect(&point, k++, out_index, out_points);
    }
    if (rejected != NULL) {
        *rejected = bad;
    }
    return k;
}
