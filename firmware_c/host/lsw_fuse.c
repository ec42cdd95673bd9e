/*
 * lsw_fuse.c - reconstruction of segment point rows, many queries per call (see lsw_fuse.h).
 * Host library only.
 */
#include "lsw_fuse.h"
#include "lsw_quat.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


/** Index of the last point of row r at or before time x (-1: none): a binary search. */
static int64_t locate(const LswFuseRows *rows, int64_t r, int64_t x)
{
    const int64_t *t = rows->t + r * rows->cap;
    int64_t lo = 0, hi = rows->n[r];
    while (lo < hi) {
        const int64_t mid = lo + (hi - lo) / 2;
        if (t[mid] <= x) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    return lo - 1;
}

/** Point k of row r as doubles, normalised (q / |q|, limbstream.quat.normalize). */
static void unit_point(const LswFuseRows *rows, int64_t r, int64_t k, double *y)
{
    const float *q = rows->q + (r * rows->cap + k) * 4;
    const double a = q[0], b = q[1], c = q[2], d = q[3];
    const double norm = sqrt(a * a + b * b + c * c + d * d);
    y[0] = a / norm;
    y[1] = b / norm;
    y[2] = c / norm;
    y[3] = d / norm;
}

/** The span of a non-empty row that SLERP uses at times whose point at or before them is k: its
 * ends (k1 == k: a row of one point), the two points normalised and their arc. */
typedef struct {
    int64_t r, k, k1;
    double q0[4], q1[4];
    LswArc arc;
} Span;

struct LswFuseSpan {
    int64_t used, t0, t1; /* used: 1 once filled; the ends' times */
    float p0[4], p1[4];   /* the ends as stored */
    double q0[4], q1[4];  /* the ends normalised */
    LswArc arc;
};

size_t lsw_fuse_row_spans_size(void)
{
    return LSW_FUSE_SPANS * sizeof(LswFuseSpan);
}

/** The first end of row r's span for point k (-1: none): k within 0 .. n - 2. */
static int64_t span_start(const LswFuseRows *rows, int64_t r, int64_t k)
{
    const int64_t n = rows->n[r];
    const int64_t last = n >= 2 ? n - 2 : 0;
    return k < 0 ? 0 : (k > last ? last : k);
}

/** The row's remembered span joining its points k and k1 as they are now, moved to the front of
 * the row's spans; NULL if none is, the front one then emptied for the caller to fill. */
static const LswFuseSpan *remembered(const LswFuseRows *rows, int64_t r, int64_t k, int64_t k1)
{
    LswFuseSpan *m = rows->spans + LSW_FUSE_SPANS * r;
    const int64_t *t = rows->t + r * rows->cap;
    const float *p0 = rows->q + (r * rows->cap + k) * 4, *p1 = rows->q + (r * rows->cap + k1) * 4;
    int j;
    for (j = 0; j < LSW_FUSE_SPANS; j++) {
        if (m[j].used && m[j].t0 == t[k] && m[j].t1 == t[k1] && memcmp(m[j].p0, p0, sizeof m[j].p0) == 0 &&
            memcmp(m[j].p1, p1, sizeof m[j].p1) == 0) {
            break;
        }
    }
    if (j == LSW_FUSE_SPANS) { /* none: the oldest makes room at the front */
        memmove(m + 1, m, (LSW_FUSE_SPANS - 1) * sizeof *m);
        m[0].used = 0;
        return NULL;
    }
    if (j > 0) {
        const LswFuseSpan hit = m[j];
        memmove(m + 1, m, (size_t)j * sizeof *m);
        m[0] = hit;
    }
    return m;
}

static void span_of(const LswFuseRows *rows, int64_t r, int64_t k, Span *s)
{
    const int64_t n = rows->n[r];
    const LswFuseSpan *hit;
    LswFuseSpan *m;
    s->r = r;
    s->k = span_start(rows, r, k);
    s->k1 = s->k + 1 < n - 1 ? s->k + 1 : n - 1;
    if (rows->spans != NULL && (hit = remembered(rows, r, s->k, s->k1)) != NULL) {
        memcpy(s->q0, hit->q0, sizeof s->q0);
        memcpy(s->q1, hit->q1, sizeof s->q1);
        s->arc = hit->arc;
        return;
    }
    unit_point(rows, r, s->k, s->q0);
    unit_point(rows, r, s->k1, s->q1);
    s->arc = lsw_quat_arc(s->q0, s->q1);
    if (rows->spans != NULL) { /* the front span: remembered() moved the others back */
        m = rows->spans + LSW_FUSE_SPANS * r;
        m->used = 1;
        m->t0 = rows->t[r * rows->cap + s->k];
        m->t1 = rows->t[r * rows->cap + s->k1];
        memcpy(m->p0, rows->q + (r * rows->cap + s->k) * 4, sizeof m->p0);
        memcpy(m->p1, rows->q + (r * rows->cap + s->k1) * 4, sizeof m->p1);
        memcpy(m->q0, s->q0, sizeof m->q0);
        memcpy(m->q1, s->q1, sizeof m->q1);
        m->arc = s->arc;
    }
}

/** The SLERP reconstruction at time x on span s. */
static void span_at(const LswFuseRows *rows, const Span *s, int64_t x, double *y)
{
    const int64_t *t = rows->t + s->r * rows->cap;
    const double span = (double)(t[s->k1] - t[s->k]);
    double u = (double)(x - t[s->k]) / (span > 0.0 ? span : 1.0);
    u = u < 0.0 ? 0.0 : (u > 1.0 ? 1.0 : u);
    lsw_quat_slerp_on(s->q0, s->q1, &s->arc, u, y);
}

/** The SLERP reconstruction of non-empty row r at time x, k the point at or before x (-1: none). */
static void exact(const LswFuseRows *rows, int64_t r, int64_t x, int64_t k, double *y)
{
    Span s;
    span_of(rows, r, k, &s);
    span_at(rows, &s, x, y);
}

/** Unit q (a point of a row) extrapolated by dt s with its body rate w: limbstream.quat.predict
 * (normalize(q + dt q (0, omega) / 2)). */
static void predict_from(const double *q, const float *w, double dt, double *y)
{
    const double bx = w[0], by = w[1], bz = w[2];
    double qdot[4];
    int i;
    qdot[0] = 0.5 * (q[0] * 0.0 - q[1] * bx - q[2] * by - q[3] * bz);
    qdot[1] = 0.5 * (q[0] * bx + q[1] * 0.0 + q[2] * bz - q[3] * by);
    qdot[2] = 0.5 * (q[0] * by - q[1] * bz + q[2] * 0.0 + q[3] * bx);
    qdot[3] = 0.5 * (q[0] * bz + q[1] * by - q[2] * bx + q[3] * 0.0);
    for (i = 0; i < 4; i++) {
        y[i] = q[i] + dt * qdot[i];
    }
    lsw_quat_normalize(y);
}

/** Point k of row r extrapolated to time x with its body rate (predict_from, q normalised). */
static void predict(const LswFuseRows *rows, int64_t r, int64_t x, int64_t k, double *y)
{
    double q[4];
    unit_point(rows, r, k, q);
    predict_from(q, rows->w + (r * rows->cap + k) * 3, (double)(x - rows->t[r * rows->cap + k]) / 1e6, y);
}

/** y = identity. */
static void identity(double *y)
{
    y[0] = 1.0;
    y[1] = y[2] = y[3] = 0.0;
}

/** Row r at time x as mode asks (LswFuseMode); k: the point at or before x (locate), or -2 if not
 * searched yet. */
static void query(const LswFuseRows *rows, int64_t r, int64_t x, int mode, int64_t k, double *y)
{
    const int64_t n = rows->n[r];
    if (n == 0) {
        identity(y);
        return;
    }
    if (mode == LSW_FUSE_LIVE && x > rows->t[r * rows->cap + n - 1]) {
        predict(rows, r, x, n - 1, y);
        return;
    }
    if (k == -2) {
        k = locate(rows, r, x);
    }
    if (mode == LSW_FUSE_PREDICTED) {
        if (k < 0) {
            identity(y);
        } else {
            predict(rows, r, x, k, y);
        }
        return;
    }
    exact(rows, r, x, k, y);
}

/** 2 acos |<a, b>| / (|a| |b|) in degrees: limbstream.quat.angle_deg. */
static double angle_deg(const double *a, const double *b)
{
    const double na = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3]);
    const double nb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3]);
    double dot = fabs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]);
    dot /= na * nb;
    dot = dot < 0.0 ? 0.0 : (dot > 1.0 ? 1.0 : dot);
    return 2.0 * acos(dot) * (180.0 / 3.14159265358979323846);
}

