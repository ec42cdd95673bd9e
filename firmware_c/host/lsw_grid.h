/*
 * lsw_grid.h - samples that arrive at a sender's own irregular times, put on a uniform grid per
 * device (the SlimeVR gateway's devices: docs/protocol.md, "SlimeVR gateway", "Timing"). Host
 * library only.
 *
 * Each device keeps its sender's last LSW_GRID_HISTORY samples (arrival time, quaternion), a grid
 * of instants one period apart locked to the lower edge of their arrivals, and its truth samples
 * (every sample, for the truth tap) until they are taken. Per tick, lsw_grid_tick gives every
 * device its sample at its grid instant: the sample that arrived just after it (delayed on its
 * way: the instant's own, and its truth sample is stamped at the instant), else the SLERP of the
 * two around it, or the newest one held.
 *
 * Times are microseconds (the gateway's clock) unless named otherwise; quaternions (w, x, y, z).
 */
#ifndef LSW_GRID_H
#define LSW_GRID_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_GRID_HISTORY 16u /**< samples each device keeps for its grid samples */
#define LSW_GRID_TRUTH 512u  /**< truth samples a device holds at most; more: the oldest is dropped */
#define LSW_GRID_JITTER 500u /**< arrival offsets kept for the jitter figure */

/** What every device of a bank shares. */
typedef struct {
    double period_us;   /**< grid period */
    double hold_us;     /**< the newest sample is held at most this long after it arrived */
    double late_us;     /**< a sample this little after an instant is the instant's own */
    double early_us;    /**< ... or this little before it */
    double phase_gain;  /**< share of a late arrival's offset the grid moves by */
    double offset_us;   /**< common time base minus the gateway's clock (truth stamps), set per tick */
    double axes[4];     /**< turn applied to every sample as it arrives (axes * q) */
    uint32_t rise_after; /**< arrivals after an early one before the grid may move later again */
    uint32_t truth;     /**< 1: keep truth samples */
} LswGridSettings;

/** One device. Zero it (lsw_grid_reset) for a new stream. */
typedef struct {
    double hist_t[LSW_GRID_HISTORY];      /**< arrivals, a ring from hist_head, increasing */
    double hist_q[LSW_GRID_HISTORY][4];   /**< their samples, turned */
    int64_t truth_t[LSW_GRID_TRUTH];      /**< truth stamps (common time base) not yet taken */
    double truth_a[LSW_GRID_TRUTH];       /**< their arrivals (increasing) */
    float truth_q[LSW_GRID_TRUTH][4];     /**< their samples, turned */
    float jitter[LSW_GRID_JITTER];        /**< |arrival - grid instant| of recent samples, a ring */
    double instant;      /**< grid instant of the last tick (valid when has_instant) */
    double anchor;       /**< arrival of the stream's first sample: where the grid starts */
    double shift;        /**< correction of the grid since the last tick */
    double truth_since;  /**< monotonic s of the oldest truth sample */
    int64_t last_t;      /**< common-time stamp of the last grid sample */
    int64_t held;        /**< grid samples held (no sample after the instant yet) */
    int64_t truth_dropped; /**< truth samples dropped (more than LSW_GRID_TRUTH waiting) */
    uint32_t hist_len, hist_head;
    uint32_t truth_len;
    uint32_t jitter_len, jitter_head;
    uint32_t no_rise;    /**< arrivals before the grid may move later again */
    uint32_t quiet;      /**< ticks since the last grid sample */
    uint8_t has_instant, has_anchor;
    uint8_t online;      /**< 1: the device has a stream (set by the caller) */
    uint8_t pad[5];
} LswGridDevice;

/** A new stream: no samples, no grid, no truth (the jitter figure and online flag stay). */
void lsw_grid_reset(LswGridDevice *d);

/**
 * A sample q (unit, the sender's axes) that arrived at t_us (kept increasing: one at or before
 * the previous arrival is taken 1 us after it), at monotonic now_s: it moves the grid
 * (lock to the lower edge of the arrivals), joins the history and the truth samples.
 */
void lsw_grid_push(const LswGridSettings *s, LswGridDevice *d, double t_us, const double *q, double now_s);

/**
 * One tick at the gateway's grid instant at_us: each online device of devices[0..count-1] moves
 * its grid instant to the one for this tick and takes its sample there. have[k] 1: y[k] (4
 * floats, turned), tick[k] (its instant mod 2^32) and stamp[k] (common time base, also d->last_t)
 * are its sample; 0: none (y NaN; quiet counts up). Returns how many devices have one.
 */
size_t lsw_grid_tick(const LswGridSettings *s, LswGridDevice *devices, size_t count, double at_us,
                     uint8_t *have, uint32_t *tick, int64_t *stamp, float *y);

/**
 * Online devices whose truth is due at monotonic now_s: at least `batch` settled samples (arrived
 * before the device's last instant plus late_us: no later tick can restamp them), or some settled
 * ones waiting max_age_s. slots[i], n[i]: the device and how many to take. Returns how many.
 */
size_t lsw_grid_truth_due(const LswGridSettings *s, const LswGridDevice *devices, size_t count,
                          double now_s, uint32_t batch, double max_age_s, uint32_t *slots, uint32_t *n);

/**
 * Takes the device's first n truth samples into t (stamps made non-decreasing) and q (n x 4);
 * returns how many (at most truth_len). The rest wait from now_s.
 */
uint32_t lsw_grid_take_truth(LswGridDevice *d, uint32_t n, int64_t *t, float *q, double now_s);

#ifdef __cplusplus
}
#endif

#endif /* LSW_GRID_H */
