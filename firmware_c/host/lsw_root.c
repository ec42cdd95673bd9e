/*
 * lsw_root.c - root translation from foot contacts, frames one by one (see lsw_root.h).
 * Each line follows limbstream.body.translation.RootTracker.step for one frame (its names too).
 * Host library only.
 */
#include "lsw_root.h"

#include <math.h>
#include <string.h>

/** np.maximum: NaN if either is. */
static double maximum(double a, double b)
{
    if (isnan(a) || isnan(b)) {
        return NAN;
    }
    return a > b ? a : b;
}

/** np.argmin of n values (no NaN): the first of the smallest. */
static int64_t argmin(const double *v, int64_t n)
{
    int64_t best = 0;
    for (int64_t j = 1; j < n; ++j) {
        if (v[j] < v[best]) {
            best = j;
        }
    }
    return best;
}

/** One frame's inputs, checked (step's first lines). */
typedef struct {
    double p[LSW_ROOT_MAX_POINTS * 3]; /**< the points, non-finite values as 0 */
    double y[LSW_ROOT_MAX_POINTS];     /**< their heights, inf where not usable */
    int64_t lowest;
    double low_y, dt;
    int first, bad, hold, off_feet, whole;
} Frame;

static void read_frame(const LswRootState *s, const LswRootConst *k, const uint8_t *feet, int64_t r, double t,
                       const double *raw, const uint8_t *use, Frame *f)
{
    const int64_t np_ = s->n_points;
    int finite = 1, any_foot = 0;
    double foot_y = INFINITY;
    f->first = s->anchor[r] == k->first;
    f->whole = 1;
    for (int64_t j = 0; j < np_; ++j) {
        for (int a = 0; a < 3; ++a) {
            const double v = raw[j * 3 + a];
            finite &= isfinite(v) != 0;
            f->p[j * 3 + a] = isfinite(v) ? v : 0.0;
        }
        f->y[j] = use[j] ? f->p[j * 3 + 1] : INFINITY;
        any_foot |= use[j] && feet[j];
        f->whole &= use[j] || !feet[j];
        if (feet[j] && f->y[j] < foot_y) {
            foot_y = f->y[j];
        }
    }
    f->bad = !finite || !isfinite(t) || (!f->first && !(t > s->t[r]));
    f->hold = f->bad || !any_foot;
    f->lowest = argmin(f->y, np_);
    f->low_y = f->hold ? 0.0 : f->y[f->lowest];
    f->off_feet = !f->hold && (f->low_y < foot_y - k->off_feet_m);
    if (f->hold) {
        f->dt = 0.0;
    } else {
        const double d = t - s->t[r];
        f->dt = d < 0.0 ? 0.0 : (d > 0.5 ? 0.5 : d);
    }
}

/** The anchor's choice of a planted frame: sets *stands, *sw (a switch) and returns the anchor. */
static int64_t choose(const LswRootState *s, const LswRootConst *k, int64_t r, const Frame *f, double root_y,
                      int planted, int *stands, int *sw)
{
    const int64_t np_ = s->n_points;
    const double *last = s->points + r * np_ * 3, *velocity = s->velocity + r * 3;
    const uint8_t *seen = s->seen + r * np_;
    const double span = f->dt > 1e-6 ? f->dt : 1e-6;
    const int64_t anchor = s->anchor[r];
    double cost[LSW_ROOT_MAX_POINTS];
    int64_t best, keep;
    for (int64_t j = 0; j < np_; ++j) {
        double rel_x, rel_z, miss;
        if (!(root_y + f->y[j] < k->low_m)) { /* not down, whatever its motion (most points: only it is asked) */
            cost[j] = INFINITY;
            continue;
        }
        rel_x = (f->p[j * 3] - last[j * 3]) / span;
        rel_z = (f->p[j * 3 + 2] - last[j * 3 + 2]) / span;
        miss = seen[j] ? hypot(velocity[0] + rel_x, velocity[2] + rel_z) : k->unseen_mps;
        cost[j] = (f->whole || miss < k->still_mps) ? miss : INFINITY;
    }
    best = argmin(cost, np_);
    keep = anchor > 0 ? anchor : 0;
    *stands = planted && isfinite(cost[best]);
    *sw = *stands && (anchor < 0 || cost[keep] > cost[best] + k->keep_mps);
    return *sw ? best : keep;
}

