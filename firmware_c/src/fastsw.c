/*
 * fastsw.c - fastSW in O(1) time and O(D) memory per sample.
 *
 * Notation (paper, Sect. 4): the anchor a is the last segment point; for
 * the samples i after it, t_i and y_i are taken relative to the anchor
 * (t_i - t_a, y_i - y_a). The temporary segment to the newest sample n has
 * slope beta_d = y_nd / t_n (eq. 7). Its SSR over the samples a < i <= n is
 *
 *   SSR = sum_i sum_d (y_id - beta_d t_i)^2                         eq. (9)
 *       = Syy - 2 sum_d beta_d Sty_d + |beta|^2 Stt                 eq. (13)
 *
 * with Syy = sum_i |y_i|^2, Sty_d = sum_i t_i y_id, Stt = sum_i t_i^2. Only
 * the *total* Syy over dimensions is needed (Algorithm 1 keeps one per
 * dimension): D + 2 running sums. Sample n's own residual is exactly 0, so
 * the sums cover a < i <= n-1 and sample n is added after the test, which
 * avoids cancelling its terms. Multiplying by t_n^2 > 0 removes every
 * division:
 *
 *   SSR > TH  <=>  t_n^2 Syy - 2 t_n (y_n . Sty) + |y_n|^2 Stt > TH t_n^2
 *
 * Sums, not running means: magnitudes stay bounded (|y_i| <= 2 for
 * quaternions, max_len <= 2^24), and sums need no division per sample.
 * Build with -ffp-contract=off so every target rounds the same way.
 *
 * Kept short for the Cortex-M4 (docs/kernel.md, instruction counts): sums
 * start from their first term, not from 0 + term (this can only change the
 * sign of a zero, which no later +, *, or comparison can tell apart); the
 * first sample and a full segment share one test on count (UINT32_MAX
 * before the first sample); a break leaves through its own path.
 */
#include "fastsw.h"
#include "fastsw_batch.h"
#include "kernel_common.h"

/* count of a stream before its first accepted sample (>= any max_len) */
#define FASTSW_NOT_STARTED UINT32_MAX

const FastswSettings fastsw_default_settings = {1e-2f, 1000u, 4u};

/** Threshold as used: NaN and negative values become 0 (any deviation breaks). */
static float sanitized_threshold(float threshold)
{
    return (threshold >= 0.0f) ? threshold : 0.0f;
}

/** max_len as used: at least 1 sample per segment. */
static uint32_t sanitized_max_len(uint32_t max_len)
{
    return (max_len > 0u) ? max_len : 1u;
}

FastswStatus fastsw_init(FastswState *state, const FastswSettings *settings)
{
    uint32_t d;

    if (settings->dim == 0u || settings->dim > FASTSW_MAX_DIM) {
        return FASTSW_BAD_SETTINGS;
    }
#if defined(FASTSW_FIXED_DIM)
    if (settings->dim != (uint32_t)FASTSW_FIXED_DIM) {
        return FASTSW_BAD_SETTINGS;
    }
#endif
    state->settings = *settings;
    fastsw_retune(state, settings->threshold, settings->max_len);
    state->next_index = 0u;
    state->count = FASTSW_NOT_STARTED;
    state->syy = 0.0f;
    state->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        state->sty[d] = 0.0f;
        state->anchor.y[d] = 0.0f;
        state->prev.y[d] = 0.0f;
    }
    state->anchor.index = state->prev.index = 0u;
    state->anchor.t = state->prev.t = 0u;
    return FASTSW_NONE;
}

void fastsw_retune(FastswState *state, float threshold, uint32_t max_len)
{
    state->settings.threshold = sanitized_threshold(threshold);
    state->settings.max_len = sanitized_max_len(max_len);
}

/**
 * Segment break at sample n: s_{n-1} becomes the segment point and the new
 * anchor, and the running sums restart with sample n alone (eq. 10-12 from
 * zero sums: 0 + x = x up to the sign of a zero, so they are set directly).
 */
static inline FastswStatus restart(FastswState *s, uint32_t dim, uint32_t index, uint32_t t,
                                   const float *y, FastswPoint *point)
{
    float yn[FASTSW_MAX_DIM];
    float tn;
    uint32_t d;

    *point = s->prev;
    s->anchor = s->prev;
    tn = (float)(uint32_t)(t - s->anchor.t); /* eq. (4) */
    s->syy = relative_sample(s->anchor.y, dim, y, yn);
    s->stt = tn * tn;
    for (d = 0u; d < dim; d++) {
        s->sty[d] = tn * yn[d];
    }
    s->count = 1u;
    store_point(&s->prev, dim, index, t, y);
    return FASTSW_POINT;
}

