/*
 * lsw_vqf.h - VQF, the orientation filter, behind a plain C API (src/lsw_vqf.cpp).
 *
 * D. Laidig, T. Seel, "VQF: Highly Accurate IMU Orientation Estimation with Bias Estimation and
 * Magnetic Disturbance Rejection", Information Fusion 91, 2023. Its C++ (class VQF, MIT licence)
 * comes from the `vqf` Python package's own sources, compiled unchanged with
 * -DVQF_SINGLE_PRECISION (floats in and out; VQF keeps its low-pass filter states in double)
 * and -ffp-contract=off on the host and on the Cortex-M4 alike.
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

/** Caller-owned storage of one filter. Private. */
typedef struct {
    union {
        double align; /* VQF's members include doubles */
        unsigned char bytes[LSW_VQF_STORAGE];
    } u;
} LswVqf;

/**
 * Construct a filter in *v with VQF's default parameters (rest detection, rest and motion bias
 * estimation and magnetic disturbance rejection on) for samples every period_s seconds (> 0).
 */
void lsw_vqf_init(LswVqf *v, float period_s);

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

/** sizeof(VQF) in this build (at most LSW_VQF_STORAGE). */
size_t lsw_vqf_size(void);

#ifdef __cplusplus
}
#endif

#endif /* LSW_VQF_H */
