"""One serial link to a device, from the host: open it (a tty or ``tcp:HOST:PORT``), send
samples and requests, read its frames on a thread of its own (docs/protocol.md, "Serial link").

The reader thread only decodes and hands off: points and heartbeats go to a bounded FIFO queue
(:attr:`SerialLink.inbox`; what does not fit is counted in :attr:`SerialLink.dropped`), answers
to the waiting request. A bad frame is counted by reason
(:attr:`SerialLink.bad`) and dropped; the link goes on.
"""
from __future__ import annotations

import itertools
import os
import queue
import select
import socket
import termios
import threading
import time
import tty

from limbstream import wire
from limbstream.wire import serial_link as link

READ_CHUNK = 4096
INBOX = 8192
"""Messages the inbox holds (minutes of points at 50 Hz: a consumer that stops reading)."""
POLL_S = 0.2
"""A tty's reader looks this often whether the link was closed."""
ANSWER_TIMEOUT_S = 5.0
"""How long a request waits for the device's answer."""


class LinkClosed(ConnectionError):
    """The link ended (the device went away)."""


def open_port(port: str, timeout_s: float = 10.0, stop: threading.Event | None = None):
    """(read(n) -> bytes, b"" at the end, None if nothing came for a while; write(bytes);
    wake() the reader blocked in read; close()) of ``port``: ``tcp:HOST:PORT`` (retried for ``timeout_s``: an emulator that is
    still starting; ConnectionAbortedError once ``stop`` is set) or a serial device path (raw mode)."""
    if port.startswith("tcp:"):
        host, _, number = port[4:].rpartition(":")
        deadline = time.monotonic() + timeout_s
        stop = stop or threading.Event()
        while True:
            try:
                sock = socket.create_connection((host or "127.0.0.1", int(number)), timeout=timeout_s)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                if stop.wait(0.05):
                    raise ConnectionAbortedError(f"{port}: stopped") from None
        sock.settimeout(None)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        def wake() -> None:
            try:
                sock.shutdown(socket.SHUT_RDWR)  # recv returns b""
            except OSError:
                pass

        return sock.recv, sock.sendall, wake, sock.close
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY)
    if os.isatty(fd):
        tty.setraw(fd, termios.TCSANOW)

    def write(data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]

    def read(n: int) -> bytes | None:
        ready, _, _ = select.select([fd], [], [], POLL_S)  # wakes up to see a close
        return os.read(fd, n) if ready else None

    return read, write, (lambda: None), (lambda: os.close(fd))


