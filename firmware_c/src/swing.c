/*
 * swing.c - Swing filter baseline in O(1) time and O(D) memory per sample
 * (see baselines.h).
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
#include "baseline_common.h"

FastswStatus swing_init(SwingState *state, const FastswSettings *settings)
{
    uint32_t d;

    if (baseline_init(&state->stream, settings, UINT32_MAX) != FASTSW_NONE) {
        return FASTSW_BAD_SETTINGS;
    }
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
    const float tp = baseline_point_at_prev(&s->stream, point);
    uint32_t d;
    for (d = 0u; d < dim; d++) {
        float beta = s->sty[d] / s->stt; /* eq. (S2): least squares ... */
        if (beta < s->lo[d]) {           /* ... clamped to the admissible range */
            beta = s->lo[d];
        }
        if (beta > s->hi[d]) {
            beta = s->hi[d];
        }
        point->y[d] = s->stream.anchor.y[d] + beta * tp;
    }
    baseline_new_segment(&s->stream, dim, point);
    s->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        s->sty[d] = 0.0f;
    }
}

/** swing_update for a known dim. */
static FastswStatus update(SwingState *s, uint32_t dim, uint32_t t, const float *y, FastswPoint *point)
{
    const uint32_t index = s->stream.next_index++;
    const float eps = s->stream.settings.threshold;
    float yn[FASTSW_MAX_DIM];
    float tn, r, nn;
    FastswStatus status = baseline_open(&s->stream, dim, index, t, y, point, yn, &nn);
    uint32_t d;

    if (status != FASTSW_NONE) {
        return status;
    }
    tn = (float)(uint32_t)(t - s->stream.anchor.t);
    r = 1.0f / tn;

    if (s->stream.count >= s->stream.settings.max_len) {
        status = FASTSW_POINT;
    } else if (s->stream.count > 0u) {
        for (d = 0u; d < dim; d++) { /* eq. (S1): does sample n's slope range meet [lo, hi]? */
            if ((yn[d] - eps) * r > s->hi[d] || (yn[d] + eps) * r < s->lo[d]) {
                status = FASTSW_POINT;
            }
        }
    }

    if (status == FASTSW_POINT) {
        close_segment(s, dim, point);
        (void)relative_sample(s->stream.anchor.y, dim, y, yn);
        tn = (float)(uint32_t)(t - s->stream.anchor.t);
        r = 1.0f / tn;
    }

    for (d = 0u; d < dim; d++) { /* eq. (S1): swing the bounds */
        const float lo = (yn[d] - eps) * r;
        const float hi = (yn[d] + eps) * r;
        if (s->stream.count == 0u || lo > s->lo[d]) {
            s->lo[d] = lo;
        }
        if (s->stream.count == 0u || hi < s->hi[d]) {
            s->hi[d] = hi;
        }
        s->sty[d] += tn * yn[d];
    }
    s->stt += tn * tn;
    s->stream.count++;
    store_point(&s->stream.prev, dim, index, t, y);
    return status;
}

BASELINE_ENTRY_POINTS(swing, SwingState)
