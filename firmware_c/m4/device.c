/*
 * device.c - the device's link messages and its one fastSW stream (see device.h).
 */
#include "device.h"

#include <string.h>

#include "lsw_bank.h"

#define SAMPLE_BODY 28u
#define RAW_BODY 48u
#define FUSION_BODY 35u
#define CONFIG_BODY 26u
#define START_BODY 4u
#define REQUEST_BODY 2u
#define ACK_OK 0u
#define ACK_REFUSED 1u
#define NO_TUNABLE 0xFFu

static const char IDENTITY[] = "limbstream-fw 2 fastSW live, VQF; board mps2-an386 cortex-m4";

extern uint32_t _stack_top[];

/** Frame and send one message. */
static void send_message(Device *d, uint8_t type, const uint8_t *body, size_t n)
{
    uint8_t frame[LSW_LINK_MAX_FRAME];
    d->write(frame, lsw_link_frame(frame, type, body, n));
}

/** Apply config[] to the settings (and the running stream when retune). */
static void apply_config(Device *d, int retune)
{
    d->settings.threshold = (float)d->config[0];
    d->settings.max_len = (uint32_t)d->config[1];
    d->settings.live_bound_deg = (float)d->config[2];
    d->live = (uint8_t)(d->settings.live_bound_deg > 0.0f && d->settings.live_bound_deg < 180.0f);
    if (retune) {
        (void)fastsw_retune(&d->state, &d->settings);
    }
}

/** A new stream: fresh kernel state, sequence and counters. */
static void start_stream(Device *d, uint16_t id)
{
    (void)fastsw_init(&d->state, &d->settings);
    d->stream_id = id;
    d->seq = 0u;
    d->samples = d->points = d->rejected = 0u;
    d->last_len = 0u;
    lsw_imu_init(&d->imu, &d->imu_settings);
    d->raw = 0u;
}

/** ACK of a request: result ACK_OK, or ACK_REFUSED naming the tunable and the value refused. */
static void send_ack(Device *d, uint16_t request, uint8_t type, uint8_t result, uint8_t tunable, double value)
{
    uint8_t body[13];
    lsw_put_u16(body, request);
    body[2] = type;
    body[3] = result;
    body[4] = tunable;
    lsw_put_f64(body + 5, value);
    send_message(d, LSW_MSG_ACK, body, sizeof body);
}

/** Whether v is within tunable t's bounds (finite, and an integer where it must be one). */
static int tunable_ok(const LswTunable *t, double v)
{
    if (!(v >= t->low && v <= t->high)) { /* also false for NaN */
        return 0;
    }
    return !t->integer || v == (double)(int64_t)v;
}

/** Bytes of the watched stack written since power-up (painted at device_init): its high-water mark. */
static uint32_t stack_used(void);

/** STATUS: this stream's counters, the link's frame counts, the config, the stack's high-water mark. */
static void send_status(Device *d, uint16_t request)
{
    uint8_t body[2 + 2 + 4 * 6 + 4 * LSW_BAD_REASONS + 8 * LSW_TUNABLES + 4];
    uint8_t *p = body;
    uint32_t k;
    lsw_put_u16(p, request), p += 2;
    lsw_put_u16(p, d->stream_id), p += 2;
    lsw_put_u32(p, d->seq), p += 4;
    lsw_put_u32(p, d->samples), p += 4;
    lsw_put_u32(p, d->points), p += 4;
    lsw_put_u32(p, d->rejected), p += 4;
    lsw_put_u32(p, d->refused), p += 4;
    lsw_put_u32(p, d->reader.frames), p += 4;
    for (k = 0u; k < LSW_BAD_REASONS; k++) {
        lsw_put_u32(p, d->reader.bad[k]), p += 4;
    }
    for (k = 0u; k < LSW_TUNABLES; k++) {
        lsw_put_f64(p, d->config[k]), p += 8;
    }
    lsw_put_u32(p, stack_used());
    send_message(d, LSW_MSG_STATUS, body, sizeof body);
}

