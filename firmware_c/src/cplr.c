/*
 * cplr.c - CPLR baseline in O(1) time and O(D) memory per sample (see cplr.h).
 *
 * Notation as in fastsw.c: for the samples i after the anchor a, t_i and y_i
 * are relative to it (t_i - t_a, y_i - y_a). Running sums over a < i <= n:
 *
 *   Stt = sum_i t_i^2,  Sty_d = sum_i t_i y_id,  Syy = sum_i |y_i|^2
 *
 * The least-squares slope of a line through the anchor and its SSR are
 *
 *   beta_d = Sty_d / Stt                                            eq. (C1)
 *   SSR    = Syy - |Sty|^2 / Stt                                    eq. (C2)
 *
 * and the test SSR > TH is done multiplied by Stt > 0 (no division):
 *
 *   Stt Syy - |Sty|^2 > TH Stt                                      eq. (C3)
 *
 * The segment point on a break is y_a + beta t_{n-1}, beta from the sums
 * over a < i <= n-1 (eq. C1), at the tick of sample n-1.
 * Build with -ffp-contract=off so every target rounds the same way.
 */
#include "cplr.h"

#include "fastsw_batch.h"
#include "kernel_common.h"

FastswStatus cplr_init(CplrState *state, const FastswSettings *settings)
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
    state->syy = 0.0f;
    state->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        state->sty[d] = 0.0f;
    }
    return FASTSW_NONE;
}

/** Close the segment at the last accepted sample: the fitted value there becomes the anchor. */
static void close_segment(CplrState *s, uint32_t dim, FastswPoint *point)
{
    const float tp = (float)(uint32_t)(s->prev.t - s->anchor.t); /* ticks, > 0 */
    uint32_t d;
    point->index = s->prev.index;
    point->t = s->prev.t;
    for (d = 0u; d < dim; d++) {
        const float beta = s->sty[d] / s->stt;          /* eq. (C1), per tick */
        point->y[d] = s->anchor.y[d] + beta * tp;
    }
    for (d = dim; d < FASTSW_MAX_DIM; d++) {
        point->y[d] = 0.0f;
    }
    s->anchor = *point;
    s->count = 0u;
    s->syy = 0.0f;
    s->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        s->sty[d] = 0.0f;
    }
}

/** cplr_update for a known dim. */
static FastswStatus update(CplrState *s, uint32_t dim, uint32_t t, const float *y, FastswPoint *point)
{
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
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    tn = (float)(uint32_t)(t - s->anchor.t);
    nn = relative_sample(s->anchor.y, dim, y, yn);
    if (!(nn <= FASTSW_NN_LIMIT)) {
        return FASTSW_REJECTED;
    }

    if (s->count >= s->settings.max_len) {
        status = FASTSW_POINT;
    } else if (s->count > 0u) { /* one sample after the anchor always fits exactly */
        const float stt = s->stt + tn * tn;
        const float syy = s->syy + nn;
        float sty2 = 0.0f;
        for (d = 0u; d < dim; d++) {
            const float sty = s->sty[d] + tn * yn[d];
            sty2 += sty * sty;
        }
        if (stt * syy - sty2 > s->settings.threshold * stt) { /* eq. (C3) */
            status = FASTSW_POINT;
        }
    }

    if (status == FASTSW_POINT) {
        close_segment(s, dim, point);
        tn = (float)(uint32_t)(t - s->anchor.t);
        nn = relative_sample(s->anchor.y, dim, y, yn);
    }

    /* add sample n to the running sums */
    s->syy += nn;
    s->stt += tn * tn;
    for (d = 0u; d < dim; d++) {
        s->sty[d] += tn * yn[d];
    }
    s->count++;
    store_point(&s->prev, dim, index, t, y);
    return status;
}

FastswStatus cplr_update(CplrState *state, uint32_t t, const float *y, FastswPoint *point)
{
    return update(state, FASTSW_DIM(&state->settings), t, y, point);
}

FastswStatus cplr_flush(CplrState *state, FastswPoint *point)
{
    if (!state->started || state->count == 0u) {
        return FASTSW_NONE;
    }
    close_segment(state, FASTSW_DIM(&state->settings), point);
    return FASTSW_POINT;
}

/** cplr_update / cplr_flush over an opaque state, for the batch driver. */
static FastswStatus update_any(void *state, uint32_t t, const float *y, FastswPoint *point)
{
    return cplr_update((CplrState *)state, t, y, point);
}

static FastswStatus flush_any(void *state, FastswPoint *point)
{
    return cplr_flush((CplrState *)state, point);
}

size_t cplr_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                   FastswPoint *out, size_t *rejected)
{
    static const FastswKernel kernel = {update_any, flush_any, NULL};
    CplrState state;

    if (cplr_init(&state, settings) != FASTSW_NONE) {
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

size_t cplr_state_size(void)
{
    return sizeof(CplrState);
}
