/*
 * lsw_vqf.h - VQF, the orientation filter, behind a plain C API (src/lsw_vqf.cpp).
 *
 * D. Laidig, T. Seel, "VQF: Highly Accurate IMU Orientation Estimation with Bias Estimation and
 * Magnetic Disturbance Rejection", Information Fusion 91, 2023. Its C++ (class VQF, MIT licence)
 * is the `vqf` Python package's own source with its filters' precision made a type (firmware_c/vqf),
 * compiled with -DVQF_SINGLE_PRECISION (floats in and out) and -ffp-contract=off on the host and on
 * the Cortex-M4 alike, in one or both of two precisions (LSW_VQF_SINGLE: VQF's low-pass filter
 * states, their coefficients and its 3x3 inverse in float too, the accelerometer low-pass filter's
 * in float-float; LSW_VQF_DOUBLE: those in double, as VQF's authors built it). The host library
 * holds both, the firmware one (fastsw_config.h). The elementary functions VQF calls are
 * src/lsw_math.hpp's on every target: the same bits.
 *
 * The filter lives in caller-owned storage (LswVqf): VQF holds its parameters, coefficients and
 * state as plain members and allocates nothing, so it is constructed in place there.
 */
#ifndef LSW_VQF_H
#define LSW_VQF_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Bytes reserved for one VQF object (lsw_vqf.cpp checks sizeof(VQF) fits at compile time). */
#define LSW_VQF_STORAGE 856u

/** VQF's precisions (lsw_vqf_init). */
#define LSW_VQF_SINGLE 0u /**< filter states, coefficients and 3x3 inverse in float (acc low-pass: float-float) */
#define LSW_VQF_DOUBLE 1u /**< those in double (VQF's own), the rest float */

/** Caller-owned storage of one filter. Private. */
typedef struct {
    uint32_t precision; /* LSW_VQF_SINGLE or LSW_VQF_DOUBLE: the filter in u */
    union {
        double align; /* VQF's members include doubles */
        unsigned char bytes[LSW_VQF_STORAGE];
    } u;
} LswVqf;

/**
 * Construct a filter in *v with VQF's default parameters (rest detection, rest and motion bias
 * estimation and magnetic disturbance rejection on) for samples every period_s seconds (> 0), in
 * the given precision (LSW_VQF_SINGLE or LSW_VQF_DOUBLE) if this build holds it, else in the one
 * it holds. Returns the precision constructed.
 */
uint32_t lsw_vqf_init(LswVqf *v, float period_s, uint32_t precision);

/** Back to the state after lsw_vqf_init (identity orientation, zero bias), parameters kept. */
void lsw_vqf_reset(LswVqf *v);

/**
 * VQF's rest detection thresholds (VQFParams.restThGyr, deg/s, and restThAcc, m/s^2; VQF's
 * defaults 2 and 0.5): rest is detected where the low-passed readings stay within them of their
 * mean for restMinT (1.5 s).
 */
void lsw_vqf_set_rest_thresholds(LswVqf *v, float gyr_dps, float acc);

/**
 * Turn the filter's earth frame about its vertical (z): VQF's gyroscope quaternion set to
 * (heading[0], 0, 0, heading[1]), a unit turn (cos h/2, sin h/2) computed by the caller (no
 * trigonometry here: the host and the firmware then start from the same bits). Call before the
 * first sample (a device's start heading).
 */
void lsw_vqf_set_heading(LswVqf *v, const float heading[2]);

/** One gyroscope sample, rad/s, sensor frame: strapdown integration, gyro rest detection. */
void lsw_vqf_gyr(LswVqf *v, const float gyr[3]);

/** One accelerometer sample, m/s^2: inclination correction, bias estimation, rest detection. */
void lsw_vqf_acc(LswVqf *v, const float acc[3]);

/** One magnetometer sample (any unit, e.g. uT): heading correction (9D). */
void lsw_vqf_mag(LswVqf *v, const float mag[3]);

/** The orientation, w x y z, sensor frame in VQF's earth frame (z up): 6D, or 9D when nine_d. */
void lsw_vqf_quat(const LswVqf *v, int nine_d, float q[4]);

/** The current gyroscope bias estimate, rad/s, sensor frame. */
void lsw_vqf_bias(const LswVqf *v, float bias[3]);

/** 1 while VQF detects rest (the sensor still for restMinT, 1.5 s), else 0. */
int lsw_vqf_rest(const LswVqf *v);

/** sizeof the VQF object in *v (at most LSW_VQF_STORAGE). */
size_t lsw_vqf_size(const LswVqf *v);

/**
 * For tests: out[k] = f(x[k]) (atan2: f(y[k], x[k])) for n arguments, with lsw_math.hpp's function
 * fn (0 sin, 1 cos, 2 tan, 3 exp, 4 asin, 5 acos, 6 atan2) in double (in_double) or float (the
 * arguments rounded to float first). Returns n.
 */
size_t lsw_math_eval(int fn, size_t n, const double *x, const double *y, double *out, int in_double);

#ifdef __cplusplus
}
#endif

#endif /* LSW_VQF_H */
