"""The SlimeVR gateway's datagrams of routed sensors' rotations, read and handled in C
(``firmware_c/host/lsw_slimevr.c``): nearly all of a tracker's traffic, without a Python step per
packet. Every other datagram comes back to the gateway's Python, in order.

A route says that rotations of (IPv4 address, port, sensor) go to a device of the gateway's
:class:`limbstream.kernel.grid.GridBank`, and which tracker's link counters
(:class:`limbstream.kernel._lib.SvrTracker`) count their packets. The C side takes a datagram
only when all of it is rotations of routed sensors, its tracker and devices are online and its
packet number is newer than the last; anything else is the gateway's to decode and count.
"""
from __future__ import annotations

import ctypes
import socket
from collections.abc import Iterable

from limbstream.kernel._lib import SvrRoute, SvrSlow, SvrTracker, _lib
from limbstream.kernel.grid import GridBank


def ipv4(host: str) -> int | None:
    """An IPv4 address as the C side keys it (host order), or None if ``host`` is not one."""
    try:
        return int.from_bytes(socket.inet_aton(host), "big") if host.count(".") == 3 else None
    except OSError:
        return None


class Receiver:
    """Reads ``sock`` (an IPv4 UDP socket; None: datagrams are handed in, :meth:`datagram`) into
    ``grid``'s devices.

    ``reads``: it reads a socket. ``kernel_stamps``: each datagram carries the kernel's arrival
    stamp, so it may wait in the socket until the next tick without losing its arrival time.
    """

    def __init__(self, sock: socket.socket | None, grid: GridBank, max_routes: int):
        self._rx = ctypes.create_string_buffer(_lib.lsw_svr_rx_size())
        self._grid = grid  # the C side keeps pointers into it (and into the routed links: _links)
        self._links: list[SvrTracker] = []
        fd = sock.fileno() if sock is not None else -1
        self.reads = sock is not None
        self.kernel_stamps = bool(_lib.lsw_svr_rx_init(self._rx, fd, grid.settings_ptr, grid.devices_ptr))
        self._routes = (SvrRoute * max(max_routes, 1))()
        self._slow = SvrSlow()
        self._errors = ctypes.c_int64(0)
        self._slow_ptr, self._errors_ptr = ctypes.addressof(self._slow), ctypes.addressof(self._errors)

    @property
    def overflows(self) -> int:
        """Datagrams the kernel dropped because the socket's buffer was full (Linux)."""
        return _lib.lsw_svr_rx_overflows(self._rx)

    @property
    def errors(self) -> int:
        """Read errors (an ICMP error of an earlier send, reported at a read)."""
        return self._errors.value

    def route(self, routes: Iterable[tuple[SvrTracker, int, int, int, int]]) -> None:
        """The routes from now on: (tracker's link counters, ip, port, sensor, device)."""
        links = []
        for n, (link, ip, port, sensor, slot) in enumerate(routes):
            self._routes[n] = SvrRoute(ctypes.pointer(link), ip, port, sensor, 0, slot, 0)
            links.append(link)
        self._links = links
        _lib.lsw_svr_rx_routes(self._rx, self._routes, len(links))

    def datagram(self, data: bytes, ip: int, port: int, t_us: float, now: float) -> bool:
        """One datagram from (ip, port), arrived at ``t_us``, at monotonic ``now`` (s): True when
        taken here."""
        return bool(_lib.lsw_svr_datagram(self._rx, data, len(data), ip, port, t_us, now))

    def drain(self, now: float, budget: int) -> tuple[int, tuple[bytes, tuple[str, int], float] | None]:
        """Read the socket at monotonic ``now`` (s), at most ``budget`` datagrams, until it is empty
        or a datagram is the gateway's: (datagrams read, that datagram as (data, address, arrival
        us) or None)."""
        n = _lib.lsw_svr_drain(self._rx, now, budget, self._slow_ptr, self._errors_ptr)
        s = self._slow
        if not s.ready:
            return n, None
        address = (socket.inet_ntoa(s.ip.to_bytes(4, "big")), s.port)
        return n, (ctypes.string_at(s.data, s.len), address, s.t_us)
