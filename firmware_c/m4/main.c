/*
 * main.c - Cortex-M4 harness: runs test vectors through fastSW and SW and
 * prints every segment point over semihosting, for comparison with the host
 * build (tests/test_m4_qemu.py).
 *
 * Vectors (layout in firmware_c/tools/vectors.py): the ones compiled in
 * (default_vectors.h), or a host file named as the first semihosting argument
 * (-semihosting-config enable=on,target=native,arg=m4.elf,arg=FILE).
 *
 * Output, one line each:
 *     case K threshold=HEX max_len=N live=HEX m=M
 *     P ALG K INDEX TICK Y0 Y1 Y2 Y3 [R0 R1 R2 R3]
 *                 (ALG fastsw|sw, Y and fastSW's rate R as hex float32 bits)
 *     R ALG K REJECTED
 *     done N_CASES
 * Exit status 0, or 1 for unreadable vectors / bad settings.
 */
#include <stdint.h>

#include "default_vectors.h"
#include "fastsw.h"
#include "semihost.h"
#include "sw.h"

#define MAX_SAMPLES 4096u
#define FILE_CAPACITY (2u << 20)

static uint8_t file_buffer[FILE_CAPACITY] __attribute__((aligned(4)));
static uint32_t case_t[MAX_SAMPLES];
static float case_y[MAX_SAMPLES * 4u];
static SwState sw_state;
static char line[160];

/** Little-endian u32 at p. */
static uint32_t read_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

/** float32 from its bit pattern. */
static float from_bits(uint32_t bits)
{
    union {
        uint32_t u;
        float f;
    } v;
    v.u = bits;
    return v.f;
}

/** Bit pattern of a float32. */
static uint32_t to_bits(float value)
{
    union {
        uint32_t u;
        float f;
    } v;
    v.f = value;
    return v.u;
}

/** Append text at *pos of line. */
static void put_str(uint32_t *pos, const char *text)
{
    while (*text != '\0' && *pos < sizeof(line) - 2u) {
        line[(*pos)++] = *text++;
    }
}

/** Append value in decimal. */
static void put_dec(uint32_t *pos, uint32_t value)
{
    char digits[11];
    int n = 0;
    do {
        digits[n++] = (char)('0' + value % 10u);
        value /= 10u;
    } while (value != 0u);
    while (n > 0 && *pos < sizeof(line) - 2u) {
        line[(*pos)++] = digits[--n];
    }
}

/** Append value as 8 hex digits. */
static void put_hex(uint32_t *pos, uint32_t value)
{
    int shift;
    for (shift = 28; shift >= 0 && *pos < sizeof(line) - 2u; shift -= 4) {
        line[(*pos)++] = "0123456789abcdef"[(value >> shift) & 0xFu];
    }
}

/** Terminate the line with a newline and print it. */
static void end_line(uint32_t pos)
{
    line[pos++] = '\n';
    line[pos] = '\0';
    semihost_write0(line);
}

/** Print one segment point: P ALG K INDEX TICK Y0..Y3, and its rate R0..R3 unless rate is NULL. */
static void print_point(const char *alg, uint32_t k, const FastswPoint *p, const float *rate)
{
    uint32_t pos = 0u, d;
    put_str(&pos, "P ");
    put_str(&pos, alg);
    put_str(&pos, " ");
    put_dec(&pos, k);
    put_str(&pos, " ");
    put_dec(&pos, p->index);
    put_str(&pos, " ");
    put_dec(&pos, p->t);
    for (d = 0u; d < 4u; d++) {
        put_str(&pos, " ");
        put_hex(&pos, to_bits(p->y[d]));
    }
    for (d = 0u; rate != 0 && d < 4u; d++) {
        put_str(&pos, " ");
        put_hex(&pos, to_bits(rate[d]));
    }
    end_line(pos);
}

/** Print R ALG K REJECTED. */
static void print_rejected(const char *alg, uint32_t k, uint32_t rejected)
{
    uint32_t pos = 0u;
    put_str(&pos, "R ");
    put_str(&pos, alg);
    put_str(&pos, " ");
    put_dec(&pos, k);
    put_str(&pos, " ");
    put_dec(&pos, rejected);
    end_line(pos);
}

