/*
 * icount_main.c - Cortex-M4 harness for exact instruction counts per call
 * (firmware_c/tools/icount.py traces it under QEMU, one instruction at a time).
 *
 * Calls, in this order, each announced by one line before the call:
 *     K k         icount_probe(k): a known 3 + 3k instructions (checks the counting)
 *     F LABEL     fastsw_update, LABEL the branch it takes:
 *                 first, normal, ssr_break, max_len_break, reject_nan, reject_time;
 *                 with the live rule on the same prefixed "live_", and live_close
 *                 (the live rule makes the sample a segment point);
 *                 or "-" for a look-ahead call on a copy of the state (not counted)
 *     S n         sw_update with n samples buffered since the anchor (n = 0..200),
 *                 or "-" for the stream's first sample (not counted)
 * and "end" when done. Inputs are the synthetic default vectors (vectors.py).
 */
#include <stdint.h>

#include "default_vectors.h"
#include "fastsw.h"
#include "semihost.h"
#include "sw.h"

#define MAX_SAMPLES 512u
#define SW_MAX_N 200u

static uint32_t case_t[MAX_SAMPLES];
static float case_y[MAX_SAMPLES * 4u];
static SwState sw_state;

/** Known cost: for k >= 1 iterations, exactly 3 + 3k instructions, bx lr included. */
__attribute__((naked, noinline)) uint32_t icount_probe(__attribute__((unused)) uint32_t k)
{
    __asm__ volatile(
        "movs r1, #0\n"
        "1:\n\t"
        "adds r1, r1, #1\n\t"
        "cmp r1, r0\n\t"
        "bne 1b\n\t"
        "mov r0, r1\n\t"
        "bx lr\n");
}

/** Little-endian u32 at p. */
static uint32_t read_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

/** Load case number `wanted` of the default vectors; returns its sample count (0 if absent). */
static uint32_t load_case(uint32_t wanted, float *threshold)
{
    const uint8_t *blob = default_vectors;
    const uint32_t n_cases = read_u32(blob + 4);
    uint32_t k, off = 8u;
    for (k = 0u; k < n_cases; k++) {
        const uint32_t m = read_u32(blob + off + 12u);
        if (k == wanted) {
            uint32_t i, n = (m < MAX_SAMPLES) ? m : MAX_SAMPLES;
            union {
                uint32_t u;
                float f;
            } v;
            v.u = read_u32(blob + off);
            *threshold = v.f;
            for (i = 0u; i < n; i++) {
                case_t[i] = read_u32(blob + off + 16u + 4u * i);
            }
            for (i = 0u; i < 4u * n; i++) {
                v.u = read_u32(blob + off + 16u + 4u * m + 4u * i);
                case_y[i] = v.f;
            }
            return n;
        }
        off += 16u + 20u * m;
    }
    return 0u;
}

/** True if one of the 4 components is NaN or infinite. */
static int non_finite(const float *y)
{
    uint32_t d;
    for (d = 0u; d < 4u; d++) {
        if (!(y[d] - y[d] == 0.0f)) {
            return 1;
        }
    }
    return 0;
}

/** Print "F [live_]LABEL" naming the branch the next fastsw_update call takes. */
static void announce_fastsw(int live, const char *label)
{
    semihost_write0(live ? "F live_" : "F ");
    semihost_write0(label);
    semihost_write0("\n");
}

/**
 * Stream case k through fastsw_update (threshold overridden if threshold_or_negative
 * >= 0; live rule at live_bound_deg, 0 for off), announcing each call's branch.
 * Returns 0, or 1 if a status contradicts it.
 */
