"""Zenoh configuration, one place: every process builds its ``zenoh.Config`` here, and every
publisher takes its congestion control, priority and express flag from :data:`QOS`.

Multicast scouting is always off (endpoints are explicit; Docker carries no multicast).
Once connected, clients retry a lost router forever with a short back-off, so they survive router
restarts (back ~0.3 s after the router returns). Opening a session waits for the router at most
``ZenohSettings.connect_timeout_s`` (None: as long as it takes, the parts ``limbstream up``
supervises), in a helper thread, so that Ctrl-C stops the caller at any moment.
"""
from __future__ import annotations

import json
import signal
import threading
from dataclasses import dataclass, field

import zenoh

from limbstream import wire
from limbstream.signals import stop_on_signals

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
ROUTER_ENV = "LIMBSTREAM_ROUTER"
"""Environment variable naming the router endpoint(s), comma-separated."""
CONFIG_ENV = "LIMBSTREAM_ZENOH_CONFIG"
"""Environment variable naming a JSON file of extra Zenoh settings (TLS, auth)."""
CONNECT_TIMEOUT_S = 10.0
"""How long a command waits for its router by default, s (``--connect-timeout``)."""


@dataclass(frozen=True)
class Qos:
    """How one kind of message is published (Zenoh publisher options).

    Attributes
    ----------
    congestion_control : BLOCK waits (up to Zenoh's ``wait_before_close``, 5 s) when a link's
        queue of this priority is full; DROP gives up after ``wait_before_drop`` (1 ms).
    priority : Zenoh priority; every priority has its own queue on every link, so a blocked
        queue of one priority does not hold back messages of another.
    express : sent at once, not batched with the messages that follow.
    """

    congestion_control: zenoh.CongestionControl
    priority: zenoh.Priority
    express: bool = False

    def options(self) -> dict:
        """Keyword arguments of ``declare_publisher`` / ``declare_advanced_publisher``."""
        return {"congestion_control": self.congestion_control, "priority": self.priority, "express": self.express}


_BLOCK, _DROP = zenoh.CongestionControl.BLOCK, zenoh.CongestionControl.DROP
QOS: dict[str, Qos] = {
    # the record: frames, replay and recordings are rebuilt from them; never dropped
    wire.SEG: Qos(_BLOCK, zenoh.Priority.DATA),
    # truth batches: the evaluation's record, recovered from the device's cache like points
    wire.RAW: Qos(_BLOCK, zenoh.Priority.DATA_LOW),
    wire.TRUTH: Qos(_BLOCK, zenoh.Priority.DATA_LOW),  # a subject's truth batches in one message
    # final frames: recorders and the dashboard's history keep them, incl. the burst after a restart
    wire.pose_stream(wire.KIND_EXACT): Qos(_BLOCK, zenoh.Priority.DATA),
    # superseded 20 ms later: never wait for them; their own queue, ahead of the bulk. Not express:
    # the frames of all subjects leave in one burst per tick, and batching (at most 1 ms) sends
    # them in a few writes instead of one per frame
    wire.pose_stream(wire.KIND_LIVE): Qos(_DROP, zenoh.Priority.INTERACTIVE_HIGH),
    # once a second per subject; the dashboard's history and recordings keep them
    wire.STATS: Qos(_BLOCK, zenoh.Priority.DATA_LOW),
    # joint angles of the live frames: superseded like them, and never ahead of them (a queue of their own,
    # below the live frames', above the bulk)
    wire.ANGLES: Qos(_DROP, zenoh.Priority.INTERACTIVE_LOW),
}
"""Publisher options per message kind (docs/protocol.md, "Congestion control and priority")."""


def publisher_options(kind: str) -> dict:
    """``declare_publisher`` keyword arguments for ``kind`` (a key of :data:`QOS`)."""
    try:
        return QOS[kind].options()
    except KeyError:
        raise ValueError(f"message kind must be one of {tuple(QOS)}, got {kind!r}") from None


def ask_caches(session: zenoh.Session, selector: str, depth: int, timeout: float):
    """Ask every publisher cache that matches ``selector`` (a :func:`wire.history_selector`) for
    what it holds: every answer of every cache (target ALL, no consolidation, replies on any key
    accepted) into a channel with room for ``depth`` points (at least 1,024); the query ends
    after ``timeout`` seconds. Returns the replies' channel (the aggregator's history and refill
    queries, a subscription's resume)."""
    return session.get(selector, zenoh.handlers.FifoChannel(max(1024, depth)), accept_replies=zenoh.ReplyKeyExpr.ANY,
                       target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout)


