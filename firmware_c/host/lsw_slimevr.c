/*
 * lsw_slimevr.c - rotation datagrams of routed SlimeVR sensors, read and handled in C (see
 * lsw_slimevr.h). Host library only; the protocol is services/gateway/slimevr_protocol.py's.
 */
#define _GNU_SOURCE /* recvmmsg (Linux; elsewhere one recvfrom per datagram, stamped at the read) */
#include "lsw_slimevr.h"

#include <errno.h>
#include <math.h>
#include <string.h>
#include <time.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#define BATCH 64u            /* datagrams per read */
#define MAX_DATAGRAM 1472u   /* longer: oversized (the caller's) */
#define MAX_ROTATIONS 16u    /* rotations of one bundle handled here; more: the caller's */
#define HEADER 12u           /* i32 type, i64 packet number */
#define ROTATION_DATA 17
#define ROTATION_ACCEL 23
#define BUNDLE 100
#define BUNDLE_COMPACT 101
#define ROTATION_NORMAL 1u
#define ROTATION_SIZE 18u    /* type 17 payload: sensor, data type, 4 f32 (the accuracy byte is optional) */
#define ROTATION_Q15_SIZE 9u /* type 23 payload up to its quaternion: sensor, 4 i16 */
#define MIN_NORM 1e-3        /* a smaller quaternion is bad (the caller counts it) */

struct LswSvrRx {
    const LswGridSettings *grid;
    LswGridDevice *devices;
    const LswSvrRoute *routes;
    uint32_t n_routes;
    int fd;
    int kernel_stamps;
    uint32_t overflows;   /* datagrams the kernel dropped on a full socket buffer (SO_RXQ_OVFL) */
    uint32_t late_errors; /* read errors after the first datagram of a batch (counted at the next drain) */
    uint32_t next, count; /* the batch: datagrams [next, count) not handled yet */
    struct sockaddr_in from[BATCH];
    uint32_t len[BATCH];
    double stamp[BATCH];
    uint8_t data[BATCH][LSW_SVR_MAX_DATAGRAM];
#ifdef __linux__
    struct mmsghdr msgs[BATCH];
    struct iovec iov[BATCH];
    union { /* control messages: the kernel's arrival stamp */
        char buf[CMSG_SPACE(sizeof(struct timespec)) + CMSG_SPACE(sizeof(uint32_t))];
        struct cmsghdr align;
    } control[BATCH];
#endif
};

typedef struct {
    uint32_t sensor;
    double q[4];
} Rotation;

static uint32_t be32(const uint8_t *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | (uint32_t)p[3];
}

static int64_t be64(const uint8_t *p)
{
    return (int64_t)(((uint64_t)be32(p) << 32) | (uint64_t)be32(p + 4));
}

static double be_f32(const uint8_t *p)
{
    const uint32_t bits = be32(p);
    float f;
    memcpy(&f, &bits, sizeof f);
    return (double)f;
}

static double be_q15(const uint8_t *p)
{
    return (double)(int16_t)(((uint16_t)p[0] << 8) | (uint16_t)p[1]) * (1.0 / 32768.0);
}

/** (w, x, y, z) normalised into out; 0 if not finite or (nearly) zero. */
static int unit(double w, double x, double y, double z, double *out)
{
    const double norm = sqrt(w * w + x * x + y * y + z * z);
    if (!isfinite(norm) || norm < MIN_NORM) {
        return 0;
    }
    out[0] = w / norm;
    out[1] = x / norm;
    out[2] = y / norm;
    out[3] = z / norm;
    return 1;
}

/** A rotation packet's payload p (n bytes) of type kind into r; 0 if it is not one handled here. */
static int rotation(int32_t kind, const uint8_t *p, size_t n, Rotation *r)
{
    if (kind == ROTATION_DATA && n >= ROTATION_SIZE && p[1] == ROTATION_NORMAL) {
        r->sensor = p[0];
        return unit(be_f32(p + 14), be_f32(p + 2), be_f32(p + 6), be_f32(p + 10), r->q);
    }
    if (kind == ROTATION_ACCEL && n >= ROTATION_Q15_SIZE) {
        r->sensor = p[0];
        return unit(be_q15(p + 7), be_q15(p + 1), be_q15(p + 3), be_q15(p + 5), r->q);
    }
    return 0;
}

