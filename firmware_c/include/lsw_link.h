/*
 * lsw_link.h - the serial link between a limbstream device and its gateway (docs/protocol.md,
 * "Serial link"): frames, their checksum and the byte-at-a-time frame reader.
 *
 * A frame on the line is COBS(payload || crc16) followed by one 0x00 delimiter; the payload is
 * link version (LSW_LINK_VERSION), message type, body. crc16 is CRC-16/CCITT-FALSE (poly 0x1021,
 * init 0xFFFF, no reflection) of the payload, little-endian. A reader that meets a bad frame
 * counts it by reason and resynchronises at the next delimiter: it never stalls.
 *
 * Portable C99, no allocation: the device firmware (firmware_c/m4/device_main.c) and the host
 * library (which the tests use to check limbstream/wire/serial_link.py against it) share it.
 */
#ifndef LSW_LINK_H
#define LSW_LINK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_LINK_VERSION 1u
#define LSW_LINK_MAX_PAYLOAD 96u /**< largest payload (version, type, body) either side sends */
/** Largest encoded frame, delimiter included: COBS adds one byte per 254 (one here). */
#define LSW_LINK_MAX_FRAME (LSW_LINK_MAX_PAYLOAD + 2u + 2u + 1u)

/* host -> device */
#define LSW_MSG_SAMPLE 0x01u   /**< u32 tick, i64 t_us, f32 q[4] */
#define LSW_MSG_CONFIG 0x02u   /**< u16 request, f64 threshold, f64 max_len, f64 live_bound_deg */
#define LSW_MSG_START 0x03u    /**< u16 request, u16 stream id: a new stream */
#define LSW_MSG_END 0x04u      /**< u16 request: end the stream (its last point, FINAL) */
#define LSW_MSG_STATUS_REQ 0x05u   /**< u16 request */
#define LSW_MSG_IDENTIFY 0x06u /**< u16 request */
#define LSW_MSG_RAW 0x07u      /**< u32 tick, i64 t_us, f32 gyr[3], acc[3], mag[3]: a raw IMU sample */
#define LSW_MSG_FUSION 0x08u   /**< u16 request, f64 raw rate Hz, f64 device rate Hz, u8 9D */
#define LSW_MSG_FUSION_REQ 0x09u /**< u16 request */
/* device -> host */
#define LSW_MSG_POINT 0x81u    /**< a segment point message, 36 or 48 bytes (lsw_wire.h) */
#define LSW_MSG_ACK 0x82u      /**< u16 request, u8 its type, u8 result, u8 tunable, f64 value */
#define LSW_MSG_STATUS 0x83u   /**< u16 request (0: heartbeat), counters and config */
#define LSW_MSG_IDENTITY 0x84u /**< u16 request, u8 link version, u8 point version, text */
#define LSW_MSG_FUSION_STATUS 0x85u /**< u16 request, u8 mode, u8 rest, f32 bias[3], u32 counts */

/** Why a frame was dropped (LswLinkReader.bad[reason]). */
typedef enum {
    LSW_BAD_COBS = 0,    /**< not valid COBS (a zero code inside, a block past the end, empty) */
    LSW_BAD_LENGTH = 1,  /**< too long for the reader, too short for a payload and CRC, or a body
                              of the wrong length for its type */
    LSW_BAD_CRC = 2,     /**< checksum differs */
    LSW_BAD_VERSION = 3, /**< another link version */
    LSW_BAD_TYPE = 4,    /**< unknown message type */
    LSW_BAD_REASONS = 5
} LswBadReason;

/** CRC-16/CCITT-FALSE of n bytes. */
uint16_t lsw_crc16(const uint8_t *data, size_t n);

/**
 * Encode one frame: COBS of (version, type, body, crc16) and the 0x00 delimiter into out
 * (capacity LSW_LINK_MAX_FRAME). body_len <= LSW_LINK_MAX_PAYLOAD - 2. Returns the frame's length.
 */
size_t lsw_link_frame(uint8_t *out, uint8_t type, const uint8_t *body, size_t body_len);

/** Frame reader: feed it bytes one at a time. Fields are private except bad. */
typedef struct {
    uint8_t raw[LSW_LINK_MAX_FRAME]; /**< the encoded bytes since the last delimiter */
    size_t n;                        /**< how many */
    uint8_t overflow;                /**< this frame is too long: dropped at its delimiter */
    uint8_t payload[LSW_LINK_MAX_FRAME]; /**< the last frame read: version, type, body */
    size_t payload_len;
    uint32_t frames;                 /**< good frames read */
    uint32_t bad[LSW_BAD_REASONS];   /**< frames dropped, by LswBadReason */
} LswLinkReader;

/** An empty reader with zero counters. */
void lsw_link_reader_init(LswLinkReader *reader);

/**
 * Take one byte. Returns 1 when it completes a good frame: reader->payload holds its version
 * (LSW_LINK_VERSION), type and body (payload_len bytes); its type's body length is the caller's
 * to check (lsw_link_bad to count a wrong one). Else 0 (a bad frame is counted and dropped).
 * Version and checksum are checked here; the type is not (lsw_link_bad with LSW_BAD_TYPE).
 */
int lsw_link_feed(LswLinkReader *reader, uint8_t byte);

/** Count the last frame read as bad for a reason the reader cannot see (type, body length). */
void lsw_link_bad(LswLinkReader *reader, LswBadReason reason);

/** Little-endian field access for message bodies. */
void lsw_put_u16(uint8_t *out, uint16_t v);
void lsw_put_u32(uint8_t *out, uint32_t v);
void lsw_put_u64(uint8_t *out, uint64_t v);
void lsw_put_f64(uint8_t *out, double v);
uint16_t lsw_get_u16(const uint8_t *in);
uint32_t lsw_get_u32(const uint8_t *in);
uint64_t lsw_get_u64(const uint8_t *in);
float lsw_get_f32(const uint8_t *in);
double lsw_get_f64(const uint8_t *in);

#ifdef __cplusplus
}
#endif

#endif /* LSW_LINK_H */
