/*
 * fastsw_config.h - every compile-time switch of the limbstream kernels, in one place.
 *
 * Override any of these with -D on the compiler command line.
 */
#ifndef FASTSW_CONFIG_H
#define FASTSW_CONFIG_H

/* Largest sample dimension D a state can hold (4 for quaternions). */
#ifndef FASTSW_MAX_DIM
#define FASTSW_MAX_DIM 8
#endif

/*
 * Fix D at compile time (e.g. -DFASTSW_FIXED_DIM=4 on the Cortex-M4) so the
 * per-dimension loops unroll. Left undefined, D is read from the settings at
 * run time (host library: any D up to FASTSW_MAX_DIM). Both compute the same
 * operations in the same order, so results are bit-identical.
 */
/* #define FASTSW_FIXED_DIM 4 */

/* Capacity of the baseline Sliding Window buffer (samples after the anchor). */
#ifndef SW_MAX_LEN
#define SW_MAX_LEN 1000
#endif

/*
 * VQF's precision (src/lsw_vqf.cpp, lsw_vqf.h): 0, single, the default (its low-pass filter states,
 * their coefficients and its 3x3 inverse in float, but the accelerometer low-pass filter's in
 * float-float: a seventh of double's instructions on a Cortex-M4, within 0.01 deg of double's error
 * against optical truth on every BROAD trial: docs/kernel.md, "VQF's precision"), or 1, double
 * (VQF's own: those in double, soft-float on a Cortex-M4). The firmware is built with this one only
 * (firmware_c/Makefile VQF_PRECISION); the host library with both (LSW_VQF_BOTH 1, setup.py),
 * chosen per device at run time (LswImuSettings.vqf_precision), this one by default.
 */
#ifndef LSW_VQF_DEFAULT_DOUBLE
#define LSW_VQF_DEFAULT_DOUBLE 0
#endif
#ifndef LSW_VQF_BOTH
#define LSW_VQF_BOTH 0
#endif

#if defined(FASTSW_FIXED_DIM)
#define FASTSW_DIM(settings) ((uint32_t)FASTSW_FIXED_DIM)
#else
#define FASTSW_DIM(settings) ((settings)->dim)
#endif

#endif /* FASTSW_CONFIG_H */