/** IDENTITY: link version, newest point version, sample dimension and the firmware's text. */
static void send_identity(Device *d, uint16_t request)
{
    uint8_t body[5 + sizeof IDENTITY - 1u];
    uint32_t k;
    lsw_put_u16(body, request);
    body[2] = (uint8_t)LSW_LINK_VERSION;
    body[3] = (uint8_t)LSW_VERSION_RATE;
    body[4] = (uint8_t)FASTSW_FIXED_DIM;
    for (k = 0u; k + 1u < sizeof IDENTITY; k++) {
        body[5 + k] = (uint8_t)IDENTITY[k];
    }
    send_message(d, LSW_MSG_IDENTITY, body, sizeof body);
}

/** A point the stream's fastSW made (out, n bytes): kept for END, sent. */
static inline __attribute__((always_inline)) void send_point(Device *d, const uint8_t *out, uint32_t n)
{
    uint32_t k;
    for (k = 0u; k < n; k++) {
        d->last_point[k] = out[k];
    }
    d->last_len = n;
    d->points++;
    send_message(d, LSW_MSG_POINT, out, n);
}

/** One sample: the kernel, and its point (if any) as its wire message. */
static void on_sample(Device *d, const uint8_t *body)
{
    const uint32_t row = d->samples % DEVICE_RING;
    const uint32_t tick = lsw_get_u32(body);
    float y[4], rates[4];
    uint8_t status, out[LSW_POINT_RATE_SIZE];
    uint32_t slot, end;
    FastswPoint point;
    const LswBankWire wire = {&d->stream_id, &d->seq, &d->base, d->ring_sample, d->ring_t_us, &d->live,
                              DEVICE_RING, 1u};
    uint32_t k;
    for (k = 0u; k < 4u; k++) {
        y[k] = lsw_get_f32(body + 12u + 4u * k);
    }
    d->ring_sample[row] = (int64_t)d->samples;
    d->ring_t_us[row] = (int64_t)lsw_get_u64(body + 4);
    if (lsw_bank_update(&d->state, 1u, &tick, y, &status, &point, rates, &wire, out, &slot, &end) != 0u) {
        send_point(d, out, end);
    }
    d->rejected += status == (uint8_t)FASTSW_REJECTED;
    d->samples++;
}

/**
 * One raw IMU sample: the host's raw-sample pipeline for one device (VQF; at the device's
 * instants fastSW, its wire ring row and its point's message).
 */
static void on_raw(Device *d, const uint8_t *body)
{
    LswRawSample raw;
    const int64_t t_us = (int64_t)lsw_get_u64(body + 4);
    float rates[4];
    uint8_t status, out[LSW_POINT_RATE_SIZE];
    uint32_t slot, end, k;
    FastswPoint point;
    const LswBankWire wire = {&d->stream_id, &d->seq, &d->base, d->ring_sample, d->ring_t_us, &d->live,
                              DEVICE_RING, 1u};
    raw.t = lsw_get_u32(body);
    for (k = 0u; k < 3u; k++) {
        raw.gyr[k] = lsw_get_f32(body + 12u + 4u * k);
        raw.acc[k] = lsw_get_f32(body + 24u + 4u * k);
        raw.mag[k] = lsw_get_f32(body + 36u + 4u * k);
    }
    d->raw++;
    if (lsw_imu_bank_update(&d->imu, &d->state, 1u, &raw, &t_us, &status, &point, rates, &wire, out, &slot,
                            &end) != 0u) {
        send_point(d, out, end);
    }
    if (status != LSW_IMU_NO_OUTPUT && status != LSW_IMU_SKIPPED) {
        d->rejected += status == (uint8_t)FASTSW_REJECTED;
        d->samples++; /* a device-rate sample: fastSW's */
    }
}

