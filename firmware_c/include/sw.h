/*
 * sw.h - the buffered Sliding Window (SW) baseline: O(n) time per sample.
 *
 * Same semantics and same segment points as fastSW (fastsw.h): the anchor is
 * the last segment point, the temporary segment runs to the newest sample n,
 * and when the SSR of the buffered samples against it exceeds the threshold
 * (or the segment would exceed max_len) sample n-1 becomes a segment point.
 * It keeps every sample since the anchor and recomputes the SSR from them
 * (paper, Algorithm "SW"), so its cost grows with the segment length n.
 * Inputs are treated exactly as in fastsw.h (same rejection rules).
 * The SSR is computed differently, so decisions that tie with the threshold
 * to float precision may differ ("quasi-equal", paper Sect. 6.2).
 */
#ifndef SW_H
#define SW_H

#include "baselines.h"
#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Caller-owned SW state; holds up to SW_MAX_LEN samples. Fields are private. */
typedef struct {
    BaselineStream stream;                      /**< count: buffered samples after the anchor */
    float t_rel[SW_MAX_LEN];                    /**< t_i - t_a of the buffered samples */
    float y_rel[SW_MAX_LEN][FASTSW_MAX_DIM];    /**< y_i - y_a of the buffered samples */
} SwState;

/** As fastsw_init; max_len is capped at SW_MAX_LEN. */
FastswStatus sw_init(SwState *state, const FastswSettings *settings);

/** As fastsw_update, in O(count) time. */
FastswStatus sw_update(SwState *state, uint32_t t, const float *y, FastswPoint *point);

/** As fastsw_flush. */
FastswStatus sw_flush(SwState *state, FastswPoint *point);

/** As fastsw_segment, with caller-provided work state (it is large). */
size_t sw_segment(SwState *work, const FastswSettings *settings, const uint32_t *t, const float *y,
                  size_t m, uint32_t *out_index, size_t *rejected);

/** sizeof(SwState). */
size_t sw_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* SW_H */
