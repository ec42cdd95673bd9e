/* lsw_gen.c - the built-in generator's kinematic tree (lsw_gen.h). */
#include "lsw_gen.h"

#include <math.h>

/** The half-angle cosine and the scale of the rotation by a (rad) about an axis:
 *  limbstream.quat.half_turns (scipy's from_rotvec). */
static void half_turn(double a, double *c, double *s) {
    double size = fabs(a);
    double half = size / 2;
    double scale;
    if (size <= 1e-3) {
        double size2 = size * size;
        scale = 0.5 - size2 / 48 + size2 * size2 / 3840;
    } else {
        scale = sin(half) / size;
    }
    *c = cos(half);
    *s = a * scale;
}

/** q times the rotation (c, s about axis): quat.multiply's eight products and four sums that do not
 *  multiply by zero. */
static void times_about_axis(const double *q, double c, double s, int32_t axis, double *out) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    if (axis == 0) {
        out[0] = w * c - x * s; out[1] = w * s + x * c; out[2] = y * c + z * s; out[3] = z * c - y * s;
    } else if (axis == 1) {
        out[0] = w * c - y * s; out[1] = x * c - z * s; out[2] = w * s + y * c; out[3] = x * s + z * c;
    } else {
        out[0] = w * c - z * s; out[1] = x * c + y * s; out[2] = y * c - x * s; out[3] = w * s + z * c;
    }
}

int lsw_gen_tree(size_t n, uint32_t nodes, const double *deg, const int32_t *axis, const int32_t *parent,
                 uint32_t outs, const int32_t *out_node, double *q) {
    if (nodes > LSW_GEN_MAX_NODES) return -1;
    for (uint32_t j = 0; j < nodes; j++)
        if (parent[j] >= (int32_t)j || parent[j] < -1 || axis[j] < 0 || axis[j] > 2) return -1;
    for (uint32_t k = 0; k < outs; k++)
        if (out_node[k] < 0 || out_node[k] >= (int32_t)nodes) return -1;
    double node[LSW_GEN_MAX_NODES][4];
    for (size_t i = 0; i < n; i++) {
        for (uint32_t j = 0; j < nodes; j++) {
            double c, s;
            half_turn(deg[j * n + i] * (3.141592653589793 / 180.0), &c, &s);  /* numpy's radians */
            if (parent[j] < 0) {
                node[j][0] = c; node[j][1] = node[j][2] = node[j][3] = 0.0;
                node[j][1 + axis[j]] = s;
            } else {
                times_about_axis(node[parent[j]], c, s, axis[j], node[j]);
            }
        }
        double *row = q + i * outs * 4;
        for (uint32_t k = 0; k < outs; k++)
            for (int m = 0; m < 4; m++) row[4 * k + m] = node[out_node[k]][m];
    }
    return 0;
}
