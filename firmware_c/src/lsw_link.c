/*
 * lsw_link.c - serial link frames (see lsw_link.h).
 */
#include "lsw_link.h"

#include <string.h>

uint16_t lsw_crc16(const uint8_t *data, size_t n)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    for (i = 0u; i < n; i++) {
        int bit;
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (bit = 0; bit < 8; bit++) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

/** COBS of n bytes (n < 254: one block) into out; returns its length n + 1. */
static size_t cobs_encode(uint8_t *out, const uint8_t *in, size_t n)
{
    size_t code_at = 0u, o = 1u, i;
    uint8_t code = 1u;
    for (i = 0u; i < n; i++) {
        if (in[i] == 0u) {
            out[code_at] = code;
            code_at = o++;
            code = 1u;
        } else {
            out[o++] = in[i];
            code++;
        }
    }
    out[code_at] = code;
    return o;
}

/** Decode COBS (no delimiter inside) of n bytes into out; returns the length, or -1 if invalid. */
static long cobs_decode(uint8_t *out, const uint8_t *in, size_t n)
{
    size_t i = 0u, o = 0u;
    while (i < n) {
        uint8_t code = in[i++];
        size_t k;
        if (code == 0u || i + code - 1u > n) {
            return -1;
        }
        for (k = 1u; k < code; k++) {
            out[o++] = in[i++];
        }
        if (code != 0xFFu && i < n) {
            out[o++] = 0u;
        }
    }
    return (long)o;
}

size_t lsw_link_frame(uint8_t *out, uint8_t type, const uint8_t *body, size_t body_len)
{
    uint8_t payload[LSW_LINK_MAX_PAYLOAD + 2u];
    uint16_t crc;
    size_t n;
    payload[0] = (uint8_t)LSW_LINK_VERSION;
    payload[1] = type;
    if (body_len > 0u) {
        memcpy(payload + 2, body, body_len);
    }
    crc = lsw_crc16(payload, body_len + 2u);
    lsw_put_u16(payload + 2 + body_len, crc);
    n = cobs_encode(out, payload, body_len + 4u);
    out[n] = 0u;
    return n + 1u;
}

void lsw_link_reader_init(LswLinkReader *reader)
{
    memset(reader, 0, sizeof *reader);
}

/** A delimiter: check the bytes since the last one as a frame. */
static int end_frame(LswLinkReader *r)
{
    long n;
    uint16_t crc;
    if (r->n == 0u && !r->overflow) {
        return 0; /* back-to-back delimiters (a sender's resync) are not frames */
    }
    if (r->overflow) {
        r->bad[LSW_BAD_LENGTH]++;
        return 0;
    }
    n = cobs_decode(r->payload, r->raw, r->n);
    if (n < 0) {
        r->bad[LSW_BAD_COBS]++;
        return 0;
    }
    if (n < 4) {
        r->bad[LSW_BAD_LENGTH]++;
        return 0;
    }
    crc = lsw_get_u16(r->payload + n - 2);
    if (lsw_crc16(r->payload, (size_t)n - 2u) != crc) {
        r->bad[LSW_BAD_CRC]++;
        return 0;
    }
    if (r->payload[0] != (uint8_t)LSW_LINK_VERSION) {
        r->bad[LSW_BAD_VERSION]++;
        return 0;
    }
    r->payload_len = (size_t)n - 2u;
    r->frames++;
    return 1;
}

int lsw_link_feed(LswLinkReader *reader, uint8_t byte)
{
    int done;
    if (byte != 0u) {
        if (reader->n < LSW_LINK_MAX_FRAME - 1u) { /* a frame without its delimiter */
            reader->raw[reader->n++] = byte;
        } else {
            reader->overflow = 1u;
        }
        return 0;
    }
    done = end_frame(reader);
    reader->n = 0u;
    reader->overflow = 0u;
    return done;
}

void lsw_link_bad(LswLinkReader *reader, LswBadReason reason)
{
    reader->bad[reason]++;
    reader->frames--;
}

void lsw_put_u16(uint8_t *out, uint16_t v)
{
    out[0] = (uint8_t)v;
    out[1] = (uint8_t)(v >> 8);
}

void lsw_put_u32(uint8_t *out, uint32_t v)
{
    lsw_put_u16(out, (uint16_t)v);
    lsw_put_u16(out + 2, (uint16_t)(v >> 16));
}

void lsw_put_u64(uint8_t *out, uint64_t v)
{
    lsw_put_u32(out, (uint32_t)v);
    lsw_put_u32(out + 4, (uint32_t)(v >> 32));
}

void lsw_put_f64(uint8_t *out, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    lsw_put_u64(out, bits);
}

uint16_t lsw_get_u16(const uint8_t *in)
{
    return (uint16_t)(in[0] | (in[1] << 8));
}

uint32_t lsw_get_u32(const uint8_t *in)
{
    return (uint32_t)lsw_get_u16(in) | ((uint32_t)lsw_get_u16(in + 2) << 16);
}

uint64_t lsw_get_u64(const uint8_t *in)
{
    return (uint64_t)lsw_get_u32(in) | ((uint64_t)lsw_get_u32(in + 4) << 32);
}

float lsw_get_f32(const uint8_t *in)
{
    uint32_t bits = lsw_get_u32(in);
    float v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

double lsw_get_f64(const uint8_t *in)
{
    uint64_t bits = lsw_get_u64(in);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}