/** One frame of row r: its root, bits and flags; the row's state moved if commit. */
static void frame(const LswRootState *s, const LswRootConst *k, const uint8_t *feet, const int64_t *contact_bit,
                  int64_t r, double t, const double *raw, const uint8_t *use, int commit, double *out_root,
                  int64_t *out_bits, int64_t *out_flags)
{
    const int64_t np_ = s->n_points;
    const double *root = s->root + r * 3, *velocity = s->velocity + r * 3, *pace = s->pace + r * 3;
    const double *last = s->points + r * np_ * 3;
    const uint8_t *seen = s->seen + r * np_;
    const int64_t anchor = s->anchor[r];
    Frame f;
    double fly[3], fly_v[3], new_root[3], anchor_xyz[3], new_velocity[3], new_pace[3], height, gain, slow;
    int flying, lands, takes_off, still_flying, planted, stands, sw, coast;
    int64_t put, new_anchor, bits = 0;
    read_frame(s, k, feet, r, t, raw, use, &f);
    memcpy(anchor_xyz, s->anchor_xyz + r * 3, sizeof anchor_xyz);
    /* ballistic: where the root would be from its last velocity under gravity */
    for (int a = 0; a < 3; ++a) {
        fly[a] = root[a] + velocity[a] * f.dt;
        fly_v[a] = velocity[a];
    }
    fly[1] -= 0.5 * k->gravity * (f.dt * f.dt);
    fly_v[1] -= k->gravity * f.dt;
    flying = anchor == k->flight;
    lands = flying && (fly[1] + f.low_y <= 0.0);
    takes_off = anchor >= 0 && f.whole && (fly[1] + f.low_y > k->take_off_mps * f.dt) && (fly_v[1] > 0.0);
    still_flying = ((flying && !lands) || takes_off) && !f.hold;
    planted = !still_flying && !f.first && !f.hold;
    memcpy(new_root, still_flying ? fly : root, sizeof new_root);
    height = (!f.whole && !f.off_feet) ? maximum(s->height[r], -f.low_y) : -f.low_y;
    if (planted) {
        new_root[1] = height;
    }
    put = choose(s, k, r, &f, new_root[1], planted, &stands, &sw);
    coast = planted && !stands;
    if (sw) {
        const double *at = f.p + put * 3;
        for (int a = 0; a < 3; a += 2) {
            if (lands) {
                anchor_xyz[a] = fly[a] + at[a];
            } else if (seen[put]) {
                anchor_xyz[a] = root[a] + last[put * 3 + a];
            } else {
                anchor_xyz[a] = root[a] + velocity[a] * f.dt + at[a];
            }
        }
        anchor_xyz[1] = 0.0;
    }
    if (stands) {
        new_root[0] = anchor_xyz[0] - f.p[put * 3];
        new_root[2] = anchor_xyz[2] - f.p[put * 3 + 2];
    }
    if (coast) {
        new_root[0] += pace[0] * f.dt;
        new_root[2] += pace[2] * f.dt;
    }
    if (f.first) {
        new_root[0] = 0.0;
        new_root[1] = -f.low_y;
        new_root[2] = 0.0;
    }
    new_anchor = still_flying ? k->flight : (f.first ? f.lowest : (coast ? k->coast : put));
    if (f.first) {
        anchor_xyz[0] = new_root[0] + f.p[f.lowest * 3];
        anchor_xyz[1] = 0.0;
        anchor_xyz[2] = new_root[2] + f.p[f.lowest * 3 + 2];
    }
    {
        const double span = f.dt > 1e-6 ? f.dt : 1e-6;
        gain = (f.dt > 0 && !f.first) ? 1.0 - exp(-f.dt / k->velocity_s) : 0.0;
        slow = (f.dt > 0 && !f.first && f.whole) ? 1.0 - exp(-f.dt / k->pace_s) : 0.0;
        for (int a = 0; a < 3; ++a) {
            const double moved = (new_root[a] - root[a]) / span;
            new_velocity[a] = still_flying ? fly_v[a] : (f.first ? 0.0 : velocity[a] + gain * (moved - velocity[a]));
            new_pace[a] = f.first ? 0.0 : pace[a] + slow * (moved - pace[a]);
        }
    }
    for (int64_t j = 0; j < np_; ++j) {
        if (feet[j] && new_root[1] + f.y[j] <= k->contact_m && !still_flying && !f.hold) {
            bits |= (int64_t)1 << contact_bit[j];
        }
    }
    *out_bits = bits;
    *out_flags = f.off_feet ? k->off_feet_flag : 0;
    memcpy(out_root, f.hold ? root : new_root, sizeof new_root);
    if (commit && !f.hold) {
        memcpy(s->root + r * 3, new_root, sizeof new_root);
        memcpy(s->velocity + r * 3, new_velocity, sizeof new_velocity);
        memcpy(s->pace + r * 3, new_pace, sizeof new_pace);
        memcpy(s->anchor_xyz + r * 3, anchor_xyz, sizeof anchor_xyz);
        memcpy(s->points + r * np_ * 3, f.p, sizeof(double) * (size_t)np_ * 3);
        memcpy(s->seen + r * np_, use, (size_t)np_);
        s->anchor[r] = new_anchor;
        s->t[r] = t;
        if (f.whole || f.first) {
            s->height[r] = new_root[1];
        }
    }
    if (commit && f.bad) {
        s->refused[r] += 1;
    }
}

void lsw_root_frames(const LswRootState *state, const LswRootConst *k, const uint8_t *feet,
                     const int64_t *contact_bit, size_t n_frames, const int64_t *owner, const double *t,
                     const double *points, const uint8_t *usable, const uint8_t *commit, double *root_out,
                     int64_t *bits_out, int64_t *flags_out)
{
    const size_t np_ = (size_t)state->n_points;
    for (size_t i = 0; i < n_frames; ++i) {
        frame(state, k, feet, contact_bit, owner[i], t[i], points + i * np_ * 3, usable + i * np_, commit[i] != 0,
              root_out + i * 3, bits_out + i, flags_out + i);
    }
}
