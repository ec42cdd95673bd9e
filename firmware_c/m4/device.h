/*
 * device.h - a limbstream device on a serial link: samples in, segment points out
 * (docs/protocol.md, "Serial link").
 *
 * It runs fastSW with the live rule on its samples through the same C code as the host's
 * emulated devices (lsw_bank_update for one stream: the same kernel, wire fields and encoder),
 * so its points are the host's bit for bit. Its settings are the contract's tunables
 * (lsw_tunables.h, generated from limbstream/wire/config.py), checked with the same bounds.
 *
 * Transport-free: it reads bytes given to device_byte and writes frames through the function
 * given to device_init (a UART, USB CDC, or a measuring harness).
 */
#ifndef DEVICE_H
#define DEVICE_H

#include <stddef.h>
#include <stdint.h>

/** Where the device's frames go. */
typedef void (*DeviceWrite)(const uint8_t *data, size_t n);

/** Power up: default settings, stream 0, counters zero; announces its identity. */
void device_init(DeviceWrite write);

/** One received byte (a frame's last byte is handled at once: a sample, a request). */
void device_byte(uint8_t byte);

/** Send the status message unasked (the heartbeat). */
void device_heartbeat(void);

#endif /* DEVICE_H */