void lsw_fuse_reconstruct(const LswFuseRows *rows, size_t count, const int64_t *slots, const int64_t *t_us,
                          const uint8_t *mode, double *out)
{
    size_t i;
    for (i = 0; i < count; i++) {
        query(rows, slots[i], t_us[i], mode[i], -2, out + 4 * i);
    }
}

void lsw_fuse_errors(const LswFuseRows *rows, size_t count, const int64_t *slots, const int64_t *t_us,
                     const float *truth, double *exact_deg, double *predicted_deg)
{
    /* A device's truth samples come in runs of consecutive times: a run finds its point from the
     * last one's, and each span is prepared once (the same arithmetic as query's: the same bits). */
    Span span;
    int64_t k = -1;
    size_t i;
    span.r = -1;
    for (i = 0; i < count; i++) {
        const float *s = truth + 4 * i;
        const double b[4] = {s[0], s[1], s[2], s[3]};
        const int64_t r = slots[i], x = t_us[i], n = rows->n[r];
        const int64_t *t = rows->t + r * rows->cap;
        double y[4], q[4];
        if (n == 0) {
            identity(y);
            exact_deg[i] = predicted_deg[i] = angle_deg(y, b);
            span.r = -1;
            continue;
        }
        if (span.r == r && k >= 0 && t[k] <= x && (k + 1 >= n || x < t[k + 1])) {
            /* the same point as the sample before */
        } else if (span.r == r && k >= 0 && k + 1 < n && t[k + 1] <= x && (k + 2 >= n || x < t[k + 2])) {
            k += 1;
        } else {
            k = locate(rows, r, x);
        }
        if (span.r != r || span.k != span_start(rows, r, k)) {
            span_of(rows, r, k, &span);
        }
        span_at(rows, &span, x, y);
        exact_deg[i] = angle_deg(y, b);
        if (k < 0) {
            identity(y);
        } else {
            if (k == span.k || k == span.k1) {
                const double *p = k == span.k ? span.q0 : span.q1;
                q[0] = p[0], q[1] = p[1], q[2] = p[2], q[3] = p[3];
            } else {
                unit_point(rows, r, k, q);
            }
            predict_from(q, rows->w + (r * rows->cap + k) * 3, (double)(x - t[k]) / 1e6, y);
        }
        predicted_deg[i] = angle_deg(y, b);
    }
}

