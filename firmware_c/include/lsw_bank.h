/*
 * lsw_bank.h - many emulated devices in one call: each advances its fastSW state by one sample
 * and every segment point emitted comes back as its wire message (lsw_wire.h), ready to send.
 *
 * The device emulator's inner loop (all its devices in one call), and the device firmware's
 * (firmware_c/m4/device.c: one stream per call), so both send the same bytes.
 */
#ifndef LSW_BANK_H
#define LSW_BANK_H

#include <stddef.h>
#include <stdint.h>

#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

/**
 * The wire fields of a bank's count streams besides their kernel points. A point's sample index
 * on the wire is the sample number the stream took at the point's update call minus the
 * stream's base; its time is that sample's device time. Both come from a ring of the last
 * `ring` calls: call c (the kernel's point index) is row c % ring, one entry per stream.
 */
typedef struct {
    const uint16_t *stream; /**< count: stream id */
    uint32_t *seq;          /**< count: sequence number of the stream's next message; +1 per point */
    const int64_t *base;    /**< count: sample number of the stream's sample 0 */
    int64_t *sample;        /**< ring x count: sample number taken at the call of that row */
    int64_t *t_us;          /**< ring x count: its device time, microseconds since the epoch */
    const uint8_t *rate;    /**< count: 1: version 2 (with body rate), 0: version 1 */
    uint32_t ring;          /**< rows of the ring, >= 1 */
    uint32_t stride;        /**< entries per ring row (the bank's stream capacity) */
} LswBankWire;

/**
 * fastsw_update_many over streams 0..count-1 (status, points and rates as there; rates:
 * count x dim floats), then each point emitted encoded, flags 0, in stream order into out
 * (at most count * LSW_POINT_RATE_SIZE bytes): version 2 with its body rate (the float64 form
 * of lsw_body_rate, rounded to float32) where wire->rate is set, else version 1. slots[i] is
 * the stream of message i, ends[i] the offset in out just after it. Returns the number of
 * messages.
 */
size_t lsw_bank_update(FastswState *states, size_t count, const uint32_t *t, const float *y,
                       uint8_t *status, FastswPoint *points, float *rates, const LswBankWire *wire,
                       uint8_t *out, uint32_t *slots, uint32_t *ends);

/**
 * The encoding half of lsw_bank_update: every stream k with status[k] == FASTSW_POINT has its
 * point (points[k], rate rates[k*dim..]) encoded into out as there. Returns the number of
 * messages. (lsw_imu_bank_update shares it.)
 */
size_t lsw_bank_encode(const FastswState *states, size_t count, const uint8_t *status,
                       const FastswPoint *points, const float *rates, const LswBankWire *wire,
                       uint8_t *out, uint32_t *slots, uint32_t *ends);

#ifdef __cplusplus
}
#endif

#endif /* LSW_BANK_H */