/** The rotations of a datagram made of nothing else (a lone one or a bundle of them); 0: not. */
static uint32_t rotations(const uint8_t *data, size_t len, Rotation *out)
{
    const int32_t kind = (int32_t)be32(data);
    const uint8_t *p = data + HEADER;
    const size_t n = len - HEADER;
    size_t at = 0u;
    uint32_t count = 0u;
    if (kind == ROTATION_DATA || kind == ROTATION_ACCEL) {
        return (uint32_t)rotation(kind, p, n, out);
    }
    if (kind != BUNDLE && kind != BUNDLE_COMPACT) {
        return 0u;
    }
    while (at < n) { /* items: u16 length, i32 type, payload (101: u8 length, u8 type, payload) */
        const size_t size = kind == BUNDLE_COMPACT ? 1u : 2u, head = kind == BUNDLE_COMPACT ? 1u : 4u;
        size_t item;
        if (n < at + size) {
            return 0u;
        }
        item = kind == BUNDLE_COMPACT ? p[at] : (size_t)(((uint16_t)p[at] << 8) | p[at + 1u]);
        at += size;
        if (n < at + item) {
            return 0u;
        }
        if (item > 0u) {
            if (item < head || count == MAX_ROTATIONS) {
                return 0u;
            }
            if (!rotation(kind == BUNDLE_COMPACT ? (int32_t)p[at] : (int32_t)be32(p + at), p + at + head,
                          item - head, &out[count])) {
                return 0u;
            }
            count++;
        }
        at += item;
    }
    return count;
}

static const LswSvrRoute *route(const LswSvrRx *rx, uint32_t ip, uint16_t port, uint32_t sensor)
{
    uint32_t k;
    for (k = 0u; k < rx->n_routes; k++) {
        const LswSvrRoute *r = &rx->routes[k];
        if (r->ip == ip && r->port == port && r->sensor == sensor) {
            return r;
        }
    }
    return NULL;
}

size_t lsw_svr_rx_size(void)
{
    return sizeof(LswSvrRx);
}

int lsw_svr_rx_init(LswSvrRx *rx, int fd, const LswGridSettings *grid, LswGridDevice *devices)
{
    uint32_t k;
    memset(rx, 0, sizeof *rx);
    rx->grid = grid;
    rx->devices = devices;
    rx->fd = fd;
#ifdef __linux__
    for (k = 0u; k < BATCH; k++) {
        rx->iov[k].iov_base = rx->data[k];
        rx->iov[k].iov_len = LSW_SVR_MAX_DATAGRAM;
    }
#else
    (void)k;
#endif
#if defined(__linux__) && defined(SO_TIMESTAMPNS)
    if (fd >= 0) {
        const int on = 1;
        rx->kernel_stamps = setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on) == 0;
#ifdef SO_RXQ_OVFL
        (void)setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on);
#endif
    }
#endif
    return rx->kernel_stamps;
}

uint32_t lsw_svr_rx_overflows(const LswSvrRx *rx)
{
    return rx->overflows;
}

void lsw_svr_rx_routes(LswSvrRx *rx, const LswSvrRoute *routes, uint32_t count)
{
    rx->routes = routes;
    rx->n_routes = count;
}

int lsw_svr_datagram(LswSvrRx *rx, const uint8_t *data, size_t len, uint32_t ip, uint16_t port, double t_us,
                     double now_s)
{
    Rotation rot[MAX_ROTATIONS];
    const LswSvrRoute *to[MAX_ROTATIONS];
    LswSvrTracker *tracker = NULL;
    int64_t number;
    uint32_t n, k;
    if (len < HEADER || len > MAX_DATAGRAM) {
        return 0;
    }
    n = rotations(data, len, rot);
    if (n == 0u) {
        return 0;
    }
    for (k = 0u; k < n; k++) {
        to[k] = route(rx, ip, port, rot[k].sensor);
        if (to[k] == NULL || !rx->devices[to[k]->slot].online) {
            return 0;
        }
        tracker = to[k]->tracker;
    }
    number = be64(data + 4);
    if (!tracker->online || number <= tracker->last_number || number == 0) {
        return 0; /* the caller marks it online again, or counts it out of order */
    }
    if (tracker->last_number >= 0 && number - tracker->last_number < ((int64_t)1 << 16)) {
        tracker->lost += number - tracker->last_number - 1;
    }
    tracker->last_number = number;
    tracker->packets++;
    tracker->arrived++;
    tracker->last_seen = now_s;
    for (k = 0u; k < n; k++) {
        lsw_grid_push(rx->grid, &rx->devices[to[k]->slot], t_us, rot[k].q, now_s);
    }
    return 1;
}

