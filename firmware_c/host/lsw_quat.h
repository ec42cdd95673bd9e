/*
 * lsw_quat.h - quaternion helpers of the host library's C (w, x, y, z, double), computed as
 * limbstream.quat computes them, step for step. Host library only (lsw_grid.c, lsw_fuse.c).
 */
#ifndef LSW_QUAT_H
#define LSW_QUAT_H

#include <math.h>

#define LSW_NEAR_SIN 1e-6 /* SLERP by linear interpolation below this sin(angle), as limbstream.quat.slerp */

/** y /= |y|. */
static inline void lsw_quat_normalize(double *y)
{
    const double norm = sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3]);
    y[0] /= norm;
    y[1] /= norm;
    y[2] /= norm;
    y[3] /= norm;
}

/** The arc from unit q0 to unit q1 that SLERP follows (the shorter one): what lsw_quat_slerp_on
 * needs of the pair, the same for every u. */
typedef struct {
    double sign;      /* -1: q1 is taken as -q1 */
    double theta;     /* the arc's half-angle, rad */
    double sin_theta;
} LswArc;

static inline LswArc lsw_quat_arc(const double *q0, const double *q1)
{
    double dot = q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3];
    LswArc arc;
    arc.sign = dot < 0.0 ? -1.0 : 1.0;
    dot = fabs(dot);
    arc.theta = acos(dot > 1.0 ? 1.0 : dot);
    arc.sin_theta = sin(arc.theta);
    return arc;
}

/** SLERP from q0 to q1 on their arc (lsw_quat_arc) at u (0..1), normalised. */
static inline void lsw_quat_slerp_on(const double *q0, const double *q1, const LswArc *arc, double u, double *y)
{
    double w0, w1;
    int i;
    if (arc->sin_theta < LSW_NEAR_SIN) {
        w0 = 1.0 - u;
        w1 = u;
    } else {
        w0 = sin((1.0 - u) * arc->theta) / arc->sin_theta;
        w1 = sin(u * arc->theta) / arc->sin_theta;
    }
    for (i = 0; i < 4; i++) {
        y[i] = w0 * q0[i] + w1 * (arc->sign * q1[i]);
    }
    lsw_quat_normalize(y);
}

/** SLERP along the shorter arc from unit q0 to unit q1 at u (0..1), normalised: limbstream.quat.slerp. */
static inline void lsw_quat_slerp(const double *q0, const double *q1, double u, double *y)
{
    const LswArc arc = lsw_quat_arc(q0, q1);
    lsw_quat_slerp_on(q0, q1, &arc, u, y);
}

#endif
