/*
 * fastsw_batch.h - one batch driver for every per-sample kernel (fastSW, SW, CPLR, Swing).
 *
 * A kernel is its update and flush functions over an opaque, initialised state (and, for
 * fastSW's live rule, the rate of the point it emitted). The driver feeds m samples,
 * flushes, and collects the segment points.
 */
#ifndef FASTSW_BATCH_H
#define FASTSW_BATCH_H

#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

/** A per-sample kernel: update(state, t, y, point), flush(state, point), and rate(state,
 * rate) giving the rate of the point just emitted (fastsw_point_rate; NULL: no rates). */
typedef struct {
    FastswStatus (*update)(void *state, uint32_t t, const float *y, FastswPoint *point);
    FastswStatus (*flush)(void *state, FastswPoint *point);
    void (*rate)(const void *state, float *rate);
} FastswKernel;

/** What a batch run writes, point by point; every field may be NULL (capacity m points each). */
typedef struct FastswBatchOut {
    uint32_t *index;     /**< sample index of each point */
    FastswPoint *points; /**< each point */
    uint32_t *call;      /**< the update call that emitted it (its sample position 0..m-1), or m
                              for the flush at the end */
    float *rates;        /**< dim floats per point: its rate (zero where the kernel has none) */
} FastswBatchOut;

/**
 * Feed m samples (t: m ticks, y: m x dim floats) to an initialised state, then flush,
 * writing the points into *out. *rejected (may be NULL) gets the rejected-sample count.
 * Returns the number of points K <= m.
 */
size_t fastsw_run_batch(void *state, const FastswKernel *kernel, uint32_t dim, const uint32_t *t,
                        const float *y, size_t m, const FastswBatchOut *out, size_t *rejected);

#ifdef __cplusplus
}
#endif

#endif /* FASTSW_BATCH_H */