/**
 * The rare cases, all with count >= max_len: the first sample of a stream
 * (count == FASTSW_NOT_STARTED; it becomes a segment point and the anchor,
 * whose y was 0, so nn = |y|^2 was checked), a time step that is not positive,
 * or a segment that reached max_len.
 */
static FastswStatus long_segment(FastswState *s, uint32_t t, const float *y, FastswPoint *point)
{
    const uint32_t dim = FASTSW_DIM(&s->settings);
    const uint32_t index = s->next_index - 1u;

    if (s->count == FASTSW_NOT_STARTED) {
        store_point(&s->anchor, dim, index, t, y);
        s->prev = s->anchor;
        s->count = 0u;
        *point = s->anchor;
        return FASTSW_POINT;
    }
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    return restart(s, dim, index, t, y, point);
}

/** fastsw_update for a known dim (inlined with a constant dim where fixed). */
static inline FastswStatus update(FastswState *s, uint32_t dim, uint32_t t, const float *y,
                                  FastswPoint *point)
{
    const uint32_t index = s->next_index++;
    float yn[FASTSW_MAX_DIM];
    float tn, tt, nn, dot;
    uint32_t d;

    nn = relative_sample(s->anchor.y, dim, y, yn); /* eq. (5) */
    if (!(nn <= FASTSW_NN_LIMIT)) {                /* NaN, Inf or overflow */
        return FASTSW_REJECTED;
    }
    if (s->count >= s->settings.max_len) {
        return long_segment(s, t, y, point);
    }
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    tn = (float)(uint32_t)(t - s->anchor.t); /* eq. (4): time relative to the anchor */
    tt = tn * tn;
    dot = yn[0] * s->sty[0];
    for (d = 1u; d < dim; d++) {
        dot += yn[d] * s->sty[d];
    }
    /* eq. (13) times t_n^2 */
    if ((tt * s->syy - 2.0f * tn * dot) + nn * s->stt > s->settings.threshold * tt) {
        return restart(s, dim, index, t, y, point);
    }
    /* add sample n to the running sums, eq. (10)-(12) */
    s->syy += nn;
    s->stt += tt;
    for (d = 0u; d < dim; d++) {
        s->sty[d] += tn * yn[d];
    }
    s->count++;
    store_point(&s->prev, dim, index, t, y);
    return FASTSW_NONE;
}

FastswStatus fastsw_update(FastswState *state, uint32_t t, const float *y, FastswPoint *point)
{
    return update(state, FASTSW_DIM(&state->settings), t, y, point);
}

FastswStatus fastsw_flush(FastswState *state, FastswPoint *point)
{
    if (state->count == FASTSW_NOT_STARTED || state->prev.index == state->anchor.index) {
        return FASTSW_NONE;
    }
    *point = state->prev;
    state->anchor = state->prev;
    state->count = 0u;
    state->syy = 0.0f;
    state->stt = 0.0f;
    {
        uint32_t d;
        for (d = 0u; d < FASTSW_MAX_DIM; d++) {
            state->sty[d] = 0.0f;
        }
    }
    return FASTSW_POINT;
}

/** fastsw_update / fastsw_flush over an opaque state, for the batch driver. */
static FastswStatus update_any(void *state, uint32_t t, const float *y, FastswPoint *point)
{
    return fastsw_update((FastswState *)state, t, y, point);
}

static FastswStatus flush_any(void *state, FastswPoint *point)
{
    return fastsw_flush((FastswState *)state, point);
}

size_t fastsw_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                      uint32_t *out_index, size_t *rejected)
{
    static const FastswKernel kernel = {update_any, flush_any};
    FastswState state;

    if (fastsw_init(&state, settings) != FASTSW_NONE) {
        if (rejected != NULL) {
            *rejected = m;
        }
        return 0u;
    }
    return fastsw_run_batch(&state, &kernel, FASTSW_DIM(settings), t, y, m, out_index, NULL, rejected);
}

size_t fastsw_update_many(FastswState *states, size_t count, const uint32_t *t, const float *y,
                          uint8_t *status, FastswPoint *points)
{
    size_t k, emitted = 0u;
    for (k = 0u; k < count; k++) {
        const uint32_t dim = FASTSW_DIM(&states[k].settings);
        const FastswStatus st = update(&states[k], dim, t[k], y + k * dim, &points[k]);
        status[k] = (uint8_t)st;
        emitted += (st == FASTSW_POINT);
    }
    return emitted;
}

size_t fastsw_state_size(void)
{
    return sizeof(FastswState);
}

uint32_t fastsw_max_dim(void)
{
    return (uint32_t)FASTSW_MAX_DIM;
}
