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
 * VQF (src/lsw_vqf.cpp) with its low-pass filter states, their coefficients and its 3x3 inverse
 * in float instead of double: no soft-float double arithmetic per raw sample on a Cortex-M4 (about
 * 1,950 instead of 19,100 instructions per raw sample), at a cost in accuracy against VQF as its
 * authors built it (docs/kernel.md, "Raw samples: VQF on the device"). 0: VQF's own precision.
 * Set it here, not on one build's command line: host and firmware must compute the same.
 */
#ifndef LSW_VQF_FLOAT
#define LSW_VQF_FLOAT 0
#endif

#if defined(FASTSW_FIXED_DIM)
#define FASTSW_DIM(settings) ((uint32_t)FASTSW_FIXED_DIM)
#else
#define FASTSW_DIM(settings) ((settings)->dim)
#endif

#endif /* FASTSW_CONFIG_H */
