/*
 * lsw_gen.h - the built-in generator's kinematic tree (limbstream.sources.generator): segment
 * orientations from joint angles, every sample of a chunk in one call. Host library only.
 *
 * A tree of elementary rotations (nodes, parents first): node j turns its parent's orientation
 * by its angle about a coordinate axis, or starts from the identity (parent -1). Every value is
 * computed in double as numpy computes it (degrees to radians as np.radians, scipy's half-angle
 * scale with its series below 1e-3 rad as limbstream.quat.half_turns), and each node is the
 * Hamilton product of its parent by the elementary rotation with the products by its zero parts
 * left out: limbstream.quat.multiply's values but for the sign of an exact zero (tests/test_quat.py,
 * tests/test_emulator_equality.py hold it to them).
 */
#ifndef LSW_GEN_H
#define LSW_GEN_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_GEN_MAX_NODES 64u /**< nodes of a tree at most */

/**
 * Orientations of n samples. deg (nodes x n, row j node j's angles, degrees), axis (nodes: 0 X,
 * 1 Y, 2 Z), parent (nodes: an earlier node, or -1), out_node (outs: the node whose orientation
 * is output k). Writes q (n x outs x 4, w x y z). Returns 0, or -1 if nodes exceeds
 * LSW_GEN_MAX_NODES or a parent or output is no earlier node (nothing written then).
 */
int lsw_gen_tree(size_t n, uint32_t nodes, const double *deg, const int32_t *axis, const int32_t *parent,
                 uint32_t outs, const int32_t *out_node, double *q);

#ifdef __cplusplus
}
#endif

#endif
