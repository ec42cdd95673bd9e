/*
 * icount_device_main.c - Cortex-M4 harness for the device firmware's exact cost per sample
 * (firmware_c/tools/icount.py --device traces it under QEMU, one instruction at a time).
 *
 * The device (device.c) is set to live mode (threshold 9e-4, max_len 25, live bound 5 degrees)
 * over its link, then fed one of the default vectors' quaternion streams as SAMPLE frames. Each
 * frame goes through icount_device_frame, whose count is the device's whole work for that
 * sample: link decode (COBS, CRC), fastSW with the live rule, the point's wire encoding and its
 * framing. The transport's own write (here a sink called through a pointer, on a board the
 * UART or USB driver) is not traced. Before each counted call the harness prints "D -", after
 * it "E point" or "E none" (whether the sample made the device send a point); "end" when done.
 */
#include <stdint.h>

#include "default_vectors.h"
#include "device.h"
#include "lsw_link.h"
#include "semihost.h"

#define VECTOR_CASE 8u /* a 300-sample live-rule stream of the default vectors */
#define PERIOD_US 20000u

static uint32_t sent; /* bytes the device has written */
static Device device;

/** Where the device's frames go: counted, not sent. */
static void sink(const uint8_t *data, size_t n)
{
    (void)data;
    sent += (uint32_t)n;
}

/** The device's work for one frame: each of its bytes, as the UART loop hands them over. */
__attribute__((noinline)) void icount_device_frame(const uint8_t *frame, uint32_t n)
{
    uint32_t i;
    for (i = 0u; i < n; i++) {
        device_byte(&device, frame[i]);
    }
}

/** Hand over a frame uncounted (setup). */
static void give(const uint8_t *frame, uint32_t n)
{
    uint32_t i;
    for (i = 0u; i < n; i++) {
        device_byte(&device, frame[i]);
    }
}

int main(void)
{
    const uint8_t *blob = default_vectors;
    uint8_t body[28], frame[LSW_LINK_MAX_FRAME];
    uint32_t off = 8u, k, i, m;
    device_init(&device, sink);
    lsw_put_u16(body, 1u);
    lsw_put_f64(body + 2, 9e-4);
    lsw_put_f64(body + 10, 25.0);
    lsw_put_f64(body + 18, 5.0);
    give(frame, (uint32_t)lsw_link_frame(frame, LSW_MSG_CONFIG, body, 26u));
    lsw_put_u16(body, 2u);
    lsw_put_u16(body + 2, 1u);
    give(frame, (uint32_t)lsw_link_frame(frame, LSW_MSG_START, body, 4u));
    for (k = 0u; k < VECTOR_CASE; k++) { /* skip to the case: header 16 B, ticks, y */
        off += 16u + 20u * lsw_get_u32(blob + off + 12u);
    }
    m = lsw_get_u32(blob + off + 12u);
    for (i = 0u; i < m; i++) {
        const uint8_t *y = blob + off + 16u + 4u * m + 16u * i;
        uint32_t before = sent, n;
        lsw_put_u32(body, i * PERIOD_US);
        lsw_put_u64(body + 4, (uint64_t)1790000000000000ull + (uint64_t)i * PERIOD_US);
        for (k = 0u; k < 16u; k++) {
            body[12u + k] = y[k];
        }
        n = (uint32_t)lsw_link_frame(frame, LSW_MSG_SAMPLE, body, 28u);
        semihost_write0("D -\n");
        icount_device_frame(frame, n);
        semihost_write0(sent != before ? "E point\n" : "E none\n");
    }
    semihost_write0("end\n");
    return 0;
}
