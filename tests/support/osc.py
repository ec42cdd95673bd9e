"""A python-osc UDP receiver for the OSC outputs' tests (VMC, VRChat)."""
from __future__ import annotations

import socket
import threading

from pythonosc import dispatcher, osc_server

SO_RCVBUFFORCE = 33  # Linux's (Python's socket module does not name it)


class OscReceiver:
    """A python-osc UDP server on a free port collecting (address, args) in arrival order."""

    def __init__(self):
        self.messages: list[tuple[str, list]] = []
        self.lock = threading.Lock()
        d = dispatcher.Dispatcher()
        d.set_default_handler(lambda address, *args: self._add(address, list(args)))
        self.server = osc_server.BlockingOSCUDPServer(("127.0.0.1", 0), d)
        try:  # room for seconds of messages while this process waits for a core (root: beyond rmem_max)
            self.server.socket.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 1 << 24)
        except PermissionError:
            self.server.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 24)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, args=(0.05,), daemon=True)
        self.thread.start()

    def _add(self, address, args):
        with self.lock:
            self.messages.append((address, args))

    def snapshot(self) -> list[tuple[str, list]]:
        with self.lock:
            return list(self.messages)

    def count(self, address: str) -> int:
        return sum(a == address for a, _ in self.snapshot())

    def close(self):
        self.server.shutdown()
        self.server.server_close()

    def bundles(self, last: str) -> list[list[tuple[str, list]]]:
        """Messages split after each one at address ``last`` (the last of a bundle)."""
        out, current = [], []
        for m in self.snapshot():
            current.append(m)
            if m[0] == last:
                out.append(current)
                current = []
        return out
