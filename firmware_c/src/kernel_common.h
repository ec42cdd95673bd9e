/*
 * kernel_common.h - helpers every per-sample kernel shares (internal to firmware_c/src).
 */
#ifndef KERNEL_COMMON_H
#define KERNEL_COMMON_H

#include <float.h>

#include "fastsw.h"

/* Largest accepted |y - y_a|^2: keeps |y - y_prev|^2 finite as well. */
#define FASTSW_NN_LIMIT (FLT_MAX / 16.0f)

/* Keeps a rarely taken path out of its caller (whose registers it would otherwise crowd). */
#if defined(__GNUC__)
#define FASTSW_NOINLINE __attribute__((noinline))
#else
#define FASTSW_NOINLINE
#endif

#if defined(FASTSW_FIXED_DIM)
/** A whole sample value, so that copies compile to load/store-multiple. */
typedef struct {
    float v[FASTSW_FIXED_DIM];
} FastswValue;
#endif

/** Copy sample (index, t, y) into *point: a bit copy (NaN payloads and -0 survive). */
static inline void store_point(FastswPoint *point, uint32_t dim, uint32_t index, uint32_t t,
                               const float *y)
{
    point->index = index;
    point->t = t;
#if defined(FASTSW_FIXED_DIM)
    (void)dim;
    *(FastswValue *)point->y = *(const FastswValue *)y;
#else
    {
        uint32_t d;
        for (d = 0u; d < dim; d++) {
            point->y[d] = y[d];
        }
    }
#endif
}

/**
 * Relative sample (eq. 4-5): yn = y - y_a (dim floats); returns |yn|^2, NaN or
 * Inf if y is not finite. The sum starts from the first square (0 + x = x).
 */
static inline float relative_sample(const float *anchor_y, uint32_t dim, const float *y, float *yn)
{
    float nn;
    uint32_t d;
    yn[0] = y[0] - anchor_y[0];
    nn = yn[0] * yn[0];
    for (d = 1u; d < dim; d++) {
        yn[d] = y[d] - anchor_y[d];
        nn += yn[d] * yn[d];
    }
    return nn;
}


/**
 * The first sample of a baseline stream: if |y|^2 is finite it becomes the anchor, the
 * previous sample and a segment point (FASTSW_POINT), else FASTSW_REJECTED.
 */
static inline FastswStatus start_stream(FastswPoint *anchor, FastswPoint *prev, uint32_t dim,
                                        uint32_t index, uint32_t t, const float *y, FastswPoint *point)
{
    float nn = y[0] * y[0];
    uint32_t d;
    for (d = 1u; d < dim; d++) {
        nn += y[d] * y[d];
    }
    if (!(nn <= FASTSW_NN_LIMIT)) { /* NaN, Inf or overflow */
        return FASTSW_REJECTED;
    }
    store_point(anchor, dim, index, t, y);
    *prev = *anchor;
    *point = *anchor;
    return FASTSW_POINT;
}

#endif /* KERNEL_COMMON_H */
