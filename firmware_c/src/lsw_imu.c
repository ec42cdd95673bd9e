/*
 * lsw_imu.c - raw samples -> VQF -> the device's instants -> fastSW (see lsw_imu.h).
 */
#include "lsw_imu.h"

const LswImuSettings lsw_imu_default_settings = {
    0.005f,  /* raw_period_s: 200 Hz */
    20000u,  /* out_period: 50 Hz in us */
    100000u, /* max_gap: 0.1 s in us */
    156.0f,  /* acc_limit: just under 16 g */
    0u,      /* 6D */
    0.5f,    /* rest_th_gyr: deg/s, a body tracker's (VQF's default 2) */
    0.5f,    /* rest_th_acc: m/s^2, VQF's default */
    {1.0f, 0.0f}, /* heading: none */
    LSW_VQF_DEFAULT_DOUBLE ? LSW_VQF_DOUBLE : LSW_VQF_SINGLE, /* vqf_precision */
};

/** The filter from scratch with the settings' rest thresholds and start heading. */
static void start_filter(LswImu *imu, int reset)
{
    if (reset) {
        lsw_vqf_reset(&imu->vqf);
    } else {
        imu->settings.vqf_precision = lsw_vqf_init(&imu->vqf, imu->settings.raw_period_s, imu->settings.vqf_precision);
        lsw_vqf_set_rest_thresholds(&imu->vqf, imu->settings.rest_th_gyr, imu->settings.rest_th_acc);
    }
    if (imu->settings.heading[1] != 0.0f) {
        lsw_vqf_set_heading(&imu->vqf, imu->settings.heading);
    }
}

void lsw_imu_init(LswImu *imu, const LswImuSettings *settings)
{
    uint32_t k;
    imu->settings = *settings;
    start_filter(imu, 0);
    imu->started = 0u;
    imu->last_t = 0u;
    imu->next_instant = 0u;
    imu->outputs = 0u;
    for (k = 0u; k < (uint32_t)LSW_IMU_FAULTS; k++) {
        imu->faults[k] = 0u;
    }
}

/** Whether all n values are finite and within LSW_IMU_RANGE (false for NaN). */
static int readable(const float *v, uint32_t n)
{
    uint32_t k;
    for (k = 0u; k < n; k++) {
        if (!(v[k] >= -LSW_IMU_RANGE && v[k] <= LSW_IMU_RANGE)) {
            return 0;
        }
    }
    return 1;
}

/** Whether acc measures gravity at all: no component at or beyond limit, not all zeros. */
static int acc_usable(const float *acc, float limit)
{
    uint32_t k;
    for (k = 0u; k < 3u; k++) {
        if (acc[k] >= limit || acc[k] <= -limit) {
            return 0;
        }
    }
    return acc[0] != 0.0f || acc[1] != 0.0f || acc[2] != 0.0f;
}

/**
 * Check the sample's time against the last accepted one: 1 to take it, 0 to skip it (not after
 * it). A step beyond max_gap resets the filter first (the stream goes on from this sample).
 */
static int take_time(LswImu *imu, uint32_t t)
{
    const uint32_t step = t - imu->last_t; /* modulo 2^32: the tick counter may wrap */
    if (!imu->started) {
        return 1;
    }
    if (step == 0u || step > 0x80000000u) {
        imu->faults[LSW_IMU_TIME_BACK]++;
        return 0;
    }
    if (step > imu->settings.max_gap) {
        imu->faults[LSW_IMU_GAP]++;
        start_filter(imu, 1);
        imu->started = 0u;
    }
    return 1;
}

/** Whether tick t makes this sample the device's sample for an instant (and moves the instant on). */
static int at_instant(LswImu *imu, uint32_t t)
{
    const uint32_t period = imu->settings.out_period;
    if (!imu->started) {
        imu->started = 1u;
        imu->next_instant = t + period;
        return 1;
    }
    if ((int32_t)(t - imu->next_instant) < 0) {
        return 0;
    }
    imu->next_instant += period;
    if ((int32_t)(t - imu->next_instant) >= 0) { /* more than a period late: on from this sample */
        imu->next_instant = t + period;
    }
    return 1;
}

