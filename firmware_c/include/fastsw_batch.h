/*
 * fastsw_batch.h - one batch driver for every per-sample kernel (fastSW, SW, CPLR, Swing).
 *
 * A kernel is its update and flush functions over an opaque, initialised state. The
 * driver feeds m samples, flushes, and collects the segment points.
 */
#ifndef FASTSW_BATCH_H
#define FASTSW_BATCH_H

#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

/** A per-sample kernel: update(state, t, y, point) and flush(state, point). */
typedef struct {
    FastswStatus (*update)(void *state, uint32_t t, const float *y, FastswPoint *point);
    FastswStatus (*flush)(void *state, FastswPoint *point);
} FastswKernel;

/**
 * Feed m samples (t: m ticks, y: m x dim floats) to an initialised state, then flush.
 * Writes each point's sample index to out_index and/or the point to out_points (either
 * may be NULL; capacity m each). *rejected (may be NULL) gets the rejected-sample count.
 * Returns the number of points K <= m.
 */
size_t fastsw_run_batch(void *state, const FastswKernel *kernel, uint32_t dim, const uint32_t *t,
                        const float *y, size_t m, uint32_t *out_index, FastswPoint *out_points,
                        size_t *rejected);

#ifdef __cplusplus
}
#endif

#endif /* FASTSW_BATCH_H */