class SerialLink:
    """A device at the other end of ``port``.

    Attributes
    ----------
    inbox : bounded queue of ("point", bytes) and ("status", LinkStatus) in arrival order;
        then ("closed", None) when the link ends.
    dropped : messages that found the inbox full.
    identity : the device's latest :class:`~limbstream.wire.serial_link.Identity`, or None.
    reader : the frame reader (``reader.bad``: frames dropped by reason, ``reader.frames``).
    bytes_in, bytes_out : bytes read from and written to the link.
    last_heard : time.monotonic() of the last bytes read (the device's heartbeat comes every second).
    """

    def __init__(self, port: str, timeout_s: float = 10.0, stop: threading.Event | None = None):
        self.port = port
        self._stop = stop or threading.Event()  # set: requests stop waiting for their answers
        self._read, self._write, self._wake, self._close = open_port(port, timeout_s, self._stop)
        self.reader = link.FrameReader(link.DEVICE_BODIES)
        self.inbox: queue.Queue = queue.Queue(INBOX)
        self.dropped = 0
        self.bytes_in = self.bytes_out = 0
        self.last_heard = time.monotonic()
        self.identity: link.Identity | None = None
        self.closed = threading.Event()
        self._closing = False
        self._lock = threading.Lock()
        self._requests = itertools.count(1)
        self._waiting: dict[int, tuple[threading.Event, list]] = {}
        self._thread = threading.Thread(target=self._run, name=f"link {port}", daemon=True)
        self._thread.start()

    @property
    def bad(self) -> dict[str, int]:
        return self.reader.bad

    def _run(self) -> None:
        try:
            while not self._closing:
                data = self._read(READ_CHUNK)
                if data is None:
                    continue
                if not data:
                    break
                self.bytes_in += len(data)
                self.last_heard = time.monotonic()
                for kind, body in self.reader.feed(data):
                    self._deliver(link.decode_device(kind, body))
        except OSError:
            pass
        finally:
            self.closed.set()
            for event, _ in list(self._waiting.values()):
                event.set()
            self.inbox.put(("closed", None))  # may wait for room: the end is never dropped

    def _deliver(self, message: link.DeviceMessage) -> None:
        if isinstance(message, bytes):
            self._hand_off(("point", message))
            return
        if isinstance(message, link.Identity):
            self.identity = message
        elif isinstance(message, link.LinkStatus) and message.request == 0:
            self._hand_off(("status", message))
            return
        waiting = self._waiting.get(message.request)
        if waiting is not None:
            waiting[1].append(message)
            waiting[0].set()

    def _hand_off(self, item: tuple) -> None:
        try:
            self.inbox.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def send(self, data: bytes) -> None:
        """Write frames (or anything: the device counts what is not a frame)."""
        if self.closed.is_set():
            raise LinkClosed(f"{self.port}: link closed")
        with self._lock:
            try:
                self._write(data)
                self.bytes_out += len(data)
            except OSError as exc:
                raise LinkClosed(f"{self.port}: {exc}") from None

    def sample(self, tick: int, t_us: int, q) -> None:
        """One sample (see :func:`limbstream.wire.serial_link.encode_sample`)."""
        self.send(link.encode_sample(tick, t_us, q))

    def raw(self, tick: int, t_us: int, gyr, acc, mag=None) -> None:
        """One raw IMU sample (see :func:`limbstream.wire.serial_link.encode_raw`)."""
        self.send(link.encode_raw(tick, t_us, gyr, acc, mag))

    def _ask(self, encode, timeout_s: float = ANSWER_TIMEOUT_S, while_heard: bool = False):
        """Send a request and wait for its answer: ``timeout_s``, or with ``while_heard`` as long as
        the device is heard from (anything it sends: its heartbeat comes every second) and
        ``timeout_s`` of silence at most."""
        request = next(self._requests) & 0xFFFF or next(self._requests)
        event: threading.Event = threading.Event()
        answer: list = []
        self._waiting[request] = (event, answer)
        try:
            self.send(encode(request))
            deadline = time.monotonic() + timeout_s
            while not event.wait(min(0.05, max(0.0, deadline - time.monotonic()))):
                if self._stop.is_set() or self.closed.is_set():
                    break
                if time.monotonic() >= deadline:  # (while the device is heard from, it is still working)
                    if not (while_heard and time.monotonic() - self.last_heard < timeout_s):
                        break
            if not answer and self._stop.is_set():
                raise LinkClosed(f"{self.port}: stopped")
            if not answer:
                raise (LinkClosed if self.closed.is_set() else TimeoutError)(
                    f"{self.port}: no answer to request {request} in {timeout_s:g} s")
            return answer[0]
        finally:
            del self._waiting[request]

    def configure(self, config: wire.DeviceConfig) -> link.Ack:
        """Send the device its tunables; its :class:`Ack` (``error``: the contract's refusal)."""
        return self._ask(lambda r: link.encode_config(r, config))

    def start(self, stream: int) -> link.Ack:
        """Begin a new stream with this id."""
        return self._ask(lambda r: link.encode_start(r, stream))

    def end(self, timeout_s: float = ANSWER_TIMEOUT_S) -> link.Ack:
        """End the stream: its last point (FINAL) comes before the ack. The device answers once it
        has taken every frame sent before, which takes a device that fell behind (a slow core, a
        backlog of frames) a while: the ack is waited for as long as the device is heard from
        (its heartbeat, every second even while it works), ``timeout_s`` of silence at most."""
        return self._ask(lambda r: link.encode_request(link.END, r), timeout_s, while_heard=True)

    def status(self) -> link.LinkStatus:
        return self._ask(lambda r: link.encode_request(link.STATUS_REQ, r))

    def identify(self) -> link.Identity:
        return self._ask(lambda r: link.encode_request(link.IDENTIFY, r))

    def fusion(self, settings) -> link.Ack:
        """Set the device's raw-sample fusion (an ``ImuSettings`` of
        :func:`limbstream.kernel.fusion.imu_settings`); a fresh filter."""
        return self._ask(lambda r: link.encode_fusion(r, settings.raw_period_s, settings.out_period, settings.max_gap,
                                                      settings.acc_limit, bool(settings.nine_d), settings.rest_th_gyr,
                                                      settings.rest_th_acc, tuple(settings.heading)))

    def fusion_status(self) -> link.FusionStatus:
        return self._ask(lambda r: link.encode_request(link.FUSION_REQ, r))

    def close(self) -> None:
        """Stop the reader, then close the port (never under a reader still using it)."""
        self._closing = True
        self._wake()
        self._thread.join(timeout=2.0)
        try:
            self._close()
        except OSError:
            pass
