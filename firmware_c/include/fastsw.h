/*
 * fastsw.h - fastSW: O(1) piecewise linear approximation of sample streams.
 *
 * Grützmacher, Kempfle, Van Laerhoven, Haubelt, "fastSW: Efficient Piecewise
 * Linear Approximation of Quaternion-Based Orientation Sensor Signals for
 * Motion Capturing with Wearable IMUs", Sensors 2021, 21, 5180.
 *
 * A segment runs from its anchor (the last segment point) a to the newest
 * sample n along the line through both. When the sum of squared residuals
 * (SSR) of the samples between them exceeds the threshold, or the segment
 * would cover more than max_len samples, the previous sample n-1 becomes a
 * segment point and the new segment's anchor. Segment points are a subset of
 * the input samples, bit for bit; they equal the Sliding Window's (sw.h).
 *
 * Live rule (settings.live_bound_deg = eps, quaternions): every segment point
 * carries a rate v (per tick, tangent to the point), and a receiver shows at
 * time t the newest point it has, extrapolated: normalise(y_a + (t - t_a) v).
 * The kernel makes the same prediction at every sample n; when it is more than
 * eps from sample n and the segment up to n still meets the SSR bound, sample
 * n itself closes the segment and becomes a segment point, with the rate that
 * extrapolates it back through sample n-1. A point closed by the SSR or max_len
 * rule (sample n-1, emitted at sample n) gets the rate that extrapolates it
 * through sample n. So every sample n is within eps of the prediction from the
 * points emitted up to its own update call (docs/kernel.md, "Live rule").
 * With the rule off the points are bit for bit those of plain fastSW.
 *
 * Usage:
 *     FastswSettings settings = fastsw_default_settings;
 *     settings.threshold = 1e-2f;
 *     FastswState state;
 *     fastsw_init(&state, &settings);
 *     for each sample: if (fastsw_update(&state, t, y, &point) == FASTSW_POINT) send(point);
 *     at end of stream: if (fastsw_flush(&state, &point) == FASTSW_POINT) send(point);
 *     with the live rule, fastsw_point_rate(&state, rate) after each FASTSW_POINT.
 *
 * Defined behaviour instead of errors:
 *
 * | input                                   | result                                    |
 * |-----------------------------------------|-------------------------------------------|
 * | y has a NaN or +-Inf component          | FASTSW_REJECTED, state unchanged          |
 * | |y - anchor|^2 overflows float          | FASTSW_REJECTED, state unchanged          |
 * | t not after the previous accepted t     | FASTSW_REJECTED, state unchanged          |
 * |   (zero or negative time step)          |                                           |
 * | t counter wraps around 2^32             | handled (differences are modulo 2^32)     |
 * | threshold < 0 or NaN                    | every accepted sample is a segment point  |
 * | max_len == 0                            | treated as 1                              |
 * | dim == 0 or dim > FASTSW_MAX_DIM        | fastsw_init returns FASTSW_BAD_SETTINGS   |
 * | live_bound_deg 0, negative, NaN, >= 180 | live rule off                             |
 * |   or +-Inf                              |                                           |
 * | live rule on and dim != 4               | FASTSW_BAD_SETTINGS (init and retune)     |
 * | live_bound_deg in (0, 0.05) degrees     | rule on; float32 resolves the bound only  |
 * |                                         |   to about 0.01 degrees                   |
 * | two consecutive samples 180 degrees     | the point between them gets rate 0 (no    |
 * |   apart (|y_p . y_r| < 1e-6)            |   finite rate passes through both)        |
 *
 * A rejected sample still consumes a sample index, so indices always count
 * update calls (the position in the caller's stream).
 */
#ifndef FASTSW_H
#define FASTSW_H

#include <stddef.h>
#include <stdint.h>

#include "fastsw_config.h"

