/*
 * sw.c - buffered Sliding Window baseline (see sw.h).
 */
#include "sw.h"

#include "baseline_common.h"

FastswStatus sw_init(SwState *state, const FastswSettings *settings)
{
    return baseline_init(&state->stream, settings, SW_MAX_LEN);
}

/** SSR of the buffered samples against the line from the anchor to (tn, yn): eq. (9). */
static float buffered_ssr(const SwState *s, uint32_t dim, float tn, const float *yn)
{
    const float r = 1.0f / tn;
    float ssr = 0.0f;
    uint32_t i, d;
    for (i = 0u; i < s->stream.count; i++) {
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
    BaselineStream *b = &s->stream;
    const uint32_t dim = FASTSW_DIM(&b->settings);
    const uint32_t index = b->next_index++;
    float yn[FASTSW_MAX_DIM];
    float tn, nn;
    FastswStatus status = baseline_open(b, dim, index, t, y, point, yn, &nn);
    uint32_t d;

    if (status != FASTSW_NONE) {
        return status;
    }
    tn = (float)(uint32_t)(t - b->anchor.t);
    if (b->count >= b->settings.max_len || buffered_ssr(s, dim, tn, yn) > b->settings.threshold) {
        status = FASTSW_POINT;
        *point = b->prev;
        b->anchor = b->prev;
        b->count = 0u;
        tn = (float)(uint32_t)(t - b->anchor.t);
        (void)relative_sample(b->anchor.y, dim, y, yn);
    }
    s->t_rel[b->count] = tn;
    for (d = 0u; d < dim; d++) {
        s->y_rel[b->count][d] = yn[d];
    }
    b->count++;
    store_point(&b->prev, dim, index, t, y);
    return status;
}

FastswStatus sw_flush(SwState *s, FastswPoint *point)
{
    BaselineStream *b = &s->stream;
    if (!b->started || b->prev.index == b->anchor.index) {
        return FASTSW_NONE;
    }
    *point = b->prev;
    b->anchor = b->prev;
    b->count = 0u;
    return FASTSW_POINT;
}

BASELINE_BATCH_ADAPTERS(sw, SwState)

size_t sw_segment(SwState *work, const FastswSettings *settings, const uint32_t *t, const float *y,
                  size_t m, uint32_t *out_index, size_t *rejected)
{
    static const FastswKernel kernel = {sw_update_any, sw_flush_any, NULL};

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
