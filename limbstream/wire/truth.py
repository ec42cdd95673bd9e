"""Subject truth tap: the truth-tap batches of several devices of one subject in one message.

A device host that samples all of a subject's devices together (the emulator) sends one message
per subject and batch on ``limbstream/<subject>/truth`` instead of one per device on each
``limbstream/<subject>/<segment>/raw``. Each entry names its device's segment and holds that
device's batch exactly as its own ``raw`` key would carry it (:mod:`.raw`, any version), so a
receiver splits the message (:func:`decode_truth`) and takes the batches in as if they had come
one by one. Layout (docs/protocol.md, "Subject truth tap"): u8 version, u8 flags, u16 count,
then count x (u8 segment length L, L bytes segment name, u32 batch size B, B bytes batch).
"""
from __future__ import annotations

import re
import struct
from collections.abc import Sequence

from .errors import WireError
from .keys import CHUNK_PATTERN, TRUTH, parse_subject_key, raw_key

TRUTH_VERSION = 1
"""Format version of a subject truth-tap message."""
_HEADER = struct.Struct("<BBH")     # version, flags, count
_SIZE = struct.Struct("<I")         # an entry's batch size
_NAME = re.compile(CHUNK_PATTERN)
MAX_TRUTH_ENTRIES = 1024
"""Most device batches one message may hold."""


def encode_truth(segments: Sequence[str], batches: Sequence[bytes]) -> bytes:
    """The batches (encoded truth-tap batches, ``wire.encode_raw``) of the devices ``segments``
    of one subject -> one subject truth-tap message. ValueError on no entries, a segment that is
    not a key chunk, or one named twice."""
    if not 0 < len(segments) == len(batches) <= MAX_TRUTH_ENTRIES:
        raise ValueError(f"a truth message holds 1..{MAX_TRUTH_ENTRIES} batches, one per segment; got "
                         f"{len(batches)} batches of {len(segments)} segments")
    if len(set(segments)) != len(segments):
        raise ValueError(f"a truth message names each segment once, got {list(segments)}")
    parts = [_HEADER.pack(TRUTH_VERSION, 0, len(segments))]
    for segment, batch in zip(segments, batches):
        name = segment.encode("ascii") if _NAME.fullmatch(segment) and len(segment) < 256 else None
        if name is None:
            raise ValueError(f"segment must be a key chunk of at most 255 characters, got {segment!r}")
        parts += [bytes((len(name),)), name, _SIZE.pack(len(batch)), batch]
    return b"".join(parts)


def decode_truth(payload: bytes) -> list[tuple[str, bytes]]:
    """A subject truth-tap message -> [(segment, its batch's bytes)], in order (the batches are
    decoded as a device's ``raw`` messages are: ``wire.decode_raws``). WireError with reason
    ``size`` (shorter than its header or an entry, no entries or more than
    :data:`MAX_TRUTH_ENTRIES`, or bytes left over), ``version``,
    ``segment`` (a name that is not a key chunk, or one named twice)."""
    if len(payload) < _HEADER.size:
        raise WireError("size", f"truth message has {len(payload)} bytes, less than its header")
    version, _, count = _HEADER.unpack_from(payload)
    if version != TRUTH_VERSION:
        raise WireError("version", f"truth message version {version}, expected {TRUTH_VERSION}")
    if not 0 < count <= MAX_TRUTH_ENTRIES:
        raise WireError("size", f"truth message holds {count} batches, expected 1..{MAX_TRUTH_ENTRIES}")
    entries: list[tuple[str, bytes]] = []
    at = _HEADER.size
    view = memoryview(payload)
    for _ in range(count):
        if at >= len(payload) or at + 1 + payload[at] + _SIZE.size > len(payload):
            raise WireError("size", f"truth message ends inside entry {len(entries)} of {count}")
        n = payload[at]
        name = bytes(view[at + 1:at + 1 + n])
        (size,) = _SIZE.unpack_from(payload, at + 1 + n)
        at += 1 + n + _SIZE.size
        if at + size > len(payload):
            raise WireError("size", f"truth message ends inside entry {len(entries)} of {count}")
        if not name.isascii() or not _NAME.fullmatch(segment := name.decode("ascii")):
            raise WireError("segment", f"truth message entry {len(entries)} names no segment: {name!r}")
        entries.append((segment, bytes(view[at:at + size])))
        at += size
    if at != len(payload):
        raise WireError("size", f"truth message has {len(payload) - at} bytes after its {count} batches")
    if len({segment for segment, _ in entries}) != count:
        raise WireError("segment", "truth message names a segment twice")
    return entries


def truth_batches(key: str, payload: bytes) -> list[tuple[str, bytes]]:
    """A subject truth-tap message as the device messages it stands for: [(the device's ``raw``
    key, its batch's bytes)]. WireError ``key`` when ``key`` is not a subject's ``truth`` key,
    else as :func:`decode_truth`."""
    subject, kind = parse_subject_key(key)
    if kind != TRUTH:
        raise WireError("key", f"not a truth key: {key!r}")
    return [(raw_key(subject, segment), batch) for segment, batch in decode_truth(payload)]