#ifdef __cplusplus
extern "C" {
#endif

struct FastswBatchOut;

/** Result of fastsw_update / fastsw_flush / sw_update. */
typedef enum {
    FASTSW_NONE = 0,         /**< sample accepted, no segment point */
    FASTSW_POINT = 1,        /**< sample accepted, *point holds a new segment point */
    FASTSW_REJECTED = 2,     /**< sample rejected (non-finite or time not increasing) */
    FASTSW_BAD_SETTINGS = -1 /**< fastsw_init / fastsw_retune: settings out of range */
} FastswStatus;

/** Tuning of one stream. Copy fastsw_default_settings and adjust. */
typedef struct {
    float threshold;  /**< SSR threshold TH, in squared sample units (quaternion: unitless) */
    uint32_t max_len; /**< most samples one segment covers after its anchor (paper: 1000) */
    uint32_t dim;     /**< sample dimension D, 1..FASTSW_MAX_DIM (quaternion: 4) */
    float live_bound_deg; /**< live rule bound eps in degrees of rotation, on in (0, 180) */
} FastswSettings;

/** threshold 1e-2, max_len 1000, dim 4, live rule off. */
extern const FastswSettings fastsw_default_settings;

/** A segment point: a copy of one accepted input sample. */
typedef struct {
    uint32_t index;             /**< position in the stream (count of update calls before it) */
    uint32_t t;                 /**< its timestamp, in the caller's ticks */
    float y[FASTSW_MAX_DIM];    /**< its value, first dim entries used */
} FastswPoint;

/** Caller-owned state of one stream; O(D) memory. Fields are private. */
typedef struct {
    FastswSettings settings;
    uint32_t next_index;        /**< index the next update call gets */
    uint32_t count;             /**< accepted samples after the anchor; UINT32_MAX before the first */
    FastswPoint anchor;         /**< last segment point a */
    FastswPoint prev;           /**< last accepted sample n-1 */
    float syy;                  /**< sum over i in (a, n-1] of |y_i - y_a|^2 */
    float stt;                  /**< sum over i in (a, n-1] of (t_i - t_a)^2 */
    float sty[FASTSW_MAX_DIM];  /**< sum over i in (a, n-1] of (t_i - t_a)(y_i - y_a) */
    uint32_t live;              /**< 1 with the live rule on */
    float live_cos2;            /**< live rule: cos^2(eps / 2) */
    float rate[FASTSW_MAX_DIM]; /**< live rule: rate v of the anchor, per tick */
} FastswState;

/**
 * Reset *state for a new stream with a copy of *settings.
 * Returns FASTSW_NONE, or FASTSW_BAD_SETTINGS (state then unusable).
 */
FastswStatus fastsw_init(FastswState *state, const FastswSettings *settings);

/**
 * Feed one sample: t in ticks of any unit (e.g. microseconds; only ratios of
 * time differences matter), y of settings.dim floats. Returns FASTSW_POINT
 * and fills *point when a segment point is emitted (the first sample, the
 * previous sample at a segment break, or with the live rule this sample),
 * else FASTSW_NONE or FASTSW_REJECTED.
 */
FastswStatus fastsw_update(FastswState *state, uint32_t t, const float *y, FastswPoint *point);

/**
 * The rate v of the newest segment point (dim floats, value units per tick):
 * what the live rule extrapolates it with; read it after FASTSW_POINT. Zero
 * with the live rule off, for the first point and for a flushed one. v is
 * tangent to its point y (v . y = 0 for unit y), so the body angular rate
 * w = 2 vec(conj(y) v) carries it (docs/protocol.md, segment point v2).
 */
void fastsw_point_rate(const FastswState *state, float *rate);

/**
 * End of stream: emit the last accepted sample as a segment point unless it
 * already is one. Returns FASTSW_POINT or FASTSW_NONE. The state stays valid;
 * further updates continue the same stream.
 */
FastswStatus fastsw_flush(FastswState *state, FastswPoint *point);

/**
 * Change threshold, max_len and live_bound_deg of a running stream
 * (settings->dim must be the stream's). Takes effect from the next sample on;
 * segment points already sent stand. A live rule switched on extrapolates the
 * current anchor at rate 0 (what its point was sent with) until the next point.
 * Returns FASTSW_NONE, or FASTSW_BAD_SETTINGS (state unchanged).
 */
FastswStatus fastsw_retune(FastswState *state, const FastswSettings *settings);

/**
 * Batch: segment m samples (t: m ticks, y: m x dim floats, row-major) from a
 * fresh stream and flush, into *out (fastsw_batch.h: indices, points, the
 * update call that emitted each, rates; each may be NULL; capacity m points).
 * Returns the number of points K. *rejected (may be NULL) receives the number
 * of rejected samples.
 */
size_t fastsw_segment(const FastswSettings *settings, const uint32_t *t, const float *y, size_t m,
                      const struct FastswBatchOut *out, size_t *rejected);

/**
 * Many streams, one sample each (one tick of many devices): states[k] gets
 * t[k] and y[k*dim..]; status[k] receives each FastswStatus, points[k] the
 * point where status[k] == FASTSW_POINT, and rates[k*dim..] its rate there
 * (rates may be NULL). All states must share dim. Returns how many points
 * were emitted.
 */
size_t fastsw_update_many(FastswState *states, size_t count, const uint32_t *t, const float *y,
                          uint8_t *status, FastswPoint *points, float *rates);

/** sizeof(FastswState), for bindings that allocate states. */
size_t fastsw_state_size(void);

/** FASTSW_MAX_DIM of this build, for bindings. */
uint32_t fastsw_max_dim(void);

#ifdef __cplusplus
}
#endif

#endif /* FASTSW_H */
