/*
 * lsw_bank.c - one tick of many emulated devices, points out as wire messages (see lsw_bank.h).
 */
#include "lsw_bank.h"

#include "lsw_wire.h"

#define TICKS_PER_SECOND 1e6 /* the bindings' kernel ticks are microseconds */

/**
 * omega = 2 vec(conj(y) v) * TICKS_PER_SECOND in float64, operation for operation as
 * limbstream.quat.body_rate computes it from float32 y and v, then rounded to float32: the host
 * emulator's rates are those of the Python path bit for bit.
 */
static void body_rate_f64(const float *y, const float *v, float *omega)
{
    const double aw = (double)y[0], ax = -(double)y[1], ay = -(double)y[2], az = -(double)y[3];
    const double bw = (double)v[0] * TICKS_PER_SECOND, bx = (double)v[1] * TICKS_PER_SECOND;
    const double by = (double)v[2] * TICKS_PER_SECOND, bz = (double)v[3] * TICKS_PER_SECOND;
    omega[0] = (float)(2.0 * (aw * bx + ax * bw + ay * bz - az * by));
    omega[1] = (float)(2.0 * (aw * by - ax * bz + ay * bw + az * bx));
    omega[2] = (float)(2.0 * (aw * bz + ax * by - ay * bx + az * bw));
}

/** lsw_bank_encode's work, inlined into lsw_bank_update (the device's per-sample path). */
static inline size_t encode(const FastswState *states, size_t count, const uint8_t *status,
                            const FastswPoint *points, const float *rates, const LswBankWire *wire,
                            uint8_t *out, uint32_t *slots, uint32_t *ends)
{
    size_t k, n = 0u;
    uint32_t end = 0u;

    (void)states; /* read for the dimension only where it is not fixed at compile time */
    for (k = 0u; k < count; k++) {
        const FastswPoint *point = &points[k];
        size_t at;
        uint32_t seq;
        FastswPoint sent;
        if (status[k] != (uint8_t)FASTSW_POINT) {
            continue;
        }
        at = (size_t)(point->index % wire->ring) * wire->stride + k;
        sent = *point;
        sent.index = (uint32_t)(wire->sample[at] - wire->base[k]);
        seq = wire->seq[k];
        if (wire->rate[k]) {
            float omega[3];
            body_rate_f64(point->y, rates + k * FASTSW_DIM(&states[k].settings), omega);
            end += lsw_encode_point_rate(out + end, 0u, wire->stream[k], seq, &sent, omega, wire->t_us[at]);
        } else {
            end += lsw_encode_point(out + end, 0u, wire->stream[k], seq, &sent, wire->t_us[at]);
        }
        wire->seq[k] = seq + 1u;
        slots[n] = (uint32_t)k;
        ends[n] = end;
        n++;
    }
    return n;
}

size_t lsw_bank_update(FastswState *states, size_t count, const uint32_t *t, const float *y,
                       uint8_t *status, FastswPoint *points, float *rates, const LswBankWire *wire,
                       uint8_t *out, uint32_t *slots, uint32_t *ends)
{
    fastsw_update_many(states, count, t, y, status, points, rates);
    return encode(states, count, status, points, rates, wire, out, slots, ends);
}

size_t lsw_bank_encode(const FastswState *states, size_t count, const uint8_t *status,
                       const FastswPoint *points, const float *rates, const LswBankWire *wire,
                       uint8_t *out, uint32_t *slots, uint32_t *ends)
{
    return encode(states, count, status, points, rates, wire, out, slots, ends);
}
