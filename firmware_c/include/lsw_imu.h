/*
 * lsw_imu.h - a device's raw-sample pipeline: raw IMU samples at the sensor rate -> VQF ->
 * orientation at the device's own instants (the device rate) -> fastSW with the live rule ->
 * segment points. The same code on the host (emulated devices, lsw_imu_bank_update over many)
 * and on the Cortex-M4 firmware (one device).
 *
 * Device instants: every out_period ticks from the stream's first sample. The first raw sample
 * at or after an instant is the device's sample for it: its orientation, stamped with that raw
 * sample's own tick, goes to fastSW (what a device does that reads its filter when its output
 * timer has fired: no interpolation, no extra latency; the stamps jitter by up to one raw period
 * around the instants and say exactly when the orientation held). A raw rate that is a multiple
 * of the device rate gives every k-th sample.
 *
 * Bad input, per device (counted in faults[], docs/kernel.md has the table):
 *
 * | raw sample                                   | handling                                   |
 * |----------------------------------------------|--------------------------------------------|
 * | NaN, +-Inf or |v| > LSW_IMU_RANGE in gyr or  | skipped (LSW_IMU_INVALID)                  |
 * |   acc (or mag in 9D)                         |                                            |
 * | time not after the previous accepted sample  | skipped (LSW_IMU_TIME_BACK)                |
 * | time step > max_gap                          | the filter is reset, the sample starts     |
 * |                                              |   anew (LSW_IMU_GAP)                       |
 * | an acc component at or beyond acc_limit      | gyro (and mag) fused, acc not (LSW_IMU_    |
 * |   (saturated), or acc all zeros              |   SATURATED)                               |
 * | gyro exactly (0, 0, 0) (stuck)               | acc (and mag) fused, gyro not (LSW_IMU_    |
 * |                                              |   GYR_STUCK)                               |
 *
 * So only finite samples reach VQF, and no NaN reaches fastSW or a point.
 *
 * Frames: lsw_imu_fuse gives VQF's orientation (the sensor frame in VQF's earth frame, z up);
 * lsw_imu_bank_update, a device, sends it in limbstream's world (y up: turned by -90 degrees about
 * x, LSW_IMU_Y_UP), the frame every device's segment points are in (docs/protocol.md).
 */
#ifndef LSW_IMU_H
#define LSW_IMU_H

#include <stddef.h>
#include <stdint.h>

#include "fastsw.h"
#include "lsw_bank.h"
#include "lsw_vqf.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Largest magnitude of a raw value taken as a reading (beyond it: invalid, like NaN). */
#define LSW_IMU_RANGE 1e6f

/** One raw sample of the IMU. */
typedef struct {
    uint32_t t;    /**< its time, kernel ticks (the bindings: microseconds) */
    float gyr[3];  /**< angular rate, rad/s, sensor frame */
    float acc[3];  /**< specific force, m/s^2, sensor frame */
    float mag[3];  /**< magnetic field, uT (9D only; ignored in 6D) */
} LswRawSample;

/** Tuning of one device's pipeline (its fastSW settings are its FastswState's). */
typedef struct {
    float raw_period_s;   /**< the sensor's sample period, s (VQF's Ts) */
    uint32_t out_period;  /**< ticks between the device's instants (20000 us: 50 Hz) */
    uint32_t max_gap;     /**< a time step longer than this (ticks) resets the filter */
    float acc_limit;      /**< an acc component at or beyond this, m/s^2, is saturated */
    uint32_t nine_d;      /**< 1: 9D (magnetometer heading correction), 0: 6D */
    float rest_th_gyr;    /**< VQF's rest threshold on the angular rate, deg/s (VQF's default: 2) */
    float rest_th_acc;    /**< VQF's rest threshold on the specific force, m/s^2 (VQF's default: 0.5) */
    float heading[2];     /**< the filter's start heading about the earth's vertical (and after a reset):
                               cos and sin of half its angle, (1, 0) for none */
    uint32_t vqf_precision; /**< LSW_VQF_SINGLE or LSW_VQF_DOUBLE (a build holding only the other
                                 runs that one; lsw_vqf.h) */
} LswImuSettings;

/**
 * 200 Hz raw, 50 Hz out (us ticks), max_gap 0.1 s, acc_limit 156 m/s^2 (a +-16 g part), 6D; rest
 * thresholds 0.5 deg/s and 0.5 m/s^2 (a body tracker's: VQF's 2 deg/s takes quiet standing sway
 * for rest and learns the sway as gyro bias; docs/kernel.md, "Filter settings"), heading 0, VQF in
 * the build's default precision (LSW_VQF_DEFAULT_DOUBLE, fastsw_config.h).
 */
extern const LswImuSettings lsw_imu_default_settings;