/** v turned by unit quaternion q: v + w t + u x t with t = 2 u x v (limbstream.quat.rotate). */
static void rotate(const double *q, const double *v, double *y)
{
    const double *u = q + 1;
    double t[3], c[3];
    t[0] = 2.0 * (u[1] * v[2] - u[2] * v[1]);
    t[1] = 2.0 * (u[2] * v[0] - u[0] * v[2]);
    t[2] = 2.0 * (u[0] * v[1] - u[1] * v[0]);
    c[0] = u[1] * t[2] - u[2] * t[1];
    c[1] = u[2] * t[0] - u[0] * t[2];
    c[2] = u[0] * t[1] - u[1] * t[0];
    y[0] = v[0] + q[0] * t[0] + c[0];
    y[1] = v[1] + q[0] * t[1] + c[1];
    y[2] = v[2] + q[0] * t[2] + c[2];
}

void lsw_fuse_chain(size_t count, const double *q, uint32_t segments, const uint8_t *alt, uint32_t bones,
                    const int32_t *segment, const int32_t *joint, const int32_t *parent, const int32_t *toward,
                    const double *share, const double *vec, const double *alt_vec, uint32_t joints, float *out,
                    double *out64)
{
    double at[LSW_FUSE_MAX_JOINTS][3];
    size_t i;
    uint32_t b, j;
    if (joints > LSW_FUSE_MAX_JOINTS) {
        return;
    }
    for (i = 0; i < count; i++) {
        const double *body = q + i * segments * 4;
        const double *v = alt[i] ? alt_vec : vec;
        for (j = 0; j < joints; j++) {
            at[j][0] = at[j][1] = at[j][2] = 0.0;
        }
        for (b = 0; b < bones; b++) {
            double turned[3], bent[4];
            const double *by = body + 4 * segment[b];
            if (toward != NULL && toward[b] >= 0) {
                lsw_quat_slerp(by, body + 4 * toward[b], share[b], bent);
                by = bent;
            }
            rotate(by, v + 3 * b, turned);
            for (j = 0; j < 3; j++) {
                at[joint[b]][j] = parent[b] < 0 ? turned[j] : at[parent[b]][j] + turned[j];
            }
        }
        for (j = 0; j < joints; j++) {
            if (out64 != NULL) {
                double *y = out64 + (i * joints + j) * 3;
                y[0] = at[j][0];
                y[1] = at[j][1];
                y[2] = at[j][2];
            } else {
                float *y = out + (i * joints + j) * 3;
                y[0] = (float)at[j][0];
                y[1] = (float)at[j][1];
                y[2] = (float)at[j][2];
            }
        }
    }
}

