"""Key expressions: the grammar of every key and selector, written once.

=====================================================  =========================  ==========
key                                                     payload                    publisher
=====================================================  =========================  ==========
``limbstream/<subject>/<segment>/seg``                  segment point              device
``limbstream/<subject>/<segment>/raw``                  truth-tap batch            device
``limbstream/<subject>/<segment>/alive``                liveliness token           device
``limbstream/<subject>/<segment>/config``               queryable: config/status   device
``limbstream/<subject>/pose``                           pose frame                 aggregator
``limbstream/<subject>/stats``                          stats (JSON on query)      aggregator
``limbstream/<subject>/angles``                         joint angles               aggregator
``limbstream/<subject>/calibrate``                      queryable: calibration     aggregator
``limbstream/<subject>/truth``                          subject truth tap          device host
``limbstream/@time``                                    queryable: time exchange   time service
``limbstream/@gateway/<gateway>``                       queryable: sensors/assign  gateway
=====================================================  =========================  ==========

``<subject>`` and ``<segment>`` are single chunks of letters, digits, ``_``, ``-`` and ``.``.
Selectors take a subject *pattern*: ``*``, a name, or a name with ``*`` inside (``s0*``).
The time key's ``@time`` is a verbatim chunk: only ``@time`` itself matches it (``*`` and ``**``
do not), so no subject can take its place and wildcard queryables never see time queries.
``@gateway`` is verbatim too: ``limbstream/@gateway/*`` reaches every gateway's queryable and no
subject or device selector reaches it.
"""
from __future__ import annotations

import re

from .errors import WireError

PREFIX = "limbstream"
SEG, RAW, ALIVE, CONFIG = "seg", "raw", "alive", "config"
"""The message kinds of a device: the last chunk of its keys."""
POSE, STATS, CALIBRATE, ANGLES, TRUTH = "pose", "stats", "calibrate", "angles", "truth"
"""The message kinds of a subject: the last chunk of its keys."""
DEVICE_KINDS: tuple[str, ...] = (SEG, RAW, ALIVE, CONFIG)
"""Last chunk of a device key."""
SUBJECT_KINDS: tuple[str, ...] = (POSE, STATS, CALIBRATE, ANGLES, TRUTH)
"""Last chunk of a subject key."""
TIME_CHUNK = "@time"
"""Second chunk of the time service's key (a verbatim chunk: wildcards never match it)."""
GATEWAY_CHUNK = "@gateway"
"""Second chunk of a gateway's key (verbatim, as the time key's)."""

CHUNK_PATTERN = r"^[A-Za-z0-9_.\-]+$"
"""A key chunk (subject or segment name): letters, digits, '_', '-', '.'."""
_CHUNK = re.compile(CHUNK_PATTERN)


def to_chunk(text: str) -> str:
    """``text`` with every character a key chunk does not allow replaced by ``-``."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "-", text)


def check_chunk(name: str, what: str = "name") -> str:
    """Return ``name`` if it is a valid single key chunk, else raise ValueError naming it."""
    if not isinstance(name, str) or not _CHUNK.match(name):
        raise ValueError(f"{what} must be a non-empty chunk of letters, digits, '_', '-', '.'; got {name!r}")
    return name


def device_id(subject: str, segment: str) -> str:
    """The device id ``<subject>/<segment>`` used in keys, stats and the REST API."""
    return f"{check_chunk(subject, 'subject')}/{check_chunk(segment, 'segment')}"


def split_device_id(did: str) -> tuple[str, str]:
    """``<subject>/<segment>`` -> (subject, segment); ValueError if it is not a device id."""
    subject, sep, segment = str(did).partition("/")
    if not sep:
        raise ValueError(f"device id must be <subject>/<segment>, got {did!r}")
    device_id(subject, segment)
    return subject, segment


def device_key(subject: str, segment: str, kind: str) -> str:
    """``limbstream/<subject>/<segment>/<kind>``, kind one of :data:`DEVICE_KINDS`."""
    if kind not in DEVICE_KINDS:
        raise ValueError(f"device key kind must be one of {DEVICE_KINDS}, got {kind!r}")
    return f"{PREFIX}/{device_id(subject, segment)}/{kind}"


def subject_key(subject: str, kind: str) -> str:
    """``limbstream/<subject>/<kind>``, kind one of :data:`SUBJECT_KINDS`."""
    if kind not in SUBJECT_KINDS:
        raise ValueError(f"subject key kind must be one of {SUBJECT_KINDS}, got {kind!r}")
    return f"{PREFIX}/{check_chunk(subject, 'subject')}/{kind}"


def seg_key(subject: str, segment: str) -> str:
    return device_key(subject, segment, SEG)


def raw_key(subject: str, segment: str) -> str:
    return device_key(subject, segment, RAW)


def alive_key(subject: str, segment: str) -> str:
    return device_key(subject, segment, ALIVE)


def config_key(subject: str, segment: str) -> str:
    return device_key(subject, segment, CONFIG)


def pose_key(subject: str) -> str:
    return subject_key(subject, POSE)


def stats_key(subject: str) -> str:
    return subject_key(subject, STATS)


def angles_key(subject: str) -> str:
    """``limbstream/<subject>/angles``: the subject's joint angles (:mod:`limbstream.wire.angles`)."""
    return subject_key(subject, ANGLES)


