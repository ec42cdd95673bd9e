/*
 * lsw_slimevr.h - the SlimeVR gateway's datagrams that carry only rotations of sensors it routes,
 * read and handled in C (services/gateway/slimevr.py keeps everything else). Host library only.
 *
 * A tracker sends about a hundred rotation datagrams a second per sensor: a lone rotation packet
 * (type 17 with the fused orientation, or 23 in Q15) or a bundle (100, 101) of them. Such a
 * datagram from a tracker whose sensors are routed (IPv4 address, port, sensor -> tracker record
 * and device) is counted on the tracker (its packet numbers: loss, order; last heard) and each
 * rotation goes to its device's grid (lsw_grid_push). Any other datagram, or one that breaks a
 * rule (out of order, bad quaternion, unrouted sensor, offline tracker or device), is left to the
 * caller, who decodes and counts it in full; datagrams keep their order.
 *
 * Reading: recvmmsg in batches, each datagram stamped by the kernel on arrival (SO_TIMESTAMPNS)
 * where the system has it, else at the read (then the caller must read often).
 */
#ifndef LSW_SLIMEVR_H
#define LSW_SLIMEVR_H

#include <stddef.h>
#include <stdint.h>

#include "lsw_grid.h"

#ifdef __cplusplus
extern "C" {
#endif

#define LSW_SVR_MAX_DATAGRAM 2048u /**< bytes read of a datagram (a longer one is cut: oversized anyway) */

/** One tracker's link counters, shared with the caller. */
typedef struct {
    int64_t last_number; /**< newest packet number taken; -1: none since its handshake */
    int64_t lost;        /**< packet numbers skipped */
    int64_t packets;     /**< numbered packets taken */
    int64_t arrived;     /**< datagrams heard (for its packet rate) */
    double last_seen;    /**< monotonic s of the newest */
    uint32_t online;     /**< 1: heard within its timeout (the caller decides) */
    uint32_t pad;
} LswSvrTracker;

/** A routed sensor: rotations from (ip, port) for this sensor go to device `slot`. */
typedef struct {
    LswSvrTracker *tracker;
    uint32_t ip;     /**< IPv4 address, host order */
    uint16_t port;
    uint8_t sensor;
    uint8_t pad;
    uint32_t slot;   /**< device index in the grid bank */
    uint32_t pad2;
} LswSvrRoute;

/** A datagram left to the caller. */
typedef struct {
    uint8_t data[LSW_SVR_MAX_DATAGRAM];
    uint32_t len;    /**< bytes in data */
    uint32_t ip;     /**< sender, IPv4, host order */
    uint16_t port;
    uint16_t ready;  /**< 1: a datagram is here */
    double t_us;     /**< arrival, gateway clock (microseconds since the epoch) */
} LswSvrSlow;

typedef struct LswSvrRx LswSvrRx;

/** Bytes of an LswSvrRx (the caller allocates it). */
size_t lsw_svr_rx_size(void);

/**
 * Set up rx for socket fd (IPv4 UDP, non-blocking reads; -1: no socket, lsw_svr_datagram only),
 * the grid bank's settings and devices. Returns 1 when datagrams are stamped by the kernel on
 * arrival, else 0.
 */
int lsw_svr_rx_init(LswSvrRx *rx, int fd, const LswGridSettings *grid, LswGridDevice *devices);

/** Datagrams the kernel dropped because the socket's buffer was full (Linux; else 0). */
uint32_t lsw_svr_rx_overflows(const LswSvrRx *rx);

/** The routes in use from now on: routes[0..count-1] (the caller keeps the array). */
void lsw_svr_rx_routes(LswSvrRx *rx, const LswSvrRoute *routes, uint32_t count);

/**
 * One datagram from (ip, port) that arrived at t_us, at monotonic now_s: 1 when handled here,
 * 0 when it is the caller's.
 */
int lsw_svr_datagram(LswSvrRx *rx, const uint8_t *data, size_t len, uint32_t ip, uint16_t port, double t_us,
                     double now_s);

/**
 * Read and handle the datagrams waiting on the socket, at most `budget`, at monotonic now_s,
 * until none waits or one is the caller's: that one is in slow (slow->ready), and the next
 * call goes on after it. Returns datagrams read (the caller's one included); read errors (an
 * ICMP error of an earlier send) count in *errors.
 */
uint32_t lsw_svr_drain(LswSvrRx *rx, double now_s, uint32_t budget, LswSvrSlow *slow, int64_t *errors);

#ifdef __cplusplus
}
#endif

#endif /* LSW_SLIMEVR_H */
