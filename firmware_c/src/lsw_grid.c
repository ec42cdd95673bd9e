/*
 * lsw_grid.c - irregular arrivals on a uniform grid per device (see lsw_grid.h). Host library only.
 */
#include "lsw_grid.h"
#include "lsw_quat.h"

#include <math.h>
#include <string.h>


/** q = a * b (Hamilton product, w first). */
static void quat_mul(const double *a, const double *b, double *q)
{
    q[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    q[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    q[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    q[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

/** SLERP along the shorter arc, normalised, into float y: limbstream.quat.slerp step for step. */
static void slerp(const double *q0, const double *q1, double u, float *y)
{
    double out[4];
    int i;
    lsw_quat_slerp(q0, q1, u, out);
    for (i = 0; i < 4; i++) {
        y[i] = (float)out[i];
    }
}

/** Python's round() of a float: to nearest, ties to even (the default rounding mode). */
static int64_t round_even(double x)
{
    return (int64_t)nearbyint(x);
}

/** History entry i (0: the oldest). */
static uint32_t hist_at(const LswGridDevice *d, uint32_t i)
{
    return (d->hist_head + i) % LSW_GRID_HISTORY;
}

void lsw_grid_reset(LswGridDevice *d)
{
    float jitter[LSW_GRID_JITTER];
    const uint32_t jitter_len = d->jitter_len, jitter_head = d->jitter_head;
    const uint8_t online = d->online;
    memcpy(jitter, d->jitter, sizeof jitter);
    memset(d, 0, sizeof *d);
    memcpy(d->jitter, jitter, sizeof jitter);
    d->jitter_len = jitter_len;
    d->jitter_head = jitter_head;
    d->online = online;
}

/**
 * Keep the grid instants on the sender's arrivals, at their lower edge: the grid starts at the
 * stream's first sample; an arrival within a quarter period before an instant moves the grid
 * back to it at once, one after an instant moves it phase_gain of the way, unless an early one
 * came within the last rise_after arrivals (its own instant must not move past it).
 */
static void lock_phase(const LswGridSettings *s, LswGridDevice *d, double t_us)
{
    const double period = s->period_us;
    double r;
    if (!d->has_instant) {
        if (!d->has_anchor) {
            d->anchor = t_us;
            d->has_anchor = 1u;
        }
        return;
    }
    r = fmod(t_us - d->instant - d->shift + period / 2.0, period);
    if (r < 0.0) {
        r += period; /* Python's % takes the divisor's sign */
    }
    r -= period / 2.0;
    if (fabs(r) < period / 4.0) {
        d->jitter[d->jitter_head] = (float)fabs(r);
        d->jitter_head = (d->jitter_head + 1u) % LSW_GRID_JITTER;
        if (d->jitter_len < LSW_GRID_JITTER) {
            d->jitter_len++;
        }
        if (r < 0.0) {
            d->shift += r;
            d->no_rise = s->rise_after;
        } else if (d->no_rise > 0u) {
            d->no_rise--;
        } else {
            d->shift += s->phase_gain * r;
        }
    }
}

void lsw_grid_push(const LswGridSettings *s, LswGridDevice *d, double t_us, const double *q, double now_s)
{
    double turned[4];
    uint32_t at;
    if (d->hist_len > 0u) {
        const double last = d->hist_t[hist_at(d, d->hist_len - 1u)];
        if (t_us <= last) { /* the host clock stepped back: keep times increasing */
            t_us = last + 1.0;
        }
    }
    lock_phase(s, d, t_us);
    quat_mul(s->axes, q, turned);
    if (d->hist_len < LSW_GRID_HISTORY) {
        at = hist_at(d, d->hist_len++);
    } else {
        at = d->hist_head;
        d->hist_head = (d->hist_head + 1u) % LSW_GRID_HISTORY;
    }
    d->hist_t[at] = t_us;
    memcpy(d->hist_q[at], turned, sizeof turned);
    if (!s->truth) {
        return;
    }
    if (d->truth_len == LSW_GRID_TRUTH) { /* nobody took them: the oldest goes */
        memmove(d->truth_t, d->truth_t + 1, (LSW_GRID_TRUTH - 1u) * sizeof d->truth_t[0]);
        memmove(d->truth_a, d->truth_a + 1, (LSW_GRID_TRUTH - 1u) * sizeof d->truth_a[0]);
        memmove(d->truth_q, d->truth_q + 1, (LSW_GRID_TRUTH - 1u) * sizeof d->truth_q[0]);
        d->truth_len--;
        d->truth_dropped++;
    }
    if (d->truth_len == 0u) {
        d->truth_since = now_s;
    }
    d->truth_t[d->truth_len] = round_even(t_us + s->offset_us);
    d->truth_a[d->truth_len] = t_us;
    for (at = 0u; at < 4u; at++) {
        d->truth_q[d->truth_len][at] = (float)turned[at];
    }
    d->truth_len++;
}

/** First truth sample that arrived at or after `arrival` (arrivals increase). */
static uint32_t truth_from(const LswGridDevice *d, double arrival)
{
    uint32_t lo = 0u, hi = d->truth_len;
    while (lo < hi) {
        const uint32_t mid = (lo + hi) / 2u;
        if (d->truth_a[mid] < arrival) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

/**
 * The device's grid instant for the tick at gateway instant at_us: one period after its last,
 * moved by the correction since (at most a quarter period), kept within the period up to at_us
 * (the sender's clock drift makes it skip an instant, or wait a tick, once in a long while).
 * 0 when it waits or has no sample yet.
 */
static int next_instant(const LswGridSettings *s, LswGridDevice *d, double at_us)
{
    const double period = s->period_us, limit = period / 4.0;
    if (!d->has_instant) {
        if (!d->has_anchor) {
            return 0;
        }
        d->instant = d->anchor + floor((at_us - d->anchor) / period) * period;
        d->has_instant = 1u;
        return 1;
    }
    d->instant += period + (d->shift < -limit ? -limit : d->shift > limit ? limit : d->shift);
    d->shift = 0.0;
    if (d->instant <= at_us - period) {
        d->instant += period;
    }
    if (d->instant > at_us) {
        d->instant -= period;
        return 0;
    }
    return 1;
}

/**
 * The device's sample at its instant at (gateway clock) into y: the nearest sample that arrived
 * less than early_us before or late_us after it (its truth sample is stamped at the instant),
 * else the SLERP of the two around it, or the newest one held (counted when older than a quarter
 * period) for at most hold_us. 0: none (before its first sample, or after the hold).
 */
static int bracket(const LswGridSettings *s, LswGridDevice *d, double at, float *y)
{
    const uint32_t len = d->hist_len;
    double before = INFINITY, after = INFINITY, t0, t1;
    uint32_t j = 0u, own;
    if (len == 0u || d->hist_t[hist_at(d, 0u)] > at || d->hist_t[hist_at(d, len - 1u)] < at - s->hold_us) {
        return 0;
    }
    while (j < len && d->hist_t[hist_at(d, j)] <= at) { /* [0, j) arrived at or before the instant */
        j++;
    }
    if (j > 0u && at - d->hist_t[hist_at(d, j - 1u)] < s->early_us) {
        before = at - d->hist_t[hist_at(d, j - 1u)];
    }
    if (j < len && d->hist_t[hist_at(d, j)] - at < s->late_us) {
        after = d->hist_t[hist_at(d, j)] - at;
    }
    if (before != INFINITY || after != INFINITY) {
        const uint32_t k = before <= after ? j - 1u : j;
        const uint32_t i = truth_from(d, d->hist_t[hist_at(d, k)]);
        if (i < d->truth_len && d->truth_a[i] == d->hist_t[hist_at(d, k)]) {
            d->truth_t[i] = round_even(at + s->offset_us);
        }
        own = hist_at(d, k);
        slerp(d->hist_q[own], d->hist_q[own], 0.0, y);
        return 1;
    }
    if (j == len) {
        own = hist_at(d, len - 1u);
        if (at - d->hist_t[own] > s->period_us / 4.0) {
            d->held++;
        }
        slerp(d->hist_q[own], d->hist_q[own], 0.0, y);
        return 1;
    }
    t0 = d->hist_t[hist_at(d, j - 1u)];
    t1 = d->hist_t[hist_at(d, j)];
    slerp(d->hist_q[hist_at(d, j - 1u)], d->hist_q[hist_at(d, j)], (at - t0) / (t1 - t0), y);
    return 1;
}

size_t lsw_grid_tick(const LswGridSettings *s, LswGridDevice *devices, size_t count, double at_us,
                     uint8_t *have, uint32_t *tick, int64_t *stamp, float *y)
{
    size_t k, taken = 0u;
    for (k = 0u; k < count; k++) {
        LswGridDevice *d = &devices[k];
        float *yk = &y[4u * k];
        have[k] = 0u;
        yk[0] = yk[1] = yk[2] = yk[3] = NAN;
        if (!d->online) {
            continue;
        }
        if (next_instant(s, d, at_us) && bracket(s, d, d->instant, yk)) {
            d->last_t = round_even(d->instant + s->offset_us);
            d->quiet = 0u;
            have[k] = 1u;
            tick[k] = (uint32_t)round_even(d->instant);
            stamp[k] = d->last_t;
            taken++;
        } else {
            d->quiet++;
        }
    }
    return taken;
}

size_t lsw_grid_truth_due(const LswGridSettings *s, const LswGridDevice *devices, size_t count,
                          double now_s, uint32_t batch, double max_age_s, uint32_t *slots, uint32_t *n)
{
    size_t k, due = 0u;
    for (k = 0u; k < count; k++) {
        const LswGridDevice *d = &devices[k];
        uint32_t settled;
        int old;
        if (!d->online || d->truth_len == 0u) {
            continue;
        }
        old = now_s - d->truth_since >= max_age_s;
        if (d->truth_len < batch && !old) {
            continue;
        }
        settled = d->has_instant ? truth_from(d, d->instant + s->late_us) : 0u;
        if (settled >= batch || (settled > 0u && old)) {
            slots[due] = (uint32_t)k;
            n[due] = settled;
            due++;
        }
    }
    return due;
}

uint32_t lsw_grid_take_truth(LswGridDevice *d, uint32_t n, int64_t *t, float *q, double now_s)
{
    uint32_t i;
    if (n > d->truth_len) {
        n = d->truth_len;
    }
    for (i = 0u; i < n; i++) {
        t[i] = (i > 0u && t[i - 1u] > d->truth_t[i]) ? t[i - 1u] : d->truth_t[i];
    }
    memcpy(q, d->truth_q, n * sizeof d->truth_q[0]);
    d->truth_len -= n;
    memmove(d->truth_t, d->truth_t + n, d->truth_len * sizeof d->truth_t[0]);
    memmove(d->truth_a, d->truth_a + n, d->truth_len * sizeof d->truth_a[0]);
    memmove(d->truth_q, d->truth_q + n, d->truth_len * sizeof d->truth_q[0]);
    if (d->truth_len > 0u) {
        d->truth_since = now_s;
    }
    return n;
}