@dataclass(frozen=True)
class ZenohSettings:
    """Where and how a process joins the Zenoh network.

    Attributes
    ----------
    mode : "client" | "peer" | "router"
    connect : endpoints to connect to, e.g. ``["tcp/127.0.0.1:7447"]``
    listen : endpoints to listen on (routers)
    lease_ms : transport lease; a frozen process is declared gone after it
    extra : further ``insert_json5`` entries (key -> JSON value), e.g. TLS or auth settings
    connect_timeout_s : a client or peer that reaches none of ``connect`` within this many
        seconds fails to open (:class:`ConnectError`); None: it waits, retrying, however long it
        takes. Either way, once connected it reconnects by itself after losing the router.
    """

    mode: str = "client"
    connect: tuple[str, ...] = (DEFAULT_ROUTER,)
    listen: tuple[str, ...] = ()
    lease_ms: int = 1000
    extra: dict = field(default_factory=dict)
    connect_timeout_s: float | None = None

    def __post_init__(self):
        if self.connect_timeout_s is not None and not self.connect_timeout_s > 0:
            raise ValueError(f"connect_timeout_s must be > 0 or None, got {self.connect_timeout_s}")


class ConnectError(ConnectionError):
    """No router answered within the settings' ``connect_timeout_s``; the sentence names the
    endpoints and the time waited."""

    def __init__(self, settings: ZenohSettings):
        super().__init__(f"no Zenoh router answered at {', '.join(settings.connect) or '(no endpoint)'} "
                         f"within {settings.connect_timeout_s:g} s")
        self.settings = settings


def build_config(settings: ZenohSettings) -> zenoh.Config:
    """The ``zenoh.Config`` for ``settings``."""
    if settings.mode not in ("client", "peer", "router"):
        raise ValueError(f"mode must be client, peer or router, got {settings.mode!r}")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    config.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    config.insert_json5("transport/link/tx/lease", str(int(settings.lease_ms)))
    if settings.mode != "router":
        # the wait of zenoh.open only: a session that lost its router retries forever either way
        timeout = settings.connect_timeout_s
        config.insert_json5("connect/timeout_ms", "-1" if timeout is None else str(max(1, round(timeout * 1e3))))
        config.insert_json5("connect/exit_on_failure", "false")
        config.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 1.5}),
        )
    for key, value in settings.extra.items():
        config.insert_json5(key, json.dumps(value))
    return config


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
_WAIT_SLICE_S = 0.05


def _open_masked(config: zenoh.Config) -> zenoh.Session:
    """zenoh.open with SIGINT/SIGTERM blocked in the calling thread, so the threads Zenoh starts
    inherit the mask and these signals always reach the main thread (whose Python handler
    could otherwise wait forever while a Zenoh thread takes the signal)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
    try:
        return zenoh.open(config)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _Opening:
    """One zenoh.open on a helper thread; a session that arrives after its caller left (a
    signal, ``stop``) is closed there."""

    def __init__(self, config: zenoh.Config):
        self.done = threading.Event()
        self.session: zenoh.Session | None = None
        self.error: BaseException | None = None
        self._lock = threading.Lock()
        self._abandoned = False
        threading.Thread(target=self._open, args=(config,), name="zenoh-open", daemon=True).start()

    def _open(self, config: zenoh.Config) -> None:
        try:
            session = _open_masked(config)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            self.error = exc
            self.done.set()
            return
        with self._lock:
            if not self._abandoned:
                self.session = session
                self.done.set()
                return
        session.close()

    def abandon(self) -> None:
        with self._lock:
            self._abandoned = True


def open_session(settings: ZenohSettings, stop: threading.Event | None = None) -> zenoh.Session | None:
    """Open a session: a client or peer waits for its router (retrying) at most
    ``settings.connect_timeout_s`` (None: however long it takes).

    zenoh.open runs on a helper thread while this one waits in short slices, so that a signal
    handler runs at once: Ctrl-C raises KeyboardInterrupt here, or sets ``stop`` (whose setting
    ends the wait: the result is then None and the caller should exit).

    Raises
    ------
    ConnectError if no router answered in time; zenoh.ZError for other failures (a ``listen``
    port in use, refused credentials, a bad setting).
    """
    opening = _Opening(build_config(settings))
    try:
        while not opening.done.wait(_WAIT_SLICE_S):
            if stop is not None and stop.is_set():
                opening.abandon()
                return None
    except BaseException:
        opening.abandon()
        raise
    if opening.error is not None:
        if (isinstance(opening.error, zenoh.ZError) and settings.connect_timeout_s is not None
                and "Unable to connect" in str(opening.error)):
            raise ConnectError(settings) from None
        raise opening.error
    return opening.session


HOST_PORT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
"""Zenoh link protocols whose address is ``HOST:PORT``."""
PATH_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
"""Zenoh link protocols whose address is a path or device name."""


def parse_port(text: str, what: str, allow_zero: bool = False) -> int:
    """The port number of ``text`` (1..65535, or 0 with ``allow_zero``); ValueError naming ``what``."""
    low = 0 if allow_zero else 1
    if not text.isdigit() or not low <= int(text) <= 65535:
        raise ValueError(f"{what}: the port must be a number in {low}..65535, got {text!r}")
    return int(text)


def split_host_port(text: str, what: str, allow_zero: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); ValueError naming ``what`` otherwise."""
    host, colon, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not colon or not host or any(c in host for c in "/ []") or (":" in host and not text.startswith("[")):
        raise ValueError(f"{what}: expected HOST:PORT, got {text!r}")
    return host, parse_port(port, what, allow_zero)


