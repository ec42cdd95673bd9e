/*
 * device.h - a limbstream device on a serial link: samples in, segment points out
 * (docs/protocol.md, "Serial link").
 *
 * It runs fastSW with the live rule on its samples through the same C code as the host's
 * emulated devices (lsw_bank_update for one stream: the same kernel, wire fields and encoder),
 * so its points are the host's bit for bit. Raw IMU samples (RAW) go through VQF first, then
 * the same fastSW stream: lsw_imu_bank_update for one device, the host's raw-sample pipeline. Its settings are the contract's tunables
 * (lsw_tunables.h, generated from limbstream/wire/config.py), checked with the same bounds.
 *
 * Transport-free: it reads bytes given to device_byte and writes frames through the function
 * given to device_init (a UART, USB CDC, or a measuring harness).
 */
#ifndef DEVICE_H
#define DEVICE_H

#include <stddef.h>
#include <stdint.h>

#include "fastsw.h"
#include "lsw_imu.h"
#include "lsw_link.h"
#include "lsw_tunables.h"
#include "lsw_wire.h"

#define DEVICE_RING 4u /**< samples remembered: a point is the current sample or the one before */

/** Where the device's frames go. */
typedef void (*DeviceWrite)(const uint8_t *data, size_t n);

/** Caller-owned state of one device (one per link). Fields are private. */
typedef struct {
    DeviceWrite write;
    LswLinkReader reader;
    FastswState state;
    FastswSettings settings;
    double config[LSW_TUNABLES];          /**< the tunables as set (status reports them) */
    uint16_t stream_id;
    uint32_t seq;                         /**< sequence number of the next point */
    int64_t base;                         /**< sample number of the stream's sample 0: always 0 */
    uint8_t live;                         /**< the live rule is on: points carry their rate (v2) */
    int64_t ring_sample[DEVICE_RING];     /**< sample number of each of the last samples */
    int64_t ring_t_us[DEVICE_RING];       /**< and its stamp, us since the epoch */
    uint32_t samples, points, rejected;   /**< this stream's counts */
    uint32_t refused;                     /**< configs refused since power-up */
    uint8_t last_point[LSW_POINT_RATE_SIZE];
    uint32_t last_len;                    /**< 0: no point in this stream yet */
    LswImu imu;                           /**< the raw-sample fusion (VQF), fresh with each stream */
    LswImuSettings imu_settings;          /**< as the last FUSION set them */
    uint32_t raw;                         /**< raw samples received in this stream */
} Device;

/** Power up: default settings, stream 0, counters zero; announces its identity through write. */
void device_init(Device *device, DeviceWrite write);

/** One received byte (a frame's last byte is handled at once: a sample, a request). */
void device_byte(Device *device, uint8_t byte);

/** Send the status message unasked (the heartbeat). */
void device_heartbeat(Device *device);

#endif /* DEVICE_H */