void lsw_fuse_ring_append(float *ring, int64_t *seen, double *total, int64_t window, size_t count,
                          const int64_t *rows, const double *values)
{
    size_t i;
    for (i = 0; i < count; i++) {
        const int64_t r = rows[i];
        ring[r * window + seen[r] % window] = (float)values[i];
        seen[r] += 1;
        total[r] += values[i];
    }
}

#define RANK_BITS 11u                           /* buckets of the radix select: 2^RANK_BITS */
#define RANK_BUCKETS (1u << RANK_BITS)

/** A float's bits as an unsigned integer in the float's order (negatives reversed below the
 * positives; every NaN last, as numpy sorts them). */
static uint32_t ordered_bits(float v)
{
    uint32_t b;
    memcpy(&b, &v, sizeof b);
    if ((b & 0x7FFFFFFFu) > 0x7F800000u) {
        return 0xFFFFFFFFu; /* any NaN: last */
    }
    return (b & 0x80000000u) ? ~b : (b | 0x80000000u);
}

static float from_ordered_bits(uint32_t k)
{
    const uint32_t b = (k & 0x80000000u) ? (k & 0x7FFFFFFFu) : ~k;
    float v;
    memcpy(&v, &b, sizeof v);
    return v;
}

/** The key of rank r (0-based) among keys[0 .. m-1], reordering them (Hoare's selection). */
static uint32_t select_key(uint32_t *keys, int64_t m, int64_t r)
{
    int64_t lo = 0, hi = m - 1;
    while (lo < hi) {
        const uint32_t pivot = keys[lo + (hi - lo) / 2];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (keys[i] < pivot) {
                i++;
            }
            while (keys[j] > pivot) {
                j--;
            }
            if (i <= j) {
                const uint32_t x = keys[i];
                keys[i++] = keys[j];
                keys[j--] = x;
            }
        }
        if (r <= j) {
            hi = j;
        } else if (r >= i) {
            lo = i;
        } else {
            return keys[r];
        }
    }
    return keys[r];
}

/** The keys of the count largest values of v[0 .. m-1] in ascending order into top (count within
 * 1 .. min(m, LSW_FUSE_RING_TOP)): one pass through a min-heap of the largest so far. */
