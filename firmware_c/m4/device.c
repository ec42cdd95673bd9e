/*
 * device.c - the device's link messages and its one fastSW stream (see device.h).
 */
#include "device.h"

#include "fastsw.h"
#include "lsw_bank.h"
#include "lsw_link.h"
#include "lsw_tunables.h"
#include "lsw_wire.h"

#define RING 4u /* samples remembered: a point is the current sample or the one before */
#define SAMPLE_BODY 28u
#define CONFIG_BODY 26u
#define START_BODY 4u
#define REQUEST_BODY 2u
#define ACK_OK 0u
#define ACK_REFUSED 1u
#define NO_TUNABLE 0xFFu

static const char IDENTITY[] = "limbstream-fw 1 fastSW live; board mps2-an386 cortex-m4";

extern uint32_t _stack_top[];

static DeviceWrite send_bytes;
static LswLinkReader reader;
static FastswState state;
static FastswSettings settings;
static double config[LSW_TUNABLES];   /* the tunables as set (status reports them) */
static uint16_t stream_id;
static uint32_t seq;
static int64_t base;                  /* sample number of the stream's sample 0: always 0 */
static uint8_t live;
static int64_t ring_sample[RING], ring_t_us[RING];
static uint32_t samples, points, rejected, refused;
static uint8_t last_point[LSW_POINT_RATE_SIZE];
static uint32_t last_len;              /* 0: no point in this stream yet */

/** Frame and send one message. */
static void send_message(uint8_t type, const uint8_t *body, size_t n)
{
    uint8_t frame[LSW_LINK_MAX_FRAME];
    send_bytes(frame, lsw_link_frame(frame, type, body, n));
}

/** Apply config[] to the settings (and the running stream when retune). */
static void apply_config(int retune)
{
    settings.threshold = (float)config[0];
    settings.max_len = (uint32_t)config[1];
    settings.live_bound_deg = (float)config[2];
    live = (uint8_t)(settings.live_bound_deg > 0.0f && settings.live_bound_deg < 180.0f);
    if (retune) {
        (void)fastsw_retune(&state, &settings);
    }
}

/** A new stream: fresh kernel state, sequence and counters. */
static void start_stream(uint16_t id)
{
    (void)fastsw_init(&state, &settings);
    stream_id = id;
    seq = 0u;
    samples = points = rejected = 0u;
    last_len = 0u;
}

/** ACK of a request: result ACK_OK, or ACK_REFUSED naming the tunable and the value refused. */
static void send_ack(uint16_t request, uint8_t type, uint8_t result, uint8_t tunable, double value)
{
    uint8_t body[13];
    lsw_put_u16(body, request);
    body[2] = type;
    body[3] = result;
    body[4] = tunable;
    lsw_put_f64(body + 5, value);
    send_message(LSW_MSG_ACK, body, sizeof body);
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
static void send_status(uint16_t request)
{
    uint8_t body[2 + 2 + 4 * 6 + 4 * LSW_BAD_REASONS + 8 * LSW_TUNABLES + 4];
    uint8_t *p = body;
    uint32_t k;
    lsw_put_u16(p, request), p += 2;
    lsw_put_u16(p, stream_id), p += 2;
    lsw_put_u32(p, seq), p += 4;
    lsw_put_u32(p, samples), p += 4;
    lsw_put_u32(p, points), p += 4;
    lsw_put_u32(p, rejected), p += 4;
    lsw_put_u32(p, refused), p += 4;
    lsw_put_u32(p, reader.frames), p += 4;
    for (k = 0u; k < LSW_BAD_REASONS; k++) {
        lsw_put_u32(p, reader.bad[k]), p += 4;
    }
    for (k = 0u; k < LSW_TUNABLES; k++) {
        lsw_put_f64(p, config[k]), p += 8;
    }
    lsw_put_u32(p, stack_used());
    send_message(LSW_MSG_STATUS, body, sizeof body);
}

/** IDENTITY: link version, newest point version, sample dimension and the firmware's text. */
static void send_identity(uint16_t request)
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
    send_message(LSW_MSG_IDENTITY, body, sizeof body);
}

/** One sample: the kernel, and its point (if any) as its wire message. */
static void on_sample(const uint8_t *body)
{
    const uint32_t row = samples % RING;
    const uint32_t tick = lsw_get_u32(body);
    float y[4], rates[4];
    uint8_t status, out[LSW_POINT_RATE_SIZE];
    uint32_t slot, end;
    FastswPoint point;
    const uint8_t rate = live;
    const LswBankWire wire = {&stream_id, &seq, &base, ring_sample, ring_t_us, &rate, RING, 1u};
    uint32_t k;
    for (k = 0u; k < 4u; k++) {
        y[k] = lsw_get_f32(body + 12u + 4u * k);
    }
    ring_sample[row] = (int64_t)samples;
    ring_t_us[row] = (int64_t)lsw_get_u64(body + 4);
    if (lsw_bank_update(&state, 1u, &tick, y, &status, &point, rates, &wire, out, &slot, &end) != 0u) {
        for (k = 0u; k < end; k++) {
            last_point[k] = out[k];
        }
        last_len = end;
        points++;
        send_message(LSW_MSG_POINT, out, end);
    }
    rejected += status == (uint8_t)FASTSW_REJECTED;
    samples++;
}