uint32_t lsw_imu_fuse(LswImu *imu, const LswRawSample *raw, uint32_t *tick, float q[4])
{
    const int nine_d = imu->settings.nine_d != 0u;
    if (!readable(raw->gyr, 3u) || !readable(raw->acc, 3u) || (nine_d && !readable(raw->mag, 3u))) {
        imu->faults[LSW_IMU_INVALID]++;
        return LSW_IMU_SKIPPED;
    }
    if (!take_time(imu, raw->t)) {
        return LSW_IMU_SKIPPED;
    }
    imu->last_t = raw->t;
    if (raw->gyr[0] != 0.0f || raw->gyr[1] != 0.0f || raw->gyr[2] != 0.0f) {
        lsw_vqf_gyr(&imu->vqf, raw->gyr);
    } else {
        imu->faults[LSW_IMU_GYR_STUCK]++;
    }
    if (acc_usable(raw->acc, imu->settings.acc_limit)) {
        lsw_vqf_acc(&imu->vqf, raw->acc);
    } else {
        imu->faults[LSW_IMU_SATURATED]++;
    }
    if (nine_d) {
        lsw_vqf_mag(&imu->vqf, raw->mag);
    }
    if (!at_instant(imu, raw->t)) {
        return LSW_IMU_NO_OUTPUT;
    }
    lsw_vqf_quat(&imu->vqf, nine_d, q);
    *tick = raw->t;
    imu->outputs++;
    return LSW_IMU_SAMPLE;
}

void lsw_imu_quat(const LswImu *imu, float q[4])
{
    lsw_vqf_quat(&imu->vqf, imu->settings.nine_d != 0u, q);
}

void lsw_imu_bias(const LswImu *imu, float bias[3])
{
    lsw_vqf_bias(&imu->vqf, bias);
}

int lsw_imu_rest(const LswImu *imu)
{
    return lsw_vqf_rest(&imu->vqf);
}

void lsw_imu_y_up(float q[4])
{
    const float c = 0.70710677f; /* sqrt(1/2) as a float */
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    q[0] = c * (w + x);
    q[1] = c * (x - w);
    q[2] = c * (y + z);
    q[3] = c * (z - y);
}

size_t lsw_imu_bank_update(LswImu *imus, FastswState *states, size_t count, const LswRawSample *raw,
                           const int64_t *t_us, uint8_t *status, FastswPoint *points, float *rates,
                           const LswBankWire *wire, uint8_t *out, uint32_t *slots, uint32_t *ends)
{
    size_t k, n = 0u;
    for (k = 0u; k < count; k++) {
        uint32_t tick;
        float q[4];
        uint32_t fused = lsw_imu_fuse(&imus[k], &raw[k], &tick, q);
        if (fused == LSW_IMU_SAMPLE) {
            if (wire != NULL) {
                const uint32_t call = states[k].next_index; /* the fastSW call this sample is */
                const size_t row = (size_t)(call % wire->ring) * wire->stride + k;
                wire->sample[row] = wire->base[k] + (int64_t)call;
                wire->t_us[row] = t_us[k];
            }
            lsw_imu_y_up(q);
            fused = (uint32_t)fastsw_update(&states[k], tick, q, &points[k]);
            if (fused == (uint32_t)FASTSW_POINT) {
                fastsw_point_rate(&states[k], rates + 4u * k);
                n++;
            }
        }
        status[k] = (uint8_t)fused;
    }
    if (wire == NULL) {
        return n;
    }
    return lsw_bank_encode(states, count, status, points, rates, wire, out, slots, ends);
}

size_t lsw_imu_fuse_batch(LswImu *imu, const LswRawSample *raw, size_t n, float *q)
{
    size_t i, skipped = 0u;
    float held[4] = {1.0f, 0.0f, 0.0f, 0.0f};
    for (i = 0u; i < n; i++) {
        uint32_t tick;
        float *out = q + 4u * i;
        uint32_t k;
        if (lsw_imu_fuse(imu, &raw[i], &tick, out) == LSW_IMU_SKIPPED) {
            skipped++;
        } else {
            lsw_imu_quat(imu, held);
        }
        for (k = 0u; k < 4u; k++) {
            out[k] = held[k];
        }
    }
    return skipped;
}

void lsw_imu_bank_status(const LswImu *imus, size_t count, float *bias, uint8_t *rest, uint32_t *faults,
                         uint32_t *outputs)
{
    size_t k;
    uint32_t f;
    for (k = 0u; k < count; k++) {
        if (bias != NULL) {
            lsw_imu_bias(&imus[k], bias + 3u * k);
        }
        if (rest != NULL) {
            rest[k] = (uint8_t)lsw_imu_rest(&imus[k]);
        }
        for (f = 0u; faults != NULL && f < (uint32_t)LSW_IMU_FAULTS; f++) {
            faults[(size_t)LSW_IMU_FAULTS * k + f] = imus[k].faults[f];
        }
        if (outputs != NULL) {
            outputs[k] = imus[k].outputs;
        }
    }
}

size_t lsw_imu_state_size(void)
{
    return sizeof(LswImu);
}
