"""Devices run by a test in its own Zenoh session: segment points, a liveliness token and a status
queryable each, the status announcing a body as the test chooses (well formed or not). Each
answers on its own config key, as a device does (docs/protocol.md), whatever the query's key
expression (the aggregator's poll asks ``limbstream/*/*/config``), and declares its queryable
before its token, so the question the token prompts finds it."""
from __future__ import annotations

import json
import threading
import time

import numpy as np
import zenoh

from limbstream import quat, wire, zconfig
from limbstream.body import Body


def pose_of(segment: str) -> np.ndarray:
    """(4,) a constant orientation of its own for each segment name."""
    k = sum(map(ord, segment)) % 17
    return quat.normalize(np.array([np.cos(0.05 * k + 0.1), 0.3, 0.2 * np.sin(k), 0.1 * np.cos(k)]))


class FakeDevices:
    """Devices in the test's own session (:meth:`add`): each a status queryable (announcing its
    body), a liveliness token and segment points of its segment's constant orientation at 50 Hz,
    each stream numbered from 0 when its device is added."""

    def __init__(self, endpoint: str):
        self.session = zconfig.open_session(zconfig.ZenohSettings(connect=(endpoint,)))
        self.stop, self.lock = threading.Event(), threading.Lock()
        self.devices: list[tuple[str, str, zenoh.Publisher, list[int]]] = []  # subject, segment, publisher, [sent]
        self.entities: list = []
        self.start = int(time.time() * 1e6)
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def add(self, subject: str, bodies: dict) -> None:
        """Devices of ``subject`` on the segments of ``bodies``, each announcing its body."""
        for segment, body in bodies.items():
            sent = [0]
            pub = self.session.declare_publisher(wire.seg_key(subject, segment))
            self.entities.append(self.session.declare_queryable(wire.config_key(subject, segment),
                                                                self._answerer(subject, segment, body, sent)))
            self.entities.append(self.session.liveliness().declare_token(wire.alive_key(subject, segment)))
            with self.lock:
                self.devices.append((subject, segment, pub, sent))

    @classmethod
    def _answerer(cls, subject: str, segment: str, body, sent: list[int]):
        def answer(query: zenoh.Query) -> None:
            status = wire.DeviceStatus(f"{subject}/{segment}", wire.DeviceConfig(), 7, sent[0], sent[0])
            query.reply(wire.config_key(subject, segment),
                        json.dumps(status.as_dict() | {"body": cls.announced(body)}).encode())
        return answer

    @staticmethod
    def announced(body: Body):
        """What a device's status says of ``body`` (its ``body`` field)."""
        return wire.encode_body(body)

    def run(self) -> None:
        tick = 0
        while not self.stop.wait(0.02):
            tick += 1
            with self.lock:
                devices = list(self.devices)
            for _, segment, pub, sent in devices:
                n = sent[0]
                point = wire.SegmentPoint(7, n, n, self.start + 20_000 * tick, tuple(pose_of(segment)),
                                          omega=(0.0, 0.0, 0.0))
                pub.put(wire.encode_point(point))
                sent[0] = n + 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.session.close()


class RawBodies(FakeDevices):
    """Fake devices whose status carries ``"body"`` as given (any JSON)."""

    @staticmethod
    def announced(body):
        return body