/** End of stream: the last sample as a FINAL point, or the last point repeated as FINAL. */
static void on_end(void)
{
    FastswPoint point;
    uint8_t out[LSW_POINT_RATE_SIZE];
    uint32_t n;
    if (fastsw_flush(&state, &point) == FASTSW_POINT) {
        const uint32_t row = point.index % RING;
        static const float held[3] = {0.0f, 0.0f, 0.0f}; /* a flushed point is held: rate 0 */
        point.index = (uint32_t)(ring_sample[row] - base);
        n = live ? lsw_encode_point_rate(out, LSW_FLAG_FINAL, stream_id, seq, &point, held, ring_t_us[row])
                 : lsw_encode_point(out, LSW_FLAG_FINAL, stream_id, seq, &point, ring_t_us[row]);
    } else if (last_len != 0u) {
        for (n = 0u; n < last_len; n++) {
            out[n] = last_point[n];
        }
        out[1] = (uint8_t)LSW_FLAG_FINAL;
        lsw_put_u32(out + 4, seq);
    } else {
        return; /* no sample in this stream */
    }
    seq++;
    points++;
    send_message(LSW_MSG_POINT, out, n);
}

/** CONFIG: all tunables within the contract's bounds are applied from the next sample, or none. */
static void on_config(uint16_t request, const uint8_t *body)
{
    double values[LSW_TUNABLES];
    uint32_t k;
    for (k = 0u; k < LSW_TUNABLES; k++) {
        values[k] = lsw_get_f64(body + 8u * k);
        if (!tunable_ok(&lsw_tunables[k], values[k])) {
            refused++;
            send_ack(request, LSW_MSG_CONFIG, ACK_REFUSED, (uint8_t)k, values[k]);
            return;
        }
    }
    for (k = 0u; k < LSW_TUNABLES; k++) {
        config[k] = values[k];
    }
    apply_config(1);
    send_ack(request, LSW_MSG_CONFIG, ACK_OK, NO_TUNABLE, 0.0);
}

/** Expected body length of each host message type (0: not one). */
static uint32_t body_length(uint8_t type)
{
    switch (type) {
    case LSW_MSG_SAMPLE: return SAMPLE_BODY;
    case LSW_MSG_CONFIG: return CONFIG_BODY;
    case LSW_MSG_START: return START_BODY;
    case LSW_MSG_END:
    case LSW_MSG_STATUS_REQ:
    case LSW_MSG_IDENTIFY: return REQUEST_BODY;
    default: return 0u;
    }
}

/** A good frame from the reader: check its type and body length, then act on it. */
static void on_frame(void)
{
    const uint8_t type = reader.payload[1];
    const uint8_t *body = reader.payload + 2;
    const uint32_t expected = body_length(type);
    uint16_t request;
    if (expected == 0u) {
        lsw_link_bad(&reader, LSW_BAD_TYPE);
        return;
    }
    if (reader.payload_len - 2u != expected) {
        lsw_link_bad(&reader, LSW_BAD_LENGTH);
        return;
    }
    if (type == LSW_MSG_SAMPLE) {
        on_sample(body);
        return;
    }
    request = lsw_get_u16(body);
    switch (type) {
    case LSW_MSG_CONFIG:
        on_config(request, body + 2);
        break;
    case LSW_MSG_START:
        start_stream(lsw_get_u16(body + 2));
        send_ack(request, type, ACK_OK, NO_TUNABLE, 0.0);
        break;
    case LSW_MSG_END:
        on_end();
        send_ack(request, type, ACK_OK, NO_TUNABLE, 0.0);
        break;
    case LSW_MSG_STATUS_REQ:
        send_status(request);
        break;
    default:
        send_identity(request);
        break;
    }
}

void device_byte(uint8_t byte)
{
    if (lsw_link_feed(&reader, byte)) {
        on_frame();
    }
}

void device_heartbeat(void)
{
    send_status(0u);
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

void device_init(DeviceWrite write)
{
    uint32_t k;
    paint_stack();
    send_bytes = write;
    lsw_link_reader_init(&reader);
    settings = fastsw_default_settings;
    settings.dim = 4u;
    for (k = 0u; k < LSW_TUNABLES; k++) {
        config[k] = lsw_tunables[k].value;
    }
    apply_config(0);
    start_stream(0u);
    refused = 0u;
    send_identity(0u);
}
