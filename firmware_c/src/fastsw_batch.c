/*
 * fastsw_batch.c - the batch driver shared by every kernel (see fastsw_batch.h).
 */
#include "fastsw_batch.h"

/** Store point number k, emitted by update call `call`, into the outputs; its rate from the kernel. */
static void collect(const FastswBatchOut *out, const FastswKernel *kernel, const void *state,
                    uint32_t dim, size_t k, const FastswPoint *point, size_t call)
{
    uint32_t d;
    if (out->index != NULL) {
        out->index[k] = point->index;
    }
    if (out->points != NULL) {
        out->points[k] = *point;
    }
    if (out->call != NULL) {
        out->call[k] = (uint32_t)call;
    }
    if (out->rates != NULL) {
        if (kernel->rate != NULL) {
            kernel->rate(state, out->rates + k * dim);
        } else {
            for (d = 0u; d < dim; d++) {
                out->rates[k * dim + d] = 0.0f;
            }
        }
    }
}

size_t fastsw_run_batch(void *state, const FastswKernel *kernel, uint32_t dim, const uint32_t *t,
                        const float *y, size_t m, const FastswBatchOut *out, size_t *rejected)
{
    FastswPoint point;
    size_t i, k = 0u, bad = 0u;

    for (i = 0u; i < m; i++) {
        const FastswStatus status = kernel->update(state, t[i], y + i * dim, &point);
        if (status == FASTSW_POINT) {
            collect(out, kernel, state, dim, k++, &point, i);
        } else if (status == FASTSW_REJECTED) {
            bad++;
        }
    }
    if (k < m && kernel->flush(state, &point) == FASTSW_POINT) {
        collect(out, kernel, state, dim, k++, &point, m);
    }
    if (rejected != NULL) {
        *rejected = bad;
    }
    return k;
}
