/*
 * lsw_wire.c - segment-point message encoders (see lsw_wire.h).
 */
#include "lsw_wire.h"

#include <string.h>

/** Store the low `bytes` bytes of v at out, least significant first. */
static void put_le(uint8_t *out, uint64_t v, uint32_t bytes)
{
    uint32_t i;
    for (i = 0u; i < bytes; i++) {
        out[i] = (uint8_t)(v >> (8u * i));
    }
}

/** Store n floats at out as their float32 bit patterns. */
static void put_floats(uint8_t *out, const float *v, uint32_t n)
{
    uint32_t d;
    for (d = 0u; d < n; d++) {
        uint32_t bits;
        memcpy(&bits, &v[d], sizeof bits);
        put_le(out + 4u * d, bits, 4u);
    }
}

/** The fields both versions share, after the version byte. */
static void put_point(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                      const FastswPoint *point, int64_t t_us)
{
    out[1] = flags;
    put_le(out + 2, stream, 2u);
    put_le(out + 4, seq, 4u);
    put_le(out + 8, point->index, 4u);
    put_le(out + 12, (uint64_t)t_us, 8u);
    put_floats(out + 20, point->y, 4u);
}

uint32_t lsw_encode_point(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                          const FastswPoint *point, int64_t t_us)
{
    out[0] = (uint8_t)LSW_VERSION;
    put_point(out, flags, stream, seq, point, t_us);
    return LSW_POINT_SIZE;
}

uint32_t lsw_encode_point_rate(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                               const FastswPoint *point, const float *omega, int64_t t_us)
{
    out[0] = (uint8_t)LSW_VERSION_RATE;
    put_point(out, flags, stream, seq, point, t_us);
    put_floats(out + 36, omega, 3u);
    return LSW_POINT_RATE_SIZE;
}

void lsw_body_rate(const float *y, const float *v, float ticks_per_second, float *omega)
{
    /* vec(conj(y) v) for y = (w, x, y, z): w v_vec - v_w y_vec - y_vec x v_vec */
    const float k = 2.0f * ticks_per_second;
    omega[0] = (y[0] * v[1] - v[0] * y[1] - (y[2] * v[3] - y[3] * v[2])) * k;
    omega[1] = (y[0] * v[2] - v[0] * y[2] - (y[3] * v[1] - y[1] * v[3])) * k;
    omega[2] = (y[0] * v[3] - v[0] * y[3] - (y[1] * v[2] - y[2] * v[1])) * k;
}
