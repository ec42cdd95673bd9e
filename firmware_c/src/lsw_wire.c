/*
 * lsw_wire.c - segment-point message encoder (see lsw_wire.h).
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

uint32_t lsw_encode_point(uint8_t *out, uint8_t flags, uint16_t stream, uint32_t seq,
                          const FastswPoint *point, int64_t t_us)
{
    uint32_t d;
    out[0] = (uint8_t)LSW_VERSION;
    out[1] = flags;
    put_le(out + 2, stream, 2u);
    put_le(out + 4, seq, 4u);
    put_le(out + 8, point->index, 4u);
    put_le(out + 12, (uint64_t)t_us, 8u);
    for (d = 0u; d < 4u; d++) {
        uint32_t bits;
        memcpy(&bits, &point->y[d], sizeof bits); /* float32 bit pattern */
        put_le(out + 20u + 4u * d, bits, 4u);
    }
    return LSW_POINT_SIZE;
}
