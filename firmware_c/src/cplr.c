/*
 * cplr.c - CPLR baseline in O(1) time and O(D) memory per sample (see baselines.h).
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
#include "baseline_common.h"

/** The running sums of an empty segment. */
static void clear_sums(CplrState *s)
{
    uint32_t d;
    s->syy = 0.0f;
    s->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        s->sty[d] = 0.0f;
    }
}

FastswStatus cplr_init(CplrState *state, const FastswSettings *settings)
{
    if (baseline_init(&state->stream, settings, UINT32_MAX) != FASTSW_NONE) {
        return FASTSW_BAD_SETTINGS;
    }
    clear_sums(state);
    return FASTSW_NONE;
}

/** Close the segment at the last accepted sample: the fitted value there becomes the anchor. */
static void close_segment(CplrState *s, uint32_t dim, FastswPoint *point)
{
    const float tp = baseline_point_at_prev(&s->stream, point);
    uint32_t d;
    for (d = 0u; d < dim; d++) {
        const float beta = s->sty[d] / s->stt;          /* eq. (C1), per tick */
        point->y[d] = s->stream.anchor.y[d] + beta * tp;
    }
    baseline_new_segment(&s->stream, dim, point);
    clear_sums(s);
}

/** cplr_update for a known dim. */
static FastswStatus update(CplrState *s, uint32_t dim, uint32_t t, const float *y, FastswPoint *point)
{
    const uint32_t index = s->stream.next_index++;
    float yn[FASTSW_MAX_DIM];
    float tn, nn;
    FastswStatus status = baseline_open(&s->stream, dim, index, t, y, point, yn, &nn);
    uint32_t d;

    if (status != FASTSW_NONE) {
        return status;
    }
    tn = (float)(uint32_t)(t - s->stream.anchor.t);
    if (s->stream.count >= s->stream.settings.max_len) {
        status = FASTSW_POINT;
    } else if (s->stream.count > 0u) { /* one sample after the anchor always fits exactly */
        const float stt = s->stt + tn * tn;
        const float syy = s->syy + nn;
        float sty2 = 0.0f;
        for (d = 0u; d < dim; d++) {
            const float sty = s->sty[d] + tn * yn[d];
            sty2 += sty * sty;
        }
        if (stt * syy - sty2 > s->stream.settings.threshold * stt) { /* eq. (C3) */
            status = FASTSW_POINT;
        }
    }

    if (status == FASTSW_POINT) {
        close_segment(s, dim, point);
        tn = (float)(uint32_t)(t - s->stream.anchor.t);
        nn = relative_sample(s->stream.anchor.y, dim, y, yn);
    }

    /* add sample n to the running sums */
    s->syy += nn;
    s->stt += tn * tn;
    for (d = 0u; d < dim; d++) {
        s->sty[d] += tn * yn[d];
    }
    s->stream.count++;
    store_point(&s->stream.prev, dim, index, t, y);
    return status;
}

BASELINE_ENTRY_POINTS(cplr, CplrState)