/** FUSION: the raw-sample pipeline's settings as the host computed them; a fresh filter. */
static void on_fusion(Device *d, uint16_t request, const uint8_t *body)
{
    LswImuSettings s;
    s.raw_period_s = lsw_get_f32(body);
    s.out_period = lsw_get_u32(body + 4);
    s.max_gap = lsw_get_u32(body + 8);
    s.acc_limit = lsw_get_f32(body + 12);
    s.nine_d = body[16];
    s.rest_th_gyr = lsw_get_f32(body + 17);
    s.rest_th_acc = lsw_get_f32(body + 21);
    s.heading[0] = lsw_get_f32(body + 25);
    s.heading[1] = lsw_get_f32(body + 29);
    s.vqf_precision = lsw_imu_default_settings.vqf_precision; /* the one this firmware is built with */
    if (!(s.raw_period_s > 0.0f && s.raw_period_s <= 1.0f) || s.out_period == 0u || s.max_gap == 0u ||
        !(s.acc_limit > 0.0f && s.acc_limit <= LSW_IMU_RANGE) || s.nine_d > 1u ||
        !(s.rest_th_gyr > 0.0f && s.rest_th_gyr <= 1000.0f) || !(s.rest_th_acc > 0.0f && s.rest_th_acc <= 1000.0f) ||
        !(s.heading[0] >= -1.0f && s.heading[0] <= 1.0f && s.heading[1] >= -1.0f && s.heading[1] <= 1.0f) ||
        !(s.heading[0] * s.heading[0] + s.heading[1] * s.heading[1] > 0.99f &&
          s.heading[0] * s.heading[0] + s.heading[1] * s.heading[1] < 1.01f)) {
        d->refused++;
        send_ack(d, request, LSW_MSG_FUSION, ACK_REFUSED, NO_TUNABLE, 0.0);
        return;
    }
    d->imu_settings = s;
    lsw_imu_init(&d->imu, &s);
    send_ack(d, request, LSW_MSG_FUSION, ACK_OK, NO_TUNABLE, 0.0);
}

/** FUSION_STATUS: the fusion's mode (6 or 9), rest, bias (rad/s), this stream's raw and
 * device-rate samples, and its bad raw samples by kind (LswImuFault order). */
static void send_fusion_status(Device *d, uint16_t request)
{
    uint8_t body[2 + 2 + 12 + 8 + 4 * LSW_IMU_FAULTS];
    uint8_t *p = body;
    float bias[3];
    uint32_t k;
    lsw_imu_bias(&d->imu, bias);
    lsw_put_u16(p, request), p += 2;
    *p++ = d->imu.settings.nine_d ? 9u : 6u;
    *p++ = (uint8_t)lsw_imu_rest(&d->imu);
    for (k = 0u; k < 3u; k++) {
        uint32_t bits;
        memcpy(&bits, &bias[k], sizeof bits);
        lsw_put_u32(p, bits), p += 4;
    }
    lsw_put_u32(p, d->raw), p += 4;
    lsw_put_u32(p, d->imu.outputs), p += 4;
    for (k = 0u; k < LSW_IMU_FAULTS; k++) {
        lsw_put_u32(p, d->imu.faults[k]), p += 4;
    }
    send_message(d, LSW_MSG_FUSION_STATUS, body, sizeof body);
}

/** End of stream: the last sample as a FINAL point, or the last point repeated as FINAL. */
static void on_end(Device *d)
{
    FastswPoint point;
    uint8_t out[LSW_POINT_RATE_SIZE];
    uint32_t n;
    if (fastsw_flush(&d->state, &point) == FASTSW_POINT) {
        const uint32_t row = point.index % DEVICE_RING;
        static const float held[3] = {0.0f, 0.0f, 0.0f}; /* a flushed point is held: rate 0 */
        point.index = (uint32_t)(d->ring_sample[row] - d->base);
        n = d->live ? lsw_encode_point_rate(out, LSW_FLAG_FINAL, d->stream_id, d->seq, &point, held, d->ring_t_us[row])
                    : lsw_encode_point(out, LSW_FLAG_FINAL, d->stream_id, d->seq, &point, d->ring_t_us[row]);
    } else if (d->last_len != 0u) {
        for (n = 0u; n < d->last_len; n++) {
            out[n] = d->last_point[n];
        }
        out[1] = (uint8_t)LSW_FLAG_FINAL;
        lsw_put_u32(out + 4, d->seq);
    } else {
        return; /* no sample in this stream */
    }
    d->seq++;
    d->points++;
    send_message(d, LSW_MSG_POINT, out, n);
}

/** CONFIG: all tunables within the contract's bounds are applied from the next sample, or none. */
static void on_config(Device *d, uint16_t request, const uint8_t *body)
{
    double values[LSW_TUNABLES];
    uint32_t k;
    for (k = 0u; k < LSW_TUNABLES; k++) {
        values[k] = lsw_get_f64(body + 8u * k);
        if (!tunable_ok(lsw_tunable(k), values[k])) {
            d->refused++;
            send_ack(d, request, LSW_MSG_CONFIG, ACK_REFUSED, (uint8_t)k, values[k]);
            return;
        }
    }
    for (k = 0u; k < LSW_TUNABLES; k++) {
        d->config[k] = values[k];
    }
    apply_config(d, 1);
    send_ack(d, request, LSW_MSG_CONFIG, ACK_OK, NO_TUNABLE, 0.0);
}

