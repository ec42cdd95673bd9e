/*
 * lsw_fuse.h - the aggregator's reconstruction of its devices' streams from their segment
 * points, many queries in one call (services/aggregator/store.py, PointStore), and the joint
 * positions of many bodies (limbstream/skeleton.py). Host library only.
 *
 * Row r of a point store holds n[r] points in time order: times t[r][k] (int64 us), orientations
 * q[r][k] (float32 w, x, y, z, any nonzero norm) and body rates w[r][k] (float32 rad/s, 0: held),
 * in arrays of cap points per row. Every result is computed in double as limbstream.quat.slerp,
 * .predict and .angle_deg compute it, step for step (tests/test_kernel_fuse.py checks them
 * against each other).
 */
#ifndef LSW_FUSE_H
#define LSW_FUSE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** What a query asks of a row at its time. */
typedef enum {
    LSW_FUSE_EXACT = 0,     /**< SLERP between the points around the time, held before the first and after the
                                 last point; identity for an empty row */
    LSW_FUSE_LIVE = 1,      /**< EXACT where a point at or after the time is known, else the newest point
                                 extrapolated with its rate (a live frame's segment) */
    LSW_FUSE_PREDICTED = 2, /**< the newest point at or before the time extrapolated with its rate (what a
                                 receiver knowing only those points shows then); identity if there is none */
} LswFuseMode;

/** A SLERP span remembered between calls: the two points it joins, as stored, and what SLERP needs
 * of them. Opaque: a row has LSW_FUSE_SPANS of them, lsw_fuse_row_spans_size() bytes. */
typedef struct LswFuseSpan LswFuseSpan;

/** Bytes of a row's LSW_FUSE_SPANS spans. */
size_t lsw_fuse_row_spans_size(void);

/** The rows of a point store (see the top of this file). */
typedef struct {
    const int64_t *t; /**< rows x cap times, us */
    const float *q;   /**< rows x cap x 4 orientations */
    const float *w;   /**< rows x cap x 3 body rates, rad/s */
    const int64_t *n; /**< rows: points held */
    int64_t cap;      /**< points per row at most */
    LswFuseSpan *spans; /**< rows x LSW_FUSE_SPANS spans the queries last used, zeroed at first (NULL: none);
                             one is reused only where its points' times and stored values are the same,
                             bit for bit, so the rows may change in any way between calls */
} LswFuseRows;

#define LSW_FUSE_SPANS 2 /**< spans remembered per row: an exact frame's and a truth sample's */

/**
 * out[i] (4 doubles, unit norm): row slots[i] at time t_us[i] (us) as mode[i] (LswFuseMode) asks.
 */
void lsw_fuse_reconstruct(const LswFuseRows *rows, size_t count, const int64_t *slots, const int64_t *t_us,
                          const uint8_t *mode, double *out);

/**
 * Angular error (degrees, 2 acos |<a, b>| of the normalised pair) of the EXACT and of the
 * PREDICTED reconstruction of row slots[i] at t_us[i] against truth[i] (4 floats), into
 * exact_deg[i] and predicted_deg[i].
 */
void lsw_fuse_errors(const LswFuseRows *rows, size_t count, const int64_t *slots, const int64_t *t_us,
                     const float *truth, double *exact_deg, double *predicted_deg);

/**
 * Append count values to ring windows of window values per row, in order: value i goes to row
 * rows[i] at ring[rows[i]][seen[rows[i]] % window] (as float), then seen[rows[i]] += 1 and
 * total[rows[i]] += value (in double, in the order given). services/aggregator/rings.py.
 */
void lsw_fuse_ring_append(float *ring, int64_t *seen, double *total, int64_t window, size_t count,
                          const int64_t *rows, const double *values);

/**
 * Order statistics of ring windows: out[i * nranks + j] = the value of rank ranks[i * nranks + j]
 * (0: the smallest) among the first n[i] values of row rows[i] of ring (window floats per row);
 * each rank within 0 .. n[i] - 1, n[i] within 1 .. window. The same values as sorting the row's
 * values (as numpy orders floats; -0 before +0, NaN last): a radix select on the floats'
 * ordered bits: one pass counts the row's values by their top 11 bits (and finds the largest), one
 * pass gathers each rank's candidates (the values of its bucket), and a selection among them
 * picks it. A row whose ranks are all among its few largest (a high quantile and the maximum:
 * LSW_FUSE_RING_TOP_OF) takes them from one pass through a heap of its largest values instead.
 * Returns 0, or -1 where no scratch memory could be had or nranks exceeds LSW_FUSE_MAX_RANKS (out
 * untouched).
 * services/aggregator/rings.py.
 */
#define LSW_FUSE_MAX_RANKS 8u /**< ranks per row at most (lsw_fuse_ring_ranks) */
#define LSW_FUSE_RING_TOP 64u  /**< ranks among a row's largest this many ... */
/** ... and its largest eighth at most: taken from a heap (lsw_fuse_ring_ranks), for m values, least the lowest rank */
#define LSW_FUSE_RING_TOP_OF(m, least) ((m) - (least) <= (int64_t)LSW_FUSE_RING_TOP && 8 * ((m) - (least)) <= (m))
int lsw_fuse_ring_ranks(const float *ring, int64_t window, size_t count, const int64_t *rows, const int64_t *n,
                        size_t nranks, const int64_t *ranks, float *out);

#define LSW_FUSE_MAX_JOINTS 64u /**< joints of a body at most (lsw_fuse_chain) */

/**
 * Forward kinematics of count bodies: out[i] (joints x 3 floats) the joint positions of body i,
 * whose segment orientations are q[i] (segments x 4 doubles, unit norm). Bone b places joint
 * joint[b] at its parent joint parent[b] (-1: the origin) plus bone vector vec[b] (3 doubles;
 * alt_vec[b] where alt[i] is 1) turned by segment segment[b]'s orientation
 * (limbstream.quat.rotate), or, where toward is not NULL and toward[b] >= 0 (a bent bone), by
 * the SLERP from it toward segment toward[b]'s by share[b] (limbstream.quat.slerp); bones come
 * parents first, and joints no bone places stay at the origin. Sums in double, stored as float
 * (limbstream.skeleton.Skeleton.positions), or as double into out64 when it is not NULL (then
 * out is not written).
 */
void lsw_fuse_chain(size_t count, const double *q, uint32_t segments, const uint8_t *alt, uint32_t bones,
                    const int32_t *segment, const int32_t *joint, const int32_t *parent, const int32_t *toward,
                    const double *share, const double *vec, const double *alt_vec, uint32_t joints, float *out,
                    double *out64);

#ifdef __cplusplus
}
#endif

#endif
