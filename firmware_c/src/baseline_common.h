/*
 * baseline_common.h - what the baselines (sw.c, cplr.c, swing.c) share (internal to
 * firmware_c/src): their stream's start and the opening of every update, and their entry points
 * for the batch driver (fastsw_batch.h).
 */
#ifndef BASELINE_COMMON_H
#define BASELINE_COMMON_H

#include "baselines.h"
#include "fastsw_batch.h"
#include "kernel_common.h"

/**
 * A new stream of a baseline: fastSW's validation and sanitising of the settings (max_len
 * capped at max_len_cap), no sample yet. FASTSW_NONE or FASTSW_BAD_SETTINGS.
 */
static inline FastswStatus baseline_init(BaselineStream *s, const FastswSettings *settings,
                                         uint32_t max_len_cap)
{
    FastswSettings capped = *settings;
    FastswState probe;

    if (capped.max_len > max_len_cap) {
        capped.max_len = max_len_cap;
    }
    if (fastsw_init(&probe, &capped) != FASTSW_NONE) {
        return FASTSW_BAD_SETTINGS;
    }
    s->settings = probe.settings;
    s->next_index = 0u;
    s->count = 0u;
    s->started = 0u;
    s->anchor = probe.anchor;
    s->prev = probe.prev;
    return FASTSW_NONE;
}

/**
 * The opening of every baseline update, for sample ``index`` (t ticks, y of dim floats): the
 * stream's first sample becomes its anchor and first point (FASTSW_POINT; FASTSW_REJECTED if it
 * is not finite); after it, a tick not after the previous accepted one, or a y whose
 * |y - y_a|^2 is not finite (eq. 4-5), is FASTSW_REJECTED. FASTSW_NONE: the sample goes on to
 * the kernel's own test, with yn = y - y_a (dim floats) and *nn = |yn|^2.
 */
static inline FastswStatus baseline_open(BaselineStream *s, uint32_t dim, uint32_t index, uint32_t t,
                                         const float *y, FastswPoint *point, float *yn, float *nn)
{
    if (!s->started) {
        const FastswStatus status = start_stream(&s->anchor, &s->prev, dim, index, t, y, point);
        s->started = (status == FASTSW_POINT);
        return status;
    }
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    *nn = relative_sample(s->anchor.y, dim, y, yn);
    return (*nn <= FASTSW_NN_LIMIT) ? FASTSW_NONE : FASTSW_REJECTED;
}

/**
 * A line-fitting baseline closes its segment at the last accepted sample: the point gets that
 * sample's index and tick; returns its time after the anchor (ticks, > 0), where the kernel
 * puts the point's value on its line.
 */
static inline float baseline_point_at_prev(const BaselineStream *s, FastswPoint *point)
{
    point->index = s->prev.index;
    point->t = s->prev.t;
    return (float)(uint32_t)(s->prev.t - s->anchor.t);
}

/** The point (its first dim values set) becomes the anchor of a new, empty segment. */
static inline void baseline_new_segment(BaselineStream *s, uint32_t dim, FastswPoint *point)
{
    uint32_t d;
    for (d = dim; d < FASTSW_MAX_DIM; d++) {
        point->y[d] = 0.0f;
    }
    s->anchor = *point;
    s->count = 0u;
}

/**
 * ``prefix``_update_any and ``prefix``_flush_any: a baseline's update and flush over an opaque
 * state (of type ``State``), as the batch driver calls them.
 */
#define BASELINE_BATCH_ADAPTERS(prefix, State)                                                     \
    static FastswStatus prefix##_update_any(void *state, uint32_t t, const float *y, FastswPoint *point) \
    {                                                                                              \
        return prefix##_update((State *)state, t, y, point);                                       \
    }                                                                                              \
    static FastswStatus prefix##_flush_any(void *state, FastswPoint *point)                        \
    {                                                                                              \
        return prefix##_flush((State *)state, point);                                              \
    }

/**
 * The entry points a line-fitting baseline (CPLR, Swing) declares in baselines.h, over its
 * file's static ``update(state, dim, t, y, point)`` and ``close_segment(state, dim, point)``
 * (the line's value at the last accepted sample becomes the point and the next anchor):
 * ``prefix``_update, _flush, _segment (the batch driver) and _state_size.
 */
#define BASELINE_ENTRY_POINTS(prefix, State)                                                       \
    FastswStatus prefix##_update(State *state, uint32_t t, const float *y, FastswPoint *point)      \
    {                                                                                              \
        return update(state, FASTSW_DIM(&state->stream.settings), t, y, point);                    \
    }                                                                                              \
    FastswStatus prefix##_flush(State *state, FastswPoint *point)                                  \
    {                                                                                              \
        if (!state->stream.started || state->stream.count == 0u) {                                 \
            return FASTSW_NONE;                                                                    \
        }                                                                                          \
        close_segment(state, FASTSW_DIM(&state->stream.settings), point);                          \
        return FASTSW_POINT;                                                                       \
    }                                                                                              \
    BASELINE_BATCH_ADAPTERS(prefix, State)                                                         \
    size_t prefix##_segment(const FastswSettings *settings, const uint32_t *t, const float *y,     \
                            size_t m, FastswPoint *out, size_t *rejected)                          \
    {                                                                                              \
        static const FastswKernel kernel = {prefix##_update_any, prefix##_flush_any, NULL};        \
        const FastswBatchOut batch = {NULL, out, NULL, NULL};                                      \
        State state;                                                                               \
        if (prefix##_init(&state, settings) != FASTSW_NONE) {                                      \
            if (rejected != NULL) {                                                                \
                *rejected = m;                                                                     \
            }                                                                                      \
            return 0u;                                                                             \
        }                                                                                          \
        return fastsw_run_batch(&state, &kernel, FASTSW_DIM(settings), t, y, m, &batch, rejected); \
    }                                                                                              \
    size_t prefix##_state_size(void)                                                               \
    {                                                                                              \
        return sizeof(State);                                                                      \
    }

#endif /* BASELINE_COMMON_H */
