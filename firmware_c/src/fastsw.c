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
 *
 * Live rule (fastsw.h): the receiver's prediction from the anchor a (always
 * the newest point) at sample n is p = y_a + t_n v with the anchor's rate v,
 * linear in t_n like the segment itself: no trigonometry, and per sample no
 * more than t_n v. It is more than eps from y_n when
 *
 *   (p . y_n)^2 < cos^2(eps/2) |p|^2 |y_n|^2                         (L1)
 *
 * (the rotation between unit quaternions is 2 arccos |p . y| / (|p| |y|);
 * squared, neither needs normalising). cos^2(eps/2) is a fixed polynomial,
 * evaluated at init and retune. A point's rate passes its extrapolation
 * through a neighbouring sample r, dt ticks away: y_p + dt v is parallel to
 * y_r (L2, through_rate). A point closed by the SSR or max_len rule at sample n
 * passes through sample n, which therefore needs no live test; a point closed
 * by the live rule passes back through sample n-1.
 * With the rule on, the rare-path limit is 0: every update runs update_live,
 * and plain updates pay nothing for the rule.
 */
#include "fastsw.h"
#include "fastsw_batch.h"
#include "kernel_common.h"

/* count of a stream before its first accepted sample (>= any max_len) */
#define FASTSW_NOT_STARTED UINT32_MAX

const FastswSettings fastsw_default_settings = {1e-2f, 1000u, 4u, 0.0f};

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

/** The live rule is on for a bound in (0, 180) degrees (NaN, 0, negative, >= 180, Inf: off). */
static int live_on(const FastswSettings *settings)
{
    return settings->live_bound_deg > 0.0f && settings->live_bound_deg < 180.0f;
}

/**
 * cos^2(eps/2) for eps = deg in (0, 180) degrees, without libm (the same bits on every
 * target): the Taylor series of cos h in x = h^2 up to h^14, h = eps/2 <= pi/2 (truncation
 * below 1e-10), by Horner in float32.
 */
static float live_cos2(float deg)
{
    const float h = deg * (3.14159265358979f / 360.0f);
    const float x = h * h;
    float c = -1.0f / 87178291200.0f;
    c = c * x + 1.0f / 479001600.0f;
    c = c * x - 1.0f / 3628800.0f;
    c = c * x + 1.0f / 40320.0f;
    c = c * x - 1.0f / 720.0f;
    c = c * x + 1.0f / 24.0f;
    c = c * x - 0.5f;
    c = c * x + 1.0f;
    return c * c;
}

/** Copy the tunables of *settings into the state (dim and the stream stay). */
static void apply_settings(FastswState *state, const FastswSettings *settings)
{
    state->settings.threshold = sanitized_threshold(settings->threshold);
    state->settings.max_len = sanitized_max_len(settings->max_len);
    state->settings.live_bound_deg = settings->live_bound_deg;
    state->live = (uint32_t)live_on(settings);
    state->live_cos2 = state->live ? live_cos2(settings->live_bound_deg) : 0.0f;
}

FastswStatus fastsw_init(FastswState *state, const FastswSettings *settings)
{
    uint32_t d;

    if (settings->dim == 0u || settings->dim > FASTSW_MAX_DIM || (live_on(settings) && settings->dim != 4u)) {
        return FASTSW_BAD_SETTINGS;
    }
#if defined(FASTSW_FIXED_DIM)
    if (settings->dim != (uint32_t)FASTSW_FIXED_DIM) {
        return FASTSW_BAD_SETTINGS;
    }
#endif
    state->settings = *settings;
    apply_settings(state, settings);
    state->next_index = 0u;
    state->count = FASTSW_NOT_STARTED;
    state->syy = 0.0f;
    state->stt = 0.0f;
    for (d = 0u; d < FASTSW_MAX_DIM; d++) {
        state->sty[d] = 0.0f;
        state->anchor.y[d] = 0.0f;
        state->prev.y[d] = 0.0f;
        state->rate[d] = 0.0f;
    }
    state->anchor.index = state->prev.index = 0u;
    state->anchor.t = state->prev.t = 0u;
    return FASTSW_NONE;
}

