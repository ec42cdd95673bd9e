/*
 * icount_imu_main.c - Cortex-M4 harness for the raw-sample pipeline's exact cost
 * (firmware_c/tools/icount.py --imu traces it under QEMU, one instruction at a time).
 *
 * A synthetic sensor at 200 Hz: 3.2 s still (gyro bias and noise: VQF detects rest after 1.5 s),
 * then 0.8 s of motion (angular rates up to 3 rad/s per axis, changing every 0.1 s; acc = gravity
 * in the sensor frame plus noise). The first 3 s (VQF's start-up: its low-pass filters average
 * their input for tauAcc = 3 s before they filter) run uncounted; then each raw sample goes through
 * icount_imu, the device's pipeline (lsw_imu_bank_update for one device: the checks, VQF 6D, the
 * device's instants at 50 Hz and fastSW with the live rule), announced "P -" and after it
 * "E none" (no device sample), "E sample" or "E point". VQF alone is the count of its two updates
 * inside it (lsw_vqf_gyr, lsw_vqf_acc: updateGyr and updateAcc), which icount.py counts too.
 * "R rest" (or "R moving") says whether VQF detected the still phase.
 */
#include <stdint.h>

#include "lsw_imu.h"
#include "semihost.h"

#define RATE_HZ 200.0f
#define WARM_UP 600u /* samples run uncounted: VQF's start-up */
#define STILL 640u
#define MOVING 160u

static LswImu imu;
static FastswState state;
/** The pipeline for one raw sample (one device of lsw_imu_bank_update, no wire). */
static uint8_t pipeline(const LswRawSample *raw)
{
    const int64_t t_us = 0;
    uint8_t status;
    FastswPoint point;
    float rates[4];
    (void)lsw_imu_bank_update(&imu, &state, 1u, raw, &t_us, &status, &point, rates, 0, 0, 0, 0);
    return status;
}

__attribute__((noinline, noclone)) uint8_t icount_imu(const LswRawSample *raw)
{
    return pipeline(raw);
}

static uint32_t lcg = 12345u;

/** A uniform number in [-1, 1). */
static float noise(void)
{
    lcg = lcg * 1664525u + 1013904223u;
    return (float)(int32_t)lcg * (1.0f / 2147483648.0f);
}

/** v in the frame of q (conj(q) v q): a world vector as the sensor measures it. */
static void to_sensor(const float *q, const float *v, float *out)
{
    const float w = q[0], x = -q[1], y = -q[2], z = -q[3];
    out[0] = (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y - w * z) * v[1] + 2 * (x * z + w * y) * v[2];
    out[1] = 2 * (x * y + w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z - w * x) * v[2];
    out[2] = 2 * (x * z - w * y) * v[0] + 2 * (y * z + w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2];
}

int main(void)
{
    static const float gravity[3] = {0.0f, 0.0f, 9.81f};
    float q[4] = {1.0f, 0.0f, 0.0f, 0.0f}, rate[3] = {0.0f, 0.0f, 0.0f};
    LswImuSettings settings = lsw_imu_default_settings; /* 200 Hz raw, 50 Hz out, 6D */
    FastswSettings live = fastsw_default_settings;
    uint32_t i, k;
    live.threshold = 9e-4f;
    live.max_len = 25u;
    live.live_bound_deg = 5.0f;
    lsw_imu_init(&imu, &settings);
    (void)fastsw_init(&state, &live);
    for (i = 0u; i < STILL + MOVING; i++) {
        LswRawSample raw;
        float n, dq[4];
        uint8_t status;
        if (i >= STILL && (i - STILL) % 20u == 0u) {
            for (k = 0u; k < 3u; k++) {
                rate[k] = 3.0f * noise();
            }
        }
        raw.t = i * 5000u;
        to_sensor(q, gravity, raw.acc);
        raw.mag[0] = raw.mag[1] = raw.mag[2] = 0.0f;
        for (k = 0u; k < 3u; k++) {
            raw.gyr[k] = rate[k] + 0.003f + 0.002f * noise();
            raw.acc[k] += 0.05f * noise();
        }
        dq[0] = q[0] - 0.5f / RATE_HZ * (q[1] * rate[0] + q[2] * rate[1] + q[3] * rate[2]);
        dq[1] = q[1] + 0.5f / RATE_HZ * (q[0] * rate[0] + q[2] * rate[2] - q[3] * rate[1]);
        dq[2] = q[2] + 0.5f / RATE_HZ * (q[0] * rate[1] + q[3] * rate[0] - q[1] * rate[2]);
        dq[3] = q[3] + 0.5f / RATE_HZ * (q[0] * rate[2] + q[1] * rate[1] - q[2] * rate[0]);
        n = dq[0] * dq[0] + dq[1] * dq[1] + dq[2] * dq[2] + dq[3] * dq[3];
        n = 1.5f - 0.5f * n; /* one Newton step towards 1/|dq| (|dq| is near 1) */
        for (k = 0u; k < 4u; k++) {
            q[k] = dq[k] * n;
        }
        if (i < WARM_UP) {
            (void)pipeline(&raw);
            continue;
        }
        semihost_write0("P -\n");
        status = icount_imu(&raw);
        semihost_write0(status == LSW_IMU_NO_OUTPUT ? "E none\n" : status == FASTSW_POINT ? "E point\n" : "E sample\n");
        if (i == STILL - 1u) {
            semihost_write0(lsw_imu_rest(&imu) ? "R rest\n" : "R moving\n"); /* VQF found the still phase? */
        }
    }
    semihost_write0("end\n");
    return 0;
}
