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

/** SLERP along the shorter arc from unit q0 to unit q1 at u (0..1), normalised: limbstream.quat.slerp. */
static inline void lsw_quat_slerp(const double *q0, const double *q1, double u, double *y)
{
    double dot = q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3];
    const double sign = dot < 0.0 ? -1.0 : 1.0;
    double theta, sin_theta, w0, w1;
    int i;
    dot = fabs(dot);
    theta = acos(dot > 1.0 ? 1.0 : dot);
    sin_theta = sin(theta);
    if (sin_theta < LSW_NEAR_SIN) {
        w0 = 1.0 - u;
        w1 = u;
    } else {
        w0 = sin((1.0 - u) * theta) / sin_theta;
        w1 = sin(u * theta) / sin_theta;
    }
    for (i = 0; i < 4; i++) {
        y[i] = w0 * q0[i] + w1 * (sign * q1[i]);
    }
    lsw_quat_normalize(y);
}

#endif
