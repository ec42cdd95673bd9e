/*
 * sw.c - buffered Sliding Window baseline (see sw.h).
 */
#include "sw.h"

#include "fastsw_batch.h"
#include "kernel_common.h"

FastswStatus sw_init(SwState *state, const FastswSettings *settings)
{
    FastswSettings capped = *settings;
    FastswState probe; /* reuse fastSW's validation and sanitising */

    if (capped.max_len > SW_MAX_LEN) {
        capped.max_len = SW_MAX_LEN;
    }
    if (fastsw_init(&probe, &capped) != FASTSW_NONE) {
        return FASTSW_BAD_SETTINGS;
    }
    state->settings = probe.settings;
    state->next_index = 0u;
    state->count = 0u;
    state->started = 0u;
    state->anchor = probe.anchor;
    state->prev = probe.prev;
    return FASTSW_NONE;
}

/** SSR of the buffered samples against the line from the anchor to (tn, yn): eq. (9). */
static float buffered_ssr(const SwState *s, uint32_t dim, float tn, const float *yn)
{
    const float r = 1.0f / tn;
    float ssr = 0.0f;
    uint32_t i, d;
    for (i = 0u; i < s->count; i++) {
        const float u = s->t_rel[i] * r;
        for (d = 0u; d < dim; d++) {
            const float e = s->y_rel[i][d] - u * yn[d];
            ssr += e * e;
        }
    }
    return ssr;
}

FastswStatus sw_update(SwState *s, uint32_t t, const float *y, FastswPoint *point)
{
    const uint32_t dim = FASTSW_DIM(&s->settings);
    const uint32_t index = s->next_index++;
    float yn[FASTSW_MAX_DIM];
    float tn, nn;
    FastswStatus status = FASTSW_NONE;
    uint32_t d;

    if (!s->started) {
        status = start_stream(&s->anchor, &s->prev, dim, index, t, y, point);
        s->started = (status == FASTSW_POINT);
        return status;
    }
    if ((int32_t)(t - s->prev.t) <= 0) {
        return FASTSW_REJECTED;
    }
    tn = (float)(uint32_t)(t - s->anchor.t);
    nn = relative_sample(s->anchor.y, dim, y, yn);
    if (!(nn <= FASTSW_NN_LIMIT)) {
        return FASTSW_REJECTED;
    }
    if (s->count >= s->settings.max_len || buffered_ssr(s, dim, tn, yn) > s->settings.threshold) {
        status = FASTSW_POINT;
        *point = s->prev;
        s->anchor = s->prev;
        s->count = 0u;
        tn = (float)(uint32_t)(t - s->anchor.t);
        nn = relative_sample(s->anchor.y, dim, y, yn);
    }
    s->t_rel[s->count] = tn;
    for (d = 0u; d < dim; d++) {
        s->y_rel[s->count][d] = yn[d];
    }
    s->count++;
    store_point(&s->prev, dim, index, t, y);
    return status;
}

FastswStatus sw_flush(SwState *s, FastswPoint *point)
{
    if (!s->started || s->prev.index == s->anchor.index) {
        return FASTSW_NONE;
    }
    *point = s->prev;
    s->anchor = s->prev;
    s->count = 0u;
    return FASTSW_POINT;
}

/** sw_update / sw_flush over an opaque state, for the batch driver. */
static FastswStatus update_any(void *state, uint32_t t, const float *y, FastswPoint *point)
{
    return sw_update((SwState *)state, t, y, point);
}

static FastswStatus flush_any(void *state, FastswPoint *point)
{
    return sw_flush((SwState *)state, point);
}

size_t sw_segment(SwState *work, const FastswSettings *settings, const uint32_t *t, const float *y,
                  size_t m, uint32_t *out_index, size_t *rejected)
{
    static const FastswKernel kernel = {update_any, flush_any, NULL};

    if (sw_init(work, settings) != FASTSW_NONE) {
        if (rejected != NULL) {
            *rejected = m;
        }
        return 0u;
    }
    {
        const FastswBatchOut out = {out_index, NULL, NULL, NULL};
        return fastsw_run_batch(work, &kernel, FASTSW_DIM(settings), t, y, m, &out, rejected);
    }
}

size_t sw_state_size(void)
{
    return sizeof(SwState);
}