/** Stream case k (m samples in case_t, case_y) through fastSW; 0, or 1 for bad settings. */
static int run_fastsw(uint32_t k, const FastswSettings *settings, uint32_t m)
{
    FastswState state;
    FastswPoint point;
    float rate[4];
    uint32_t i, rejected = 0u;
    if (fastsw_init(&state, settings) != FASTSW_NONE) {
        return 1;
    }
    for (i = 0u; i < m; i++) {
        const FastswStatus status = fastsw_update(&state, case_t[i], &case_y[i * 4u], &point);
        if (status == FASTSW_POINT) {
            fastsw_point_rate(&state, rate);
            print_point("fastsw", k, &point, rate);
        } else if (status == FASTSW_REJECTED) {
            rejected++;
        }
    }
    if (fastsw_flush(&state, &point) == FASTSW_POINT) {
        fastsw_point_rate(&state, rate);
        print_point("fastsw", k, &point, rate);
    }
    print_rejected("fastsw", k, rejected);
    return 0;
}

/** As run_fastsw, through the Sliding Window baseline. */
static int run_sw(uint32_t k, const FastswSettings *settings, uint32_t m)
{
    FastswPoint point;
    uint32_t i, rejected = 0u;
    if (sw_init(&sw_state, settings) != FASTSW_NONE) {
        return 1;
    }
    for (i = 0u; i < m; i++) {
        const FastswStatus status = sw_update(&sw_state, case_t[i], &case_y[i * 4u], &point);
        if (status == FASTSW_POINT) {
            print_point("sw", k, &point, 0);
        } else if (status == FASTSW_REJECTED) {
            rejected++;
        }
    }
    if (sw_flush(&sw_state, &point) == FASTSW_POINT) {
        print_point("sw", k, &point, 0);
    }
    print_rejected("sw", k, rejected);
    return 0;
}

/** Run every case of a vector blob of size bytes; 0 on success. */
static int run_blob(const uint8_t *blob, uint32_t size)
{
    uint32_t n_cases, k, off = 8u;
    if (size < 8u || blob[0] != 'L' || blob[1] != 'S' || blob[2] != 'V' || blob[3] != '2') {
        semihost_write0("error: not a vector file (magic LSV2)\n");
        return 1;
    }
    n_cases = read_u32(blob + 4);
    for (k = 0u; k < n_cases; k++) {
        FastswSettings settings = fastsw_default_settings;
        uint32_t m, i, pos = 0u;
        if (size - off < 16u) {
            semihost_write0("error: truncated vector file\n");
            return 1;
        }
        settings.threshold = from_bits(read_u32(blob + off));
        settings.max_len = read_u32(blob + off + 4u);
        settings.live_bound_deg = from_bits(read_u32(blob + off + 8u));
        m = read_u32(blob + off + 12u);
        off += 16u;
        if (m > MAX_SAMPLES || (size - off) / 20u < m) {
            semihost_write0("error: case too long or truncated\n");
            return 1;
        }
        for (i = 0u; i < m; i++) {
            case_t[i] = read_u32(blob + off + 4u * i);
        }
        off += 4u * m;
        for (i = 0u; i < 4u * m; i++) {
            case_y[i] = from_bits(read_u32(blob + off + 4u * i));
        }
        off += 16u * m;
        put_str(&pos, "case ");
        put_dec(&pos, k);
        put_str(&pos, " threshold=");
        put_hex(&pos, to_bits(settings.threshold));
        put_str(&pos, " max_len=");
        put_dec(&pos, settings.max_len);
        put_str(&pos, " live=");
        put_hex(&pos, to_bits(settings.live_bound_deg));
        put_str(&pos, " m=");
        put_dec(&pos, m);
        end_line(pos);
        if (run_fastsw(k, &settings, m) != 0 || run_sw(k, &settings, m) != 0) {
            semihost_write0("error: bad settings\n");
            return 1;
        }
    }
    {
        uint32_t pos = 0u;
        put_str(&pos, "done ");
        put_dec(&pos, n_cases);
        end_line(pos);
    }
    return 0;
}

int main(void)
{
    static char cmdline[512];
    const char *path = 0;
    uint32_t i;

    /* argument 0 is the program; argument 1, if any, a vector file */
    if (semihost_cmdline(cmdline, sizeof(cmdline)) == 0) {
        for (i = 0u; cmdline[i] != '\0' && cmdline[i] != ' '; i++) {
        }
        while (cmdline[i] == ' ') {
            i++;
        }
        if (cmdline[i] != '\0') {
            path = &cmdline[i];
        }
    }
    if (path != 0) {
        const long size = semihost_read_file(path, file_buffer, sizeof(file_buffer));
        if (size < 0) {
            semihost_write0("error: cannot read vector file\n");
            return 1;
        }
        return run_blob(file_buffer, (uint32_t)size);
    }
    return run_blob(default_vectors, (uint32_t)sizeof(default_vectors));
}