static void top_keys(const float *v, int64_t m, int64_t count, uint32_t *top)
{
    int64_t k, i, c;
    for (k = 0; k < m; k++) {
        const uint32_t key = ordered_bits(v[k]);
        if (k < count) { /* filling: sift up */
            for (i = k; i > 0 && top[(i - 1) / 2] > key; i = (i - 1) / 2) {
                top[i] = top[(i - 1) / 2];
            }
            top[i] = key;
        } else if (key > top[0]) { /* larger than the least kept: it takes the root's place, sift down */
            for (i = 0; (c = 2 * i + 1) < count; i = c) {
                if (c + 1 < count && top[c + 1] < top[c]) {
                    c++;
                }
                if (top[c] >= key) {
                    break;
                }
                top[i] = top[c];
            }
            top[i] = key;
        }
    }
    for (k = 1; k < count; k++) { /* ascending: an insertion sort of a few */
        const uint32_t key = top[k];
        for (i = k; i > 0 && top[i - 1] > key; i--) {
            top[i] = top[i - 1];
        }
        top[i] = key;
    }
}

int lsw_fuse_ring_ranks(const float *ring, int64_t window, size_t count, const int64_t *rows, const int64_t *n,
                        size_t nranks, const int64_t *ranks, float *out)
{
    uint32_t counts[RANK_BUCKETS];
    /* scratch: the row's keys, then each rank's candidates */
    uint32_t *keys = nranks <= LSW_FUSE_MAX_RANKS ? malloc((size_t)window * (nranks + 1) * sizeof *keys) : NULL;
    size_t i, j;
    if (keys == NULL) {
        return -1;
    }
    for (i = 0; i < count; i++) {
        const float *v = ring + rows[i] * window;
        const int64_t m = n[i];
        const int64_t *rank = ranks + i * nranks;
        uint32_t bucket[LSW_FUSE_MAX_RANKS], below[LSW_FUSE_MAX_RANKS], got[LSW_FUSE_MAX_RANKS], top = 0;
        size_t pending = 0, todo[LSW_FUSE_MAX_RANKS];
        int64_t k, least = m - 1;
        for (j = 0; j < nranks; j++) {
            least = rank[j] < least ? rank[j] : least;
        }
        if (LSW_FUSE_RING_TOP_OF(m, least)) { /* only the top few asked (a high quantile, the max) */
            uint32_t best[LSW_FUSE_RING_TOP];
            top_keys(v, m, m - least, best);
            for (j = 0; j < nranks; j++) {
                out[i * nranks + j] = from_ordered_bits(best[rank[j] - least]);
            }
            continue;
        }
        memset(counts, 0, sizeof counts);
        for (k = 0; k < m; k++) {
            const uint32_t key = ordered_bits(v[k]);
            keys[k] = key;
            counts[key >> (32u - RANK_BITS)]++;
            top = key > top ? key : top;
        }
        for (j = 0; j < nranks; j++) {
            uint32_t b = 0, under = 0;
            if (rank[j] == m - 1) {  /* the largest: known */
                out[i * nranks + j] = from_ordered_bits(top);
                continue;
            }
            while (under + counts[b] <= (uint32_t)rank[j]) {
                under += counts[b++];
            }
            todo[pending] = j, bucket[pending] = b, below[pending] = under, got[pending] = 0;
            pending++;
        }
        if (pending) {  /* one pass gathers every pending rank's candidates: those of its bucket */
            for (k = 0; k < m; k++) {
                const uint32_t key = keys[k], b = key >> (32u - RANK_BITS);
                size_t p;
                for (p = 0; p < pending; p++) {
                    if (b == bucket[p]) {
                        keys[window * (p + 1) + got[p]++] = key;
                    }
                }
            }
        }
        for (j = 0; j < pending; j++) {
            uint32_t *mine = keys + window * (j + 1);
            out[i * nranks + todo[j]] = from_ordered_bits(select_key(mine, got[j], rank[todo[j]] - below[j]));
        }
    }
    free(keys);
    return 0;
}