/** Bad raw samples, by kind (LswImu.faults). */
typedef enum {
    LSW_IMU_INVALID = 0,   /**< non-finite or out-of-range value: skipped */
    LSW_IMU_TIME_BACK = 1, /**< time not after the previous sample: skipped */
    LSW_IMU_GAP = 2,       /**< time step > max_gap: filter reset */
    LSW_IMU_SATURATED = 3, /**< acc saturated or all zeros: acc not fused */
    LSW_IMU_GYR_STUCK = 4, /**< gyro all zeros: gyro not fused */
    LSW_IMU_FAULTS = 5
} LswImuFault;

/** lsw_imu_fuse's result, and lsw_imu_bank_update's status beyond FastswStatus's. */
#define LSW_IMU_SAMPLE 0u    /**< lsw_imu_fuse: the device's sample for an instant */
#define LSW_IMU_NO_OUTPUT 3u /**< sample fused, not a device instant: nothing for fastSW */
#define LSW_IMU_SKIPPED 4u   /**< sample skipped (invalid or time not increasing) */

/** Caller-owned state of one device's fusion. Fields are private except faults and outputs. */
typedef struct {
    LswVqf vqf;
    LswImuSettings settings;
    uint32_t started;      /**< 0 until the first accepted sample (and after a gap) */
    uint32_t last_t;       /**< tick of the last accepted sample */
    uint32_t next_instant; /**< tick of the next device instant */
    uint32_t outputs;      /**< device-rate samples made since init (fastSW's sample count) */
    uint32_t faults[LSW_IMU_FAULTS];
} LswImu;

/** A new device: filter, instants and counters from scratch. */
void lsw_imu_init(LswImu *imu, const LswImuSettings *settings);

/**
 * Fuse one raw sample. Returns LSW_IMU_SAMPLE when it is the device's sample for an instant (*tick
 * and q (w x y z, sensor frame in the earth frame, z up) hold it), LSW_IMU_NO_OUTPUT when not,
 * LSW_IMU_SKIPPED when the sample was bad and skipped.
 */
uint32_t lsw_imu_fuse(LswImu *imu, const LswRawSample *raw, uint32_t *tick, float q[4]);

/** The current orientation (6D or 9D as set), w x y z. */
void lsw_imu_quat(const LswImu *imu, float q[4]);

/** The current gyroscope bias estimate, rad/s. */
void lsw_imu_bias(const LswImu *imu, float bias[3]);

/** 1 while the filter detects rest, else 0. */
int lsw_imu_rest(const LswImu *imu);

/** q (w x y z) in VQF's earth frame (z up) turned into limbstream's world (y up), in place:
 * -90 degrees about x on the left (limbstream.quat.Z_UP_TO_Y_UP). */
void lsw_imu_y_up(float q[4]);

/**
 * Many devices, one raw sample each (raw[k], its stamp t_us[k] in us since the epoch): each is
 * fused (lsw_imu_fuse); a device's sample for an instant, turned y up (lsw_imu_y_up), goes to its
 * fastSW state (states[k]),
 * and status[k] is FASTSW_NONE / POINT / REJECTED as fastsw_update's, else LSW_IMU_NO_OUTPUT or
 * LSW_IMU_SKIPPED. points[k] and rates[k*4..] as fastsw_update_many's. With wire (may be NULL),
 * the device-rate sample's number (imus[k].outputs - 1 + wire->base[k]) and stamp go into
 * the wire ring's row for its fastSW call, and every point is encoded as lsw_bank_update does
 * (out, slots, ends; returns the number of messages); without, returns the number of points.
 */
size_t lsw_imu_bank_update(LswImu *imus, FastswState *states, size_t count, const LswRawSample *raw,
                           const int64_t *t_us, uint8_t *status, FastswPoint *points, float *rates,
                           const LswBankWire *wire, uint8_t *out, uint32_t *slots, uint32_t *ends);

/**
 * Offline: fuse n raw samples in order through one device (lsw_imu_fuse, instants ignored) and
 * write the orientation after each into q (n x 4 floats, w x y z; a skipped sample repeats the
 * orientation before it, identity before the first). Returns the number of samples skipped.
 */
size_t lsw_imu_fuse_batch(LswImu *imu, const LswRawSample *raw, size_t n, float *q);

/**
 * What a bank's devices report: bias (count x 3, rad/s), rest (count: 1 at rest), faults
 * (count x LSW_IMU_FAULTS counts, LswImuFault order) and outputs (count: device-rate samples
 * made). Any output may be NULL.
 */
void lsw_imu_bank_status(const LswImu *imus, size_t count, float *bias, uint8_t *rest, uint32_t *faults,
                         uint32_t *outputs);

/** sizeof(LswImu), for bindings that allocate states. */
size_t lsw_imu_state_size(void);

#ifdef __cplusplus
}
#endif

#endif /* LSW_IMU_H */
