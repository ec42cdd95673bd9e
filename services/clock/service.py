"""The time service: a queryable on ``limbstream/@time`` answering each device's time request
with its receive and send times (docs/protocol.md, "Time exchange").

One thread waits on the queryable's channel and answers at once: ``t2`` is stamped as soon as
the query is taken from the channel, ``t3`` just before the reply goes out, so the service's own
time between them never counts as network delay. Zenoh's callbacks are not used.

For tests and benchmarks the service can add delay to the exchange path (each direction
``delay_ms`` +- uniform ``jitter_ms``, drawn per query, outside [t2, t3], standing in for
``tc netem delay D J`` on hosts without it), and its clock can jump once (``jump_ms`` after
``jump_after_s``).
"""
from __future__ import annotations

import heapq
import logging
import random
import threading
import time
from dataclasses import dataclass

import zenoh

from limbstream import wire

log = logging.getLogger("limbstream.clock")


@dataclass(frozen=True)
class ClockServiceSettings:
    """Tuning of the time service.

    Attributes
    ----------
    speed : time scale of the served time (as the emulator's ``--speed``).
    anchor_us : the instant the scaled time agrees with the host clock, us; None: the start.
    delay_ms, jitter_ms : test option: each direction of the exchange is delayed by
        ``delay_ms`` + uniform(-``jitter_ms``, ``jitter_ms``) (at least 0), wall milliseconds.
    jump_ms, jump_after_s : test option: the served clock jumps by ``jump_ms`` once,
        ``jump_after_s`` wall seconds after the start.
    seed : seed of the injected delays.
    """

    speed: float = 1.0
    anchor_us: float | None = None
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    jump_ms: float = 0.0
    jump_after_s: float = 0.0
    seed: int = 0


@dataclass
class ServiceStats:
    answered: int = 0
    bad: int = 0  # requests that were not time requests (answered with an error reply)


class TimeService:
    """Serves the common time base on :func:`limbstream.wire.time_key`."""

    def __init__(self, session: zenoh.Session, settings: ClockServiceSettings = ClockServiceSettings()):
        self.session, self.settings = session, settings
        self.anchor_us = time.time_ns() / 1e3 if settings.anchor_us is None else settings.anchor_us
        self.started = time.monotonic()
        self.stats = ServiceStats()
        self._rng = random.Random(settings.seed)
        self._delayed = settings.delay_ms > 0 or settings.jitter_ms > 0
        self._heap: list = []
        self._cond = threading.Condition()
        self._n = 0

    def now_us(self) -> int:
        """The served time: the host clock scaled around the anchor, plus the test jump once due."""
        s = self.settings
        t = self.anchor_us + s.speed * (time.time_ns() / 1e3 - self.anchor_us)
        if s.jump_ms and time.monotonic() - self.started >= s.jump_after_s:
            t += s.jump_ms * 1e3
        return int(round(t))

    def _path_delay(self) -> float:
        s = self.settings
        return max(0.0, s.delay_ms + self._rng.uniform(-s.jitter_ms, s.jitter_ms)) / 1e3

    def run(self, stop: threading.Event) -> ServiceStats:
        """Answer until ``stop`` (the calling thread waits; a receiver thread blocks on the
        queryable's channel and answers)."""
        queryable = self.session.declare_queryable(wire.time_key(), zenoh.handlers.FifoChannel(1 << 14))
        threads = [threading.Thread(target=self._receive, args=(queryable, stop), name="clock-receive", daemon=True)]
        if self._delayed:
            threads.append(threading.Thread(target=self._send_delayed, args=(stop,), name="clock-delay", daemon=True))
        for t in threads:
            t.start()
        try:
            last = 0
            while not stop.wait(10.0):  # a count every 10 s (INFO: -v)
                log.info("answered %d time requests (%d in the last 10 s), refused %d",
                         self.stats.answered, self.stats.answered - last, self.stats.bad)
                last = self.stats.answered
        finally:
            stop.set()
            with self._cond:
                self._cond.notify_all()
            # wake the receiver: a query only this session's queryable sees
            self.session.get(wire.time_key(), allowed_destination=zenoh.Locality.SESSION_LOCAL, timeout=1.0)
            for t in threads:
                t.join(timeout=2.0)
            queryable.undeclare()
        return self.stats

    def _receive(self, queryable, stop: threading.Event) -> None:
        """Receiver thread: each query is answered (or queued for its injected delay) as soon as
        ``recv`` returns it."""
        while True:
            query = queryable.recv()
            if stop.is_set():
                query.drop()
                return
            if self._delayed:
                self._push(time.monotonic() + self._path_delay(), "stamp", query)
            else:
                self._answer(query, self.now_us())

    def _answer(self, query: zenoh.Query, t2: int) -> None:
        """Reply to one query received at ``t2`` (served time)."""
        with query:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                request = wire.decode_time_request(payload)
            except wire.WireError as exc:
                self.stats.bad += 1
                query.reply_err(f"time request: {exc}")
                return
            answer = wire.TimeAnswer(request.id, request.t1_us, t2, max(t2, self.now_us()))
            query.reply(wire.time_key(), wire.encode_time_answer(answer))
            self.stats.answered += 1

    # ------------------------------------------------------------------ injected path delay

    def _push(self, due: float, what: str, query, payload: bytes | None = None) -> None:
        with self._cond:
            self._n += 1
            heapq.heappush(self._heap, (due, self._n, what, query, payload))
            self._cond.notify()

    def _send_delayed(self, stop: threading.Event) -> None:
        """Delayed path: a query is stamped (t2, t3) when its request delay is over, its answer
        sent when its answer delay is over."""
        while not stop.is_set():
            with self._cond:
                while not stop.is_set() and not (self._heap and self._heap[0][0] <= time.monotonic()):
                    self._cond.wait(self._heap[0][0] - time.monotonic() if self._heap else 0.1)
                if stop.is_set():
                    return
                _, _, what, query, payload = heapq.heappop(self._heap)
            if what == "stamp":
                payload = self._stamped(query)
                if payload is not None:
                    self._push(time.monotonic() + self._path_delay(), "send", query, payload)
            else:
                with query:
                    query.reply(wire.time_key(), payload)

    def _stamped(self, query: zenoh.Query) -> bytes | None:
        """The answer of a delayed query (stamped now), or None (bad request, refused)."""
        t2 = self.now_us()
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            request = wire.decode_time_request(payload)
        except wire.WireError as exc:
            self.stats.bad += 1
            with query:
                query.reply_err(f"time request: {exc}")
            return None
        self.stats.answered += 1
        return wire.encode_time_answer(wire.TimeAnswer(request.id, request.t1_us, t2, max(t2, self.now_us())))