FastswStatus fastsw_retune(FastswState *state, const FastswSettings *settings)
{
    const uint32_t was_live = state->live;
    uint32_t d;

    if (settings->dim != state->settings.dim || (live_on(settings) && settings->dim != 4u)) {
        return FASTSW_BAD_SETTINGS;
    }
    apply_settings(state, settings);
    if (state->live && !was_live) { /* the anchor was sent without a rate */
        for (d = 0u; d < FASTSW_MAX_DIM; d++) {
            state->rate[d] = 0.0f;
        }
    }
    return FASTSW_NONE;
}

/** The SSR test, eq. (13) times t_n^2: does the segment from the anchor to sample n break? */
static inline int ssr_exceeds(const FastswState *s, uint32_t dim, const float *yn, float nn, float tn,
                              float tt)
{
    float dot = yn[0] * s->sty[0];
    uint32_t d;
    for (d = 1u; d < dim; d++) {
        dot += yn[d] * s->sty[d];
    }
    return (tt * s->syy - 2.0f * tn * dot) + nn * s->stt > s->settings.threshold * tt;
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

/** Empty running sums: the segment has no sample after its anchor yet. */
static inline void clear_sums(FastswState *s, uint32_t dim)
{
    uint32_t d;
    s->count = 0u;
    s->syy = 0.0f;
    s->stt = 0.0f;
    for (d = 0u; d < dim; d++) {
        s->sty[d] = 0.0f;
    }
}

/**
 * The rate that extrapolates a new point yp through the sample yr, dt ticks
 * away (negative: before it): y_p + dt v is parallel to y_r, with
 *
 *   v = (y_r - c y_p) k,   k = 1 / (c dt),   c = y_p . y_r             (L2)
 *
 * tangent to y_p (v . y_p = 0 for unit y_p). k is computed as
 * c / ((c^2 + 1e-12) dt): the same to 1e-6 for any step below 179.9 degrees
 * (|c| > 1e-3), and bounded without a branch when the two samples are half a
 * turn apart (c = 0, where no finite rate passes through both: v = 0).
 */
static inline void through_rate(float *rate, uint32_t dim, const float *yp, const float *yr, float dt)
{
    float c = yp[0] * yr[0];
    float k;
    uint32_t d;
    for (d = 1u; d < dim; d++) {
        c += yp[d] * yr[d];
    }
    k = c / ((c * c + 1e-12f) * dt);
    for (d = 0u; d < dim; d++) {
        rate[d] = (yr[d] - c * yp[d]) * k;
    }
}

/** The live test (L1): is the prediction from the anchor, tn ticks after it, more than eps from y? */
static inline int off_course(const FastswState *s, uint32_t dim, const float *y, float tn)
{
    float p = s->anchor.y[0] + tn * s->rate[0];
    float py = p * y[0], pp = p * p, yy = y[0] * y[0];
    uint32_t d;
    for (d = 1u; d < dim; d++) {
        p = s->anchor.y[d] + tn * s->rate[d];
        py += p * y[d];
        pp += p * p;
        yy += y[d] * y[d];
    }
    return py * py < s->live_cos2 * pp * yy;
}

/**
 * Live rule, segment break at sample n (SSR or max_len rule): s_{n-1} closes the
 * segment with the rate through sample n, so the prediction at n is sample n
 * itself and needs no live test.
 */
static inline FastswStatus live_break(FastswState *restrict s, uint32_t t,
                                               const float *restrict y, FastswPoint *restrict point)
{
    const uint32_t dim = FASTSW_DIM(&s->settings);
    through_rate(s->rate, dim, s->prev.y, y, (float)(uint32_t)(t - s->prev.t));
    return restart(s, dim, s->next_index - 1u, t, y, point);
}

/** Live rule, sample n off course: it closes the segment, with the rate back through n-1. */
static inline FastswStatus live_close(FastswState *restrict s, uint32_t t,
                                               const float *restrict y, FastswPoint *restrict point)
{
    const uint32_t dim = FASTSW_DIM(&s->settings);
    const uint32_t index = s->next_index - 1u;
    through_rate(s->rate, dim, y, s->prev.y, -(float)(uint32_t)(t - s->prev.t));
    store_point(&s->anchor, dim, index, t, y);
    store_point(&s->prev, dim, index, t, y);
    store_point(point, dim, index, t, y);
    clear_sums(s, dim);
    return FASTSW_POINT;
}

/**
 * The rare cases, all with count >= max_len: the first sample of a stream
 * (count == FASTSW_NOT_STARTED; it becomes a segment point and the anchor,
 * whose y was 0, so nn = |y|^2 was checked), a time step that is not
 * positive, or a segment that reached max_len.
 */
static FASTSW_NOINLINE FastswStatus long_segment(FastswState *s, uint32_t t, const float *y,
                                                 FastswPoint *point)
{
    const uint32_t dim = FASTSW_DIM(&s->settings);
    const uint32_t index = s->next_index - 1u;

    if (s->count == FASTSW_NOT_STARTED) {
        store_point(&s->anchor, dim, index, t, y);
        s->prev = s->anchor;
        s->count = 0u;
        *point = s->anchor;
        return FASTSW_POINT; /* with the live rule, at rate 0 (init, retune) */
    }
    if ((int32_t)(t - s->prev.t) <= 0) { /* zero or negative time step */
        return FASTSW_REJECTED;
    }
    if (s->live) {
        return live_break(s, t, y, point);
    }
    return restart(s, dim, index, t, y, point);
}

/** fastsw_update for a known dim (inlined with a constant dim where fixed). */
static inline FastswStatus update(FastswState *s, uint32_t dim, uint32_t t, const float *y,
                                  FastswPoint *point)
{
    const uint32_t index = s->next_index++;
    float yn[FASTSW_MAX_DIM];
    float tn, tt, nn, dot, ssr;
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
    ssr = (tt * s->syy - 2.0f * tn * dot) + nn * s->stt; /* eq. (13) times t_n^2 */
    if (s->live) {
        if (ssr > s->settings.threshold * tt) {
            return live_break(s, t, y, point);
        }
        if (off_course(s, dim, y, tn)) {
            return live_close(s, t, y, point);
        }
    } else if (ssr > s->settings.threshold * tt) {
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

void fastsw_point_rate(const FastswState *state, float *rate)
{
    const uint32_t dim = FASTSW_DIM(&state->settings);
    uint32_t d;
    for (d = 0u; d < dim; d++) {
        rate[d] = state->live ? state->rate[d] : 0.0f;
    }
}

FastswStatus fastsw_flush(FastswState *state, FastswPoint *point)
{
    uint32_t d;

    if (state->count == FASTSW_NOT_STARTED || state->prev.index == state->anchor.index) {
        return FASTSW_NONE;
    }
    *point = state->prev;
    state->anchor = state->prev;
    clear_sums(state, FASTSW_MAX_DIM);
    for (d = 0u; d < FASTSW_MAX_DIM; d++) { /* the end of a stream is held */
        state->rate[d] = 0.0f;
    }
    return FASTSW_POINT;
}

/** fastsw_update / fastsw_flush / fastsw_point_rate over an opaque state, for the batch driver. */
static FastswStatus update_any(void *state, uint32_t t, const float *y, FastswPoint *point)
{
    return fastsw_update((FastswState *)state, t, y, point);
}

static FastswStatus flush_any(void *state, FastswPoint *point)
{
    return fastsw_flush((FastswState *)state, point);
}

static void rate_any(const void *state, float *rate)
{
    fastsw_point_rate((const FastswState *)state, rate);
}

size_t fastsw_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                      const FastswBatchOut *out, size_t *rejected)
{
    static const FastswKernel kernel = {update_any, flush_any, rate_any};
    FastswState state;

    if (fastsw_init(&state, settings) != FASTSW_NONE) {
        if (rejected != NULL) {
            *rejected = m;
        }
        return 0u;
    }
    return fastsw_run_batch(&state, &kernel, FASTSW_DIM(settings), t, y, m, out, rejected);
}

size_t fastsw_update_many(FastswState *states, size_t count, const uint32_t *t, const float *y,
                          uint8_t *status, FastswPoint *points, float *rates)
{
    size_t k, emitted = 0u;
    for (k = 0u; k < count; k++) {
        const uint32_t dim = FASTSW_DIM(&states[k].settings);
        const FastswStatus st = update(&states[k], dim, t[k], y + k * dim, &points[k]);
        status[k] = (uint8_t)st;
        if (st == FASTSW_POINT) {
            emitted++;
            if (rates != NULL) {
                fastsw_point_rate(&states[k], rates + k * dim);
            }
        }
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