def check_endpoint(endpoint: str, flag: str = "--connect", listen: bool = False) -> str:
    """``endpoint`` if it is a Zenoh endpoint ``PROTOCOL/ADDRESS`` (``tcp/HOST:PORT``, ``tls/...``,
    ``unixsock-stream/PATH``; ``?metadata`` and ``#config`` after it pass through), else
    ValueError in one sentence naming ``flag`` (a listening endpoint may take port 0)."""
    protocol, slash, rest = endpoint.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    what = f"{flag} {endpoint}"
    if not slash or protocol not in HOST_PORT_PROTOCOLS + PATH_PROTOCOLS:
        raise ValueError(f"{what}: expected a Zenoh endpoint PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447 "
                         f"(protocols: {', '.join(HOST_PORT_PROTOCOLS + PATH_PROTOCOLS)})")
    if protocol in HOST_PORT_PROTOCOLS:
        split_host_port(address, what, allow_zero=listen)
    elif not address:
        raise ValueError(f"{what}: expected {protocol}/PATH")
    return endpoint


def split_list(value: str) -> tuple[str, ...]:
    """``"a, b,,c"`` -> ``("a", "b", "c")``: endpoints as flags and variables give them."""
    return tuple(e.strip() for e in value.split(",") if e.strip())


def read_extra(path: str) -> dict:
    """The ``{"config/path": value}`` object of a JSON file of extra Zenoh settings; ValueError
    naming the file if it cannot be read or is not one."""
    try:
        with open(path) as f:
            extra = json.load(f)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    if not isinstance(extra, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return extra


def part_session(settings: ZenohSettings, stop: threading.Event | None = None
                 ) -> tuple[threading.Event, zenoh.Session | None]:
    """What a long-running part starts with: its stop event (``stop``, else a new one; set by
    SIGINT and SIGTERM) and its session, opened once its router answers (None: stopped first)."""
    stop = stop_on_signals(stop)
    return stop, open_session(settings, stop)


def settings(mode: str = "client", connect: str = "", listen: str = "", config_file: str = "",
             connect_timeout_s: float | None = None) -> ZenohSettings:
    """ZenohSettings of a mode, comma-separated endpoints, a JSON file of extra settings (key ->
    value; "": none) and the bound on the wait for a router (None or 0: however long it takes);
    ValueError naming a bad endpoint (:func:`check_endpoint`), or the file when it cannot be read
    or holds no JSON object."""
    for flag, endpoints in (("--connect", connect), ("--listen", listen)):
        for endpoint in split_list(endpoints):
            check_endpoint(endpoint, flag, listen=flag == "--listen")
    try:
        extra = read_extra(config_file) if config_file else {}
    except ValueError as exc:
        raise ValueError(f"--zenoh-config {exc}") from None
    return ZenohSettings(mode=mode, connect=split_list(connect), listen=split_list(listen), extra=extra,
                         connect_timeout_s=connect_timeout_s or None)