static double realtime_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
}

#ifdef __linux__
/** Read the next batch into rx (0 datagrams: none waits); -1 on a read error. */
static int read_batch(LswSvrRx *rx)
{
    uint32_t k;
    int got;
    rx->next = rx->count = 0u;
    for (k = 0u; k < BATCH; k++) {
        struct msghdr *h = &rx->msgs[k].msg_hdr;
        memset(h, 0, sizeof *h);
        h->msg_name = &rx->from[k];
        h->msg_namelen = sizeof rx->from[k];
        h->msg_iov = &rx->iov[k];
        h->msg_iovlen = 1;
        h->msg_control = rx->control[k].buf;
        h->msg_controllen = sizeof rx->control[k].buf;
    }
    got = recvmmsg(rx->fd, rx->msgs, BATCH, MSG_DONTWAIT, NULL);
    if (got < 0) {
        return (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) ? 0 : -1;
    }
    for (k = 0u; k < (uint32_t)got; k++) {
        struct msghdr *h = &rx->msgs[k].msg_hdr;
        struct cmsghdr *c;
        rx->len[k] = rx->msgs[k].msg_len;
        rx->stamp[k] = 0.0;
        for (c = CMSG_FIRSTHDR(h); c != NULL; c = CMSG_NXTHDR(h, c)) {
#ifdef SO_TIMESTAMPNS
            if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
                struct timespec ts;
                memcpy(&ts, CMSG_DATA(c), sizeof ts);
                rx->stamp[k] = (double)ts.tv_sec * 1e6 + (double)ts.tv_nsec / 1e3;
            }
#endif
#ifdef SO_RXQ_OVFL
            if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
                memcpy(&rx->overflows, CMSG_DATA(c), sizeof rx->overflows); /* the socket's running count */
            }
#endif
        }
        if (rx->stamp[k] == 0.0) {
            rx->stamp[k] = realtime_us();
        }
    }
    rx->count = (uint32_t)got;
    return got;
}
#else
/** Read the next batch into rx, one recvfrom each, stamped at the read (0: none waits; -1: a read error). */
static int read_batch(LswSvrRx *rx)
{
    uint32_t k;
    rx->next = rx->count = 0u;
    for (k = 0u; k < BATCH; k++) {
        socklen_t size = sizeof rx->from[k];
        const ssize_t got = recvfrom(rx->fd, rx->data[k], LSW_SVR_MAX_DATAGRAM, MSG_DONTWAIT,
                                     (struct sockaddr *)&rx->from[k], &size);
        if (got < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
                if (k == 0u) {
                    return -1;
                }
                rx->late_errors++;
            }
            break;
        }
        rx->len[k] = (uint32_t)got;
        rx->stamp[k] = realtime_us();
    }
    rx->count = k;
    return (int)k;
}
#endif

uint32_t lsw_svr_drain(LswSvrRx *rx, double now_s, uint32_t budget, LswSvrSlow *slow, int64_t *errors)
{
    uint32_t read = 0u;
    slow->ready = 0u;
    *errors += rx->late_errors;
    rx->late_errors = 0u;
    while (read < budget) {
        uint32_t k, len, ip;
        uint16_t port;
        if (rx->next == rx->count) {
            const int got = read_batch(rx);
            if (got < 0) {
                (*errors)++;
                read++; /* an error reported once per earlier send: it counts toward the budget */
                continue;
            }
            if (got == 0) {
                break;
            }
        }
        k = rx->next++;
        read++;
        len = rx->len[k] < LSW_SVR_MAX_DATAGRAM ? rx->len[k] : LSW_SVR_MAX_DATAGRAM;
        ip = ntohl(rx->from[k].sin_addr.s_addr);
        port = ntohs(rx->from[k].sin_port);
        if (rx->from[k].sin_family == AF_INET
            && lsw_svr_datagram(rx, rx->data[k], len, ip, port, rx->stamp[k], now_s)) {
            continue;
        }
        memcpy(slow->data, rx->data[k], len);
        slow->len = len;
        slow->ready = 1u;
        slow->ip = ip;
        slow->port = port;
        slow->t_us = rx->stamp[k];
        break;
    }
    return read;
}
