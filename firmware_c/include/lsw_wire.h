/*
 * lsw_wire.h - the segment-point message of the limbstream wire contract (docs/protocol.md).
 *
 * Little-endian, written byte by byte so any target's endianness and struct padding are
 * irrelevant. limbstream/wire/point.py decodes the same layouts; a test checks both agree
 * byte for byte.
 *
 * | offset | size | field                                                  |
 * |-------:|-----:|--------------------------------------------------------|
 * |      0 |    1 | version: LSW_VERSION (36 bytes) or LSW_VERSION_RATE (48) |
 * |      1 |    1 | flags (LSW_FLAG_FINAL: last point of stream)           |
 * |      2 |    2 | stream id (drawn at device start)                      |
 * |      4 |    4 | sequence number of segment-point messages              |
 * |      8 |    4 | sample index in the device's stream                    |
 * |     12 |    8 | device time, microseconds since the epoch              |
 * |     20 |   16 | quaternion w, x, y, z (IEEE-754 float32)               |
 * |     36 |   12 | version 2: body angular rate x, y, z, rad/s (float32)  |
 */
#ifndef LSW_WIRE_H
#define LSW_WIRE_H

#include <stdint.h>

#include "fastsw.h"

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_VERSION 1u
#define LSW_VERSION_RATE 2u
#define LSW_POINT_SIZE 36u
#define LSW_POINT_RATE_SIZE 48u
#define LSW_FLAG_FINAL 0x01u

/**
 * Write one segment point message, version 1, into out (LSW_POINT_SIZE bytes).
 * point->y holds the quaternion (w, x, y, z); t_us is the device time of the point.
 * Returns LSW_POINT_SIZE.
 */
uint32_t lsw_encode_point(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                          const FastswPoint *point, int64_t t_us);

/**
 * Write one segment point message with its rate, version 2, into out (LSW_POINT_RATE_SIZE
 * bytes): as lsw_encode_point, then omega (3 floats, rad/s, lsw_body_rate).
 * Returns LSW_POINT_RATE_SIZE.
 */
uint32_t lsw_encode_point_rate(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                               const FastswPoint *point, const float *omega, int64_t t_us);

/**
 * The body angular rate the wire carries for a point y (4 floats) whose kernel rate is v
 * (fastsw_point_rate, per tick): omega = 2 vec(conj(y) v) ticks_per_second, rad/s.
 */
void lsw_body_rate(const float *y, const float *v, float ticks_per_second, float *omega);

#ifdef __cplusplus
}
#endif

#endif /* LSW_WIRE_H */
