/*
 * lsw_root.h - root translation from foot contacts, the per-frame state machine of
 * limbstream.body.translation.RootTracker.step, frames one by one (docs/body.md, "Root
 * translation"). Host library only.
 *
 * N rows (bodies) of P points each. Every frame belongs to a row and is taken against that row's
 * state as the committed frames before it left it; a committed frame (an exact one) moves it, an
 * uncommitted one (a live frame) only reads it. Every value
 * is computed in double as the numpy step computes it, operation for operation
 * (tests/test_root_tracker_c.py checks them against each other).
 */
#ifndef LSW_ROOT_H
#define LSW_ROOT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_ROOT_MAX_POINTS 128 /**< P at most */

/** The trackers' state, N rows (RootTracker's arrays, C order): updated in place on commit. */
typedef struct {
    double *root;       /**< N x 3, m */
    double *velocity;   /**< N x 3, m/s */
    double *pace;       /**< N x 3, m/s */
    int64_t *anchor;    /**< N: the anchor's point index, or LswRootConst.first / .flight / .coast */
    double *anchor_xyz; /**< N x 3, m: the anchor's world position */
    double *t;          /**< N: newest frame time, s */
    double *height;     /**< N: the root's height with both feet, m */
    double *points;     /**< N x P x 3: the last points, m */
    uint8_t *seen;      /**< N x P: which of them were usable */
    int64_t *refused;   /**< N: frames refused */
    int64_t n_points;   /**< P, at most LSW_ROOT_MAX_POINTS */
} LswRootState;

/** The tracker's constants (limbstream.body.translation: defined there, passed in). */
typedef struct {
    double gravity, take_off_mps, contact_m, low_m, keep_mps, velocity_s, pace_s, still_mps, unseen_mps,
        off_feet_m;
    int64_t first, flight, coast; /**< anchor codes: no frame yet, in flight, going on at its pace */
    int64_t off_feet_flag;        /**< FRAME_OFF_FEET */
} LswRootConst;

/**
 * Track F frames in the order given: frame f of row owner[f] at time t[f] (s) with points
 * points[f] (P x 3, m, root-relative), usable[f] (P: 0 not to go on). feet (P): the foot points;
 * contact_bit (P): each foot point's bit in the contact bits. Writes each frame's root (F x 3, m),
 * contact bits (F) and flags (F). commit (F): a frame whose commit is nonzero moves its row's state
 * (refused frames counted), one whose commit is 0 reads it and leaves it as it was; each frame is
 * taken against its row's state as the committed frames before it left it.
 */
void lsw_root_frames(const LswRootState *state, const LswRootConst *k, const uint8_t *feet,
                     const int64_t *contact_bit, size_t n_frames, const int64_t *owner, const double *t,
                     const double *points, const uint8_t *usable, const uint8_t *commit, double *root_out,
                     int64_t *bits_out, int64_t *flags_out);

#ifdef __cplusplus
}
#endif

#endif
