/*
 * lsw_clock.h - stamping samples on the common time base, for many emulated devices in one call:
 * each device's correction (service time minus device time) follows its sync estimate's line
 * with a bounded slew (docs/protocol.md, "Time exchange"; limbstream/device/sync.py).
 *
 * Host only (the device emulator's inner loop; not part of the Cortex-M4 build).
 */
#ifndef LSW_CLOCK_H
#define LSW_CLOCK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/** Per-device sync state, arrays indexed by device slot. Times in microseconds (float64). */
typedef struct {
    const double *a, *b, *ref; /**< the estimate's line: correction a + b * (L - ref) at device time L */
    double *c;                 /**< correction of the device's last stamp */
    double *c_local;           /**< device time of that stamp; NaN before the first */
    uint8_t *step;             /**< 1: the next stamp sets c to the line (no slew); cleared by it */
    const uint8_t *ever;       /**< 0: never synced, stamps are the device's own clock */
    uint8_t *stepped;          /**< set by each stamp: it was a step (not the device's first stamp) */
    double slew;               /**< largest rate of change of c beyond the drift b (fraction) */
} LswSync;

/**
 * Stamps out[i] = local[i] + C for the samples taken at device times local[i] by devices
 * slots[i] (each device once per call, its times increasing over calls), updating each device's
 * correction C: C advances by b over the elapsed time and moves towards the line by at most
 * slew times it; a device's first stamp or a pending step sets C to the line (a step: stepped
 * is set, unless it was the first stamp). Returns the number of steps.
 */
size_t lsw_stamp(const LswSync *sync, size_t n, const int64_t *slots, const double *local, double *out);

#ifdef __cplusplus
}
#endif

#endif /* LSW_CLOCK_H */