/** Expected body length of each host message type (0: not one). */
static uint32_t body_length(uint8_t type)
{
    switch (type) {
    case LSW_MSG_SAMPLE: return SAMPLE_BODY;
    case LSW_MSG_RAW: return RAW_BODY;
    case LSW_MSG_FUSION: return FUSION_BODY;
    case LSW_MSG_CONFIG: return CONFIG_BODY;
    case LSW_MSG_START: return START_BODY;
    case LSW_MSG_END:
    case LSW_MSG_STATUS_REQ:
    case LSW_MSG_FUSION_REQ:
    case LSW_MSG_IDENTIFY: return REQUEST_BODY;
    default: return 0u;
    }
}

/** A good frame from the reader: check its type and body length, then act on it. */
static void on_frame(Device *d)
{
    const uint8_t type = d->reader.payload[1];
    const uint8_t *body = d->reader.payload + 2;
    const uint32_t expected = body_length(type);
    uint16_t request;
    if (expected == 0u) {
        lsw_link_bad(&d->reader, LSW_BAD_TYPE);
        return;
    }
    if (d->reader.payload_len - 2u != expected) {
        lsw_link_bad(&d->reader, LSW_BAD_LENGTH);
        return;
    }
    if (type == LSW_MSG_SAMPLE) {
        on_sample(d, body);
        return;
    }
    if (type == LSW_MSG_RAW) {
        on_raw(d, body);
        return;
    }
    request = lsw_get_u16(body);
    switch (type) {
    case LSW_MSG_CONFIG:
        on_config(d, request, body + 2);
        break;
    case LSW_MSG_START:
        start_stream(d, lsw_get_u16(body + 2));
        send_ack(d, request, type, ACK_OK, NO_TUNABLE, 0.0);
        break;
    case LSW_MSG_END:
        on_end(d);
        send_ack(d, request, type, ACK_OK, NO_TUNABLE, 0.0);
        break;
    case LSW_MSG_STATUS_REQ:
        send_status(d, request);
        break;
    case LSW_MSG_FUSION:
        on_fusion(d, request, body + 2);
        break;
    case LSW_MSG_FUSION_REQ:
        send_fusion_status(d, request);
        break;
    default:
        send_identity(d, request);
        break;
    }
}

void device_byte(Device *device, uint8_t byte)
{
    if (lsw_link_feed(&device->reader, byte)) {
        on_frame(device);
    }
}

void device_heartbeat(Device *device)
{
    send_status(device, 0u);
}

#define STACK_PAINT 0x5AA5C33Cu
#define STACK_WATCHED 4096u /* words below the stack top that are painted and watched */

/** The lowest watched stack word (an address: the linker's symbol is the top). */
static volatile uint32_t *stack_bottom(void)
{
    return (volatile uint32_t *)((uintptr_t)_stack_top - 4u * STACK_WATCHED);
}

static uint32_t stack_used(void)
{
    const volatile uint32_t *p = stack_bottom();
    uint32_t n = 0u;
    while (n < STACK_WATCHED && p[n] == STACK_PAINT) {
        n++;
    }
    return 4u * (STACK_WATCHED - n);
}

/** Paint the watched stack below the current frame (the high-water mark is what gets overwritten). */
static void paint_stack(void)
{
    volatile uint32_t *p = stack_bottom();
    const volatile uint32_t *here = (uint32_t *)__builtin_frame_address(0) - 64; /* leave this frame alone */
    while (p < here) {
        *p++ = STACK_PAINT;
    }
}

void device_init(Device *device, DeviceWrite write)
{
    uint32_t k;
    paint_stack();
    device->write = write;
    lsw_link_reader_init(&device->reader);
    device->settings = fastsw_default_settings;
    device->settings.dim = 4u;
    for (k = 0u; k < LSW_TUNABLES; k++) {
        device->config[k] = lsw_tunable(k)->value;
    }
    device->base = 0;
    device->imu_settings = lsw_imu_default_settings;
    apply_config(device, 0);
    start_stream(device, 0u);
    device->refused = 0u;
    send_identity(device, 0u);
}
