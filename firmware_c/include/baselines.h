/*
 * baselines.h - the fastSW paper's line-fitting baselines, CPLR and the Swing filter, with
 * fastSW's interface (fastsw.h): a caller-owned state, *_init, *_update, *_flush and a batch
 * *_segment. O(1) time and O(D) memory per sample each.
 *
 * CPLR: online connected piecewise linear regression. After Grützmacher, Beichler, Hein,
 * Kirste, Haubelt, "Time and Memory Efficient Online Piecewise Linear Approximation of Sensor
 * Signals", Sensors 2018, 18(6), 1672, as used as a baseline in the fastSW paper (Sensors 2021,
 * 21, 5180):
 *
 * - A segment starts at its anchor a, the last segment point, which stays
 *   fixed (connected segments). For the samples a < i <= n the line
 *   y = y_a + beta (t - t_a) is fitted by least squares with the intercept
 *   fixed at the anchor: beta_d = Sty_d / Stt (eq. C1, cplr.c).
 * - Its sum of squared residuals over all D dimensions is
 *   SSR = Syy - |Sty|^2 / Stt (eq. C2), from D + 2 running sums.
 * - When a new sample n makes SSR > threshold (or the segment would cover
 *   more than max_len samples), the segment closes at the previous sample
 *   n-1: the point emitted is the line fitted to a < i <= n-1, evaluated at
 *   t_{n-1}. It becomes the next anchor, and sample n is the first sample
 *   of the new segment.
 * - The SSR test is done in float (-ffp-contract=off); with Syy much larger than
 *   the SSR it cancels, so decisions near the threshold are accurate to about
 *   1e-7 Syy.
 *
 * Swing filter: an L-infinity error bound. After Elmeleegy, Chandramouli, Madhavan, Sistla,
 * Thompson, "Online Piece-wise Linear Approximation of Numerical Streams with Precision
 * Guarantees", PVLDB 2(1), 2009, as used as a baseline in the fastSW paper:
 *
 * - A segment starts at its anchor a, the last segment point (connected
 *   segments). Per dimension d it keeps the range [lo_d, hi_d] of slopes
 *   (sample units per tick) whose line through the anchor passes within
 *   epsilon = threshold of every sample since the anchor. A sample n narrows
 *   it to its intersection with [(y_nd - eps) / t_n, (y_nd + eps) / t_n]
 *   (eq. S1: the upper line swings down, the lower line swings up).
 * - When that intersection is empty in any dimension (or the segment would
 *   cover more than max_len samples), the segment closes at the previous
 *   sample n-1 on the line whose slope is the least-squares slope through
 *   the anchor, clamped to [lo_d, hi_d] (eq. S2, the paper's choice of the
 *   line minimising the mean squared error among the admissible ones). Its
 *   value at t_{n-1} is the point and the next anchor; sample n starts the
 *   new segment. Every sample of a segment is thus within eps of the
 *   segment's line in every dimension (to float rounding).
 *
 * Both: the first sample of a stream is a point (copied); flush ends the stream with the line's
 * value at the last accepted sample. Segment points are NOT input samples: a point has the
 * timestamp (and index) of a sample but a value on the line (for quaternions, normalise the
 * points before SLERP). Settings are FastswSettings: threshold is CPLR's SSR bound (squared
 * sample units) or the Swing filter's eps (the largest absolute deviation per dimension, sample
 * units); max_len and dim as in fastsw.h. Points are FastswPoint (index and t of the sample whose
 * time the point has, y the line's value there).
 *
 * Defined behaviour instead of errors: exactly the table of fastsw.h (a rejected sample -
 * NaN/Inf, overflow, time not increasing - leaves the state unchanged and still consumes an
 * index; threshold < 0 or NaN acts as 0; max_len 0 acts as 1; bad dim -> FASTSW_BAD_SETTINGS).
 */
#ifndef BASELINES_H
#define BASELINES_H

#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

/** What every baseline's state begins with (CPLR, Swing, the Sliding Window). Fields are private. */
typedef struct {
    FastswSettings settings;
    uint32_t next_index;        /**< index the next update call gets */
    uint32_t count;             /**< accepted samples after the anchor */
    uint32_t started;           /**< 1 once the first sample was accepted */
    FastswPoint anchor;         /**< last segment point */
    FastswPoint prev;           /**< last accepted input sample */
} BaselineStream;

/** Caller-owned CPLR state of one stream; O(D) memory. Fields are private. */
typedef struct {
    BaselineStream stream;      /**< its anchor: the fitted line's value at the last break */
    float syy;                  /**< sum over i in (a, n-1] of |y_i - y_a|^2 */
    float stt;                  /**< sum over i in (a, n-1] of (t_i - t_a)^2, ticks^2 */
    float sty[FASTSW_MAX_DIM];  /**< sum over i in (a, n-1] of (t_i - t_a)(y_i - y_a) */
} CplrState;

/** Caller-owned swing filter state of one stream; O(D) memory. Fields are private. */
typedef struct {
    BaselineStream stream;      /**< its anchor: the value on the previous line */
    float stt;                  /**< sum over i in (a, n-1] of (t_i - t_a)^2, ticks^2 */
    float sty[FASTSW_MAX_DIM];  /**< sum over i in (a, n-1] of (t_i - t_a)(y_i - y_a) */
    float lo[FASTSW_MAX_DIM];   /**< lowest admissible slope per dimension, units/tick */
    float hi[FASTSW_MAX_DIM];   /**< highest admissible slope per dimension, units/tick */
} SwingState;

/** Reset *state for a new stream; FASTSW_NONE or FASTSW_BAD_SETTINGS. */
FastswStatus cplr_init(CplrState *state, const FastswSettings *settings);
FastswStatus swing_init(SwingState *state, const FastswSettings *settings);

/**
 * Feed one sample (t ticks, y of dim floats). Returns FASTSW_POINT and fills *point when a
 * segment point is emitted (the first sample, or the line's value at the previous sample's time
 * on a break), else FASTSW_NONE or FASTSW_REJECTED.
 */
FastswStatus cplr_update(CplrState *state, uint32_t t, const float *y, FastswPoint *point);
FastswStatus swing_update(SwingState *state, uint32_t t, const float *y, FastswPoint *point);

/**
 * End of stream: emit the line's value at the last accepted sample, unless that sample already
 * is the anchor. FASTSW_POINT or FASTSW_NONE.
 */
FastswStatus cplr_flush(CplrState *state, FastswPoint *point);
FastswStatus swing_flush(SwingState *state, FastswPoint *point);

/**
 * Batch: segment m samples (t: m ticks, y: m x dim floats, row-major) from a fresh stream and
 * flush. Writes the points to out (capacity m) and returns their count K. *rejected (may be
 * NULL) receives the rejected sample count.
 */
size_t cplr_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                    FastswPoint *out, size_t *rejected);
size_t swing_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                     FastswPoint *out, size_t *rejected);

/** sizeof(CplrState), sizeof(SwingState), for bindings. */
size_t cplr_state_size(void);
size_t swing_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* BASELINES_H */