static int trace_fastsw(uint32_t k, float threshold_or_negative, uint32_t max_len, float live_bound_deg)
{
    FastswSettings settings = fastsw_default_settings;
    FastswState state;
    FastswPoint point;
    const int live = live_bound_deg > 0.0f;
    uint32_t i, m, since_anchor = 0u, last_t = 0u, started = 0u;
    float threshold = 0.0f;

    m = load_case(k, &threshold);
    settings.threshold = (threshold_or_negative >= 0.0f) ? threshold_or_negative : threshold;
    settings.max_len = max_len;
    settings.live_bound_deg = live_bound_deg;
    if (m == 0u || fastsw_init(&state, &settings) != FASTSW_NONE) {
        return 1;
    }
    for (i = 0u; i < m; i++) {
        const float *y = &case_y[4u * i];
        const char *label;
        FastswStatus expected, status;
        if (non_finite(y)) {
            label = "reject_nan";
            expected = FASTSW_REJECTED;
        } else if (started && (int32_t)(case_t[i] - last_t) <= 0) {
            label = "reject_time";
            expected = FASTSW_REJECTED;
        } else if (!started) {
            label = "first";
            expected = FASTSW_POINT;
        } else if (!live && since_anchor >= settings.max_len) {
            label = "max_len_break";
            expected = FASTSW_POINT;
        } else {
            /* the SSR (and live) rule decides: ask a copy of the state which way it goes */
            const int full = since_anchor >= settings.max_len;
            FastswState probe = state;
            FastswPoint scratch;
            semihost_write0("F -\n"); /* this call is not counted */
            expected = fastsw_update(&probe, case_t[i], y, &scratch);
            if (expected == FASTSW_NONE) {
                label = "normal";
            } else if (live && scratch.index == i) {
                label = "close";
            } else {
                label = full ? "max_len_break" : "ssr_break";
            }
        }
        announce_fastsw(live, label);
        status = fastsw_update(&state, case_t[i], y, &point);
        if (status != expected) {
            semihost_write0("error: unexpected status\n");
            return 1;
        }
        if (status != FASTSW_REJECTED) {
            if (!started || (status == FASTSW_POINT && point.index == i)) {
                since_anchor = 0u; /* this sample is the anchor */
            } else {
                since_anchor = (status == FASTSW_POINT) ? 1u : since_anchor + 1u;
            }
            started = 1u;
            last_t = case_t[i];
        }
    }
    return 0;
}

/** Announce "S n" and call sw_update with n = 0..SW_MAX_N buffered samples; 0 on success. */
static int trace_sw(void)
{
    FastswSettings settings = fastsw_default_settings;
    FastswPoint point;
    float threshold;
    uint32_t i, m = load_case(0u, &threshold);
    char text[16];

    settings.threshold = 1e30f; /* never breaks on the SSR */
    if (m < SW_MAX_N + 2u || sw_init(&sw_state, &settings) != FASTSW_NONE) {
        return 1;
    }
    semihost_write0("S -\n"); /* the anchor: not counted */
    (void)sw_update(&sw_state, case_t[0], &case_y[0], &point);
    for (i = 1u; i <= SW_MAX_N + 1u; i++) {
        uint32_t n = i - 1u, pos = 0u;
        char digits[4];
        int nd = 0;
        do {
            digits[nd++] = (char)('0' + n % 10u);
            n /= 10u;
        } while (n != 0u);
        text[pos++] = 'S';
        text[pos++] = ' ';
        while (nd > 0) {
            text[pos++] = digits[--nd];
        }
        text[pos++] = '\n';
        text[pos] = '\0';
        semihost_write0(text);
        if (sw_update(&sw_state, case_t[i], &case_y[4u * i], &point) != FASTSW_NONE) {
            return 1;
        }
    }
    return 0;
}

int main(void)
{
    static const uint32_t probe_k[3] = {1u, 5u, 17u};
    uint32_t i;
    for (i = 0u; i < 3u; i++) {
        char text[8] = {'K', ' ', (char)('0' + probe_k[i] / 10u), (char)('0' + probe_k[i] % 10u), '\n', 0};
        semihost_write0(text);
        (void)icount_probe(probe_k[i]);
    }
    /* default vectors (vectors.py): case 1 threshold 1e-3, case 5 NaN/Inf/time faults,
     * then the same with the live rule at 2, 170 and 3 degrees */
    if (trace_fastsw(1u, -1.0f, 1000u, 0.0f) != 0 || trace_fastsw(0u, 1e30f, 7u, 0.0f) != 0 ||
        trace_fastsw(5u, -1.0f, 1000u, 0.0f) != 0 || trace_fastsw(1u, -1.0f, 1000u, 2.0f) != 0 ||
        trace_fastsw(0u, 1e30f, 7u, 170.0f) != 0 || trace_fastsw(5u, -1.0f, 1000u, 3.0f) != 0 ||
        trace_sw() != 0) {
        return 1;
    }
    semihost_write0("end\n");
    return 0;
}