def truth_key(subject: str) -> str:
    """``limbstream/<subject>/truth``: the truth-tap batches of the subject's devices, one message
    per batch for all of them (:mod:`limbstream.wire.truth`)."""
    return subject_key(subject, TRUTH)


def calibrate_key(subject: str) -> str:
    """``limbstream/<subject>/calibrate``: the queryable of the aggregator serving the subject."""
    return subject_key(subject, CALIBRATE)


def history_selector(subject: str, segment: str, most: int, sn: tuple[int, int] | None = None) -> str:
    """A device's cached segment points (Zenoh's advanced publisher answers queries on
    ``<seg key>/@adv/**``): the newest ``most`` of them, or, with ``sn`` = (first, last), those
    its publisher sent with Zenoh's own sequence numbers first..last (``_sn``, inclusive)."""
    selector = f"{seg_key(subject, segment)}/@adv/**"
    if sn is None:
        return f"{selector}?_max={int(most)}"
    return f"{selector}?_sn={max(0, int(sn[0]))}..{int(sn[1])}"


def time_key() -> str:
    """``limbstream/@time``: the time service's queryable (docs/protocol.md, "Time exchange")."""
    return f"{PREFIX}/{TIME_CHUNK}"


def gateway_key(name: str) -> str:
    """``limbstream/@gateway/<name>``: the queryable of the gateway named ``name`` (its sensors
    and their assignment; docs/protocol.md, "SlimeVR gateway")."""
    return f"{PREFIX}/{GATEWAY_CHUNK}/{check_chunk(name, 'gateway name')}"


def gateway_selector() -> str:
    """Every gateway's queryable: ``limbstream/@gateway/*``."""
    return f"{PREFIX}/{GATEWAY_CHUNK}/*"


def parse_gateway_key(key: str) -> str:
    """``limbstream/@gateway/<name>`` -> name; WireError('key') otherwise."""
    parts = str(key).split("/")
    if len(parts) != 3 or parts[:2] != [PREFIX, GATEWAY_CHUNK] or not _CHUNK.match(parts[2]):
        raise WireError("key", f"not a gateway key: {key!r}")
    return parts[2]


def subject_pattern(text: str) -> str:
    """A user's subject pattern as a key chunk: ``*`` (all), a name, or a name with ``*``
    wildcards inside (``s0*`` becomes Zenoh's ``s0$*``). ValueError if it is neither."""
    text = str(text).strip()
    if text == "*":
        return text
    check_chunk(text.replace("*", "x"), "subject pattern")
    return text.replace("*", "$*")


def device_selector(kind: str, subjects: str = "*") -> str:
    """Every ``kind`` key of the devices of the subjects matched by ``subjects`` (a pattern,
    see :func:`subject_pattern`), e.g. ``limbstream/s0$*/*/seg``."""
    if kind not in DEVICE_KINDS:
        raise ValueError(f"device key kind must be one of {DEVICE_KINDS}, got {kind!r}")
    return f"{PREFIX}/{subject_pattern(subjects)}/*/{kind}"


def subject_selector(kind: str, subjects: str = "*") -> str:
    """Every ``kind`` key (``pose``, ``stats``, ...) of the subjects matched by ``subjects``."""
    if kind not in SUBJECT_KINDS:
        raise ValueError(f"subject key kind must be one of {SUBJECT_KINDS}, got {kind!r}")
    return f"{PREFIX}/{subject_pattern(subjects)}/{kind}"


def parse_device_key(key: str) -> tuple[str, str, str]:
    """``limbstream/<subject>/<segment>/<kind>`` -> (subject, segment, kind); WireError('key') otherwise."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != PREFIX or not all(_CHUNK.match(p) for p in parts[1:]):
        raise WireError("key", f"not a device key: {key!r}")
    return parts[1], parts[2], parts[3]


def parse_subject_key(key: str) -> tuple[str, str]:
    """``limbstream/<subject>/<kind>`` -> (subject, kind); WireError('key') otherwise."""
    parts = str(key).split("/")
    if len(parts) != 3 or parts[0] != PREFIX or not all(_CHUNK.match(p) for p in parts[1:]):
        raise WireError("key", f"not a subject key: {key!r}")
    return parts[1], parts[2]
