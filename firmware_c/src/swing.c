/*
 * swing.c - Swing filter baseline in O(1) time and O(D) memory per sample
 * (see swing.h).
 *
 * Notation as in fastsw.c: for the samples i after the anchor a, t_i and y_i
 * are relative to it (t_i - t_a, y_i - y_a), eps = threshold. Per dimension:
 *
 *   lo_d = max_i (y_id - eps) / t_i,  hi_d = min_i (y_id + eps) / t_i   eq. (S1)
 *
 * A new sample n fits when its own range meets [lo_d, hi_d] in every d.
 * The line chosen on a break has the slope
 *
 *   beta_d = clamp(Sty_d / Stt, lo_d, hi_d)                          eq. (S2)
 *
 * with Stt = sum_i t_i^2, Sty_d = sum_i t_i y_id over a < i <= n-1: the
 * least-squares slope through the anchor, and (the squared error being convex
 * in beta_d) the admissible slope of least squared error.
 * Build with -ffp-contract=off so every target rounds the same way.
 */
#include "swing.h"

#include "fastsw_batch.h"
#include "kernel_common.h"

FastswStatus swing_init(SwingState *state, const FastswSettings *settings)
{
    FastswState probe; /* reuse fastSW's validation and sanitising */
    uint32_t d;

    if (fastsw_init(&probe, settings) != FASTSW_NONE) {
        return FASTSW_BAD_SETTINGS;
    }
    state->settings = probe.settings;
    state->next_index = 0u;
    state->count = 0u;
    state->started = 0u;
    state->anchor = probe.anchor;
    state->prev = probe.prev;
    state->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        state->sty[d] = 0.0f;
        state->lo[d] = 0.0f;
        state->hi[d] = 0.0f;
    }
    return FASTSW_NONE;
}

/** Close the segment at the last accepted sample on the line of eq. (S2); it becomes the anchor. */
static void close_segment(SwingState *s, uint32_t dim, FastswPoint *point)
{
    const float tp = (float)(uint32_t)(s->prev.t - s->anchor.t); /* ticks, > 0 */
    uint32_t d;
    point->index = s->prev.index;
    point->t = s->prev.t;
    for (d = 0u; d < dim; d++) {
        float beta = s->sty[d] / s->stt; /* eq. (S2): least squares ... */
        if (beta < s->lo[d]) {           /* ... clamped to the admissible range */
            beta = s->lo[d];
        }
        if (beta > s->hi[d]) {
            beta = s->hi[d];
        }
        point->y[d] = s->anchor.y[d] + beta * tp;
    }
    for (d = dim; d < FASTSW_MAX_DIM; d++) {
        point->y[d] = 0.0f;
    }
    s->anchor = *point;
    s->count = 0u;
    s->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        s->sty[d] = 0.0f;
    }
}

/** swing_update for a known dim. */
static FastswStatus update(SwingState *s, uint32_t dim, uint32_t t, const float *y, FastswPoint *point)
{
    const uint32_t index = s->next_index++;
    const float eps = s->settings.threshold;
    float yn[FASTSW_MAX_DIM];
    float tn, r;
    FastswStatus status = FASTSW_NONE;
    uint32_t d;

    if (!s->started) {
        status = start_stream(&s->anchor, &s->prev, dim, index, t, y, point);
        s->started = (status == FASTSW_POINT);
        return status;
    }
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    if (!(relative_sample(s->anchor.y, dim, y, yn) <= FASTSW_NN_LIMIT)) {
        return FASTSW_REJECTED;
    }
    tn = (float)(uint32_t)(t - s->anchor.t);
    r = 1.0f / tn;

    if (s->count >= s->settings.max_len) {
        status = FASTSW_POINT;
    } else if (s->count > 0u) {
        for (d = 0u; d < dim; d++) { /* eq. (S1): does sample n's slope range meet [lo, hi]? */
            if ((yn[d] - eps) * r > s->hi[d] || (yn[d] + eps) * r < s->lo[d]) {
                status = FASTSW_POINT;
            }
        }
    }

    if (status == FASTSW_POINT) {
        close_segment(s, dim, point);
        (void)relative_sample(s->anchor.y, dim, y, yn);
        tn = (float)(uint32_t)(t - s->anchor.t);
        r = 1.0f / tn;
    }

    for (d = 0u; d < dim; d++) { /* eq. (S1): swing the bounds */
        const float lo = (yn[d] - eps) * r;
        const float hi = (yn[d] + eps) * r;
        if (s->count == 0u || lo > s->lo[d]) {
            s->lo[d] = lo;
        }
        if (s->count == 0u || hi < s->hi[d]) {
            s->hi[d] = hi;
        }
        s->sty[d] += tn * yn[d];
    }
    s->stt += tn * tn;
    s->count++;
    store_point(&s->prev, dim, index, t, y);
    return status;
}

FastswStatus swing_update(SwingState *state, uint32_t t, const float *y, FastswPoint *point)
{
    return update(state, FASTSW_DIM(&state->settings), t, y, point);
}

FastswStatus swing_flush(SwingState *state, FastswPoint *point)
{
    if (!state->started || state->count == 0u) {
        return FASTSW_NONE;
    }
    close_segment(state, FASTSW_DIM(&state->settings), point);
    return FASTSW_POINT;
}

/** swing_update / swing_flush over an opaque state, for the batch driver. */
static FastswStatus update_any(void *state, uint32_t t, const float *y, FastswPoint *point)
{
    return swing_update((SwingState *)state, t, y, point);
}

static FastswStatus flush_any(void *state, FastswPoint *point)
{
    return swing_flush((SwingState *)state, point);
}

size_t swing_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                    FastswPoint *out, size_t *rejected)
{
    static const FastswKernel kernel = {update_any, flush_any, NULL};
    SwingState state;

    if (swing_init(&state, settings) != FASTSW_NONE) {
        if (rejected != NULL) {
            *rejected = m;
        }
        return 0u;
    }
    {
        const FastswBatchOut batch = {NULL, out, NULL, NULL};
        return fastsw_run_batch(&state, &kernel, FASTSW_DIM(settings), t, y, m, &batch, rejected);
    }
}

size_t swing_state_size(void)
{
    return sizeof(SwingState);
}
