"""The recording file: what crosses the router, in MCAP (https://mcap.dev), written once here
and read back by replay and export. Layout in docs/outputs.md.

One channel per key kind (:data:`TOPICS`); each message is an envelope of the key and the wire
bytes as they came (:func:`envelope`), logged at its receive time. Exact pose frames are also
written as ``foxglove.SceneUpdate`` skeletons on ``/<subject>/skeleton`` (:func:`skeleton_topic`,
the topic ``limbstream foxglove`` uses live), so the Foxglove app draws the bodies straight from
the file.

Writing is chunked (zstd) and :meth:`RecordingWriter.flush` ends the chunk in progress and
hands it to the OS: a writer killed at any moment leaves a file readable up to its last
flushed chunk (:class:`Recording` reads such a file and says so).
"""
from __future__ import annotations

import os
import struct
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, DataEnd, Footer, Header, Message, Metadata
from mcap.stream_reader import StreamReader

from limbstream import wire

KINDS: tuple[str, ...] = (wire.SEG, wire.RAW, wire.POSE, wire.STATS, wire.CONFIG, wire.ANGLES)
"""Key kinds a recording holds, one channel each."""
TOPICS: dict[str, str] = {kind: f"/limbstream/{kind}" for kind in KINDS}
"""MCAP topic of each kind."""
TOPIC_KINDS: dict[str, str] = {topic: kind for kind, topic in TOPICS.items()}
"""The kind of each MCAP topic."""


def skeleton_topic(subject: str) -> str:
    """Topic of a subject's foxglove.SceneUpdate skeletons (one per exact pose frame)."""
    return f"/{subject}/skeleton"

MESSAGE_ENCODING = "limbstream"
"""Message encoding of the :data:`TOPICS` channels: :func:`envelope`."""
PROFILE = "limbstream"
METADATA_NAME = "limbstream"
"""Name of the metadata record with the recorder's settings."""

_PAYLOADS = {
    "seg": "segment point, 36 bytes (docs/protocol.md: Segment point)",
    "raw": "truth-tap batch (docs/protocol.md: Truth tap)",
    "pose": "pose frame, exact or live, the subject's layout (docs/protocol.md: Pose frame)",
    "stats": "stats message of one subject, compact or JSON form (docs/protocol.md: Stats)",
    "config": "device status JSON, a config query's reply (docs/protocol.md: Device config)",
    "angles": "joint angles of a pose frame, 115 bytes (docs/protocol.md: Joint angles)",
}
SCHEMAS: dict[str, tuple[str, bytes]] = {
    kind: (f"limbstream.{kind}",
           (f"limbstream envelope v1: u16 little-endian key length, the Zenoh key (UTF-8), then the "
            f"payload: {text}. log_time: receive time, ns since the Unix epoch.").encode())
    for kind, text in _PAYLOADS.items()
}
"""Schema (name, data) of each kind: the data is the layout in words (schema encoding
:data:`MESSAGE_ENCODING`)."""

_LEN = struct.Struct("<H")


class RecordingError(ValueError):
    """A recording that cannot be written or read; the message names the file (one line)."""


def envelope(key: str, payload: bytes) -> bytes:
    """The message data of a :data:`TOPICS` channel: u16 key length, key, payload."""
    raw = key.encode()
    return _LEN.pack(len(raw)) + raw + payload


def open_envelope(data: bytes) -> tuple[str, bytes]:
    """(key, payload) of an envelope; WireError('envelope') if it is not one."""
    if len(data) < _LEN.size:
        raise wire.WireError("envelope", f"message of {len(data)} bytes has no key length")
    n = _LEN.unpack_from(data)[0]
    if len(data) < _LEN.size + n:
        raise wire.WireError("envelope", f"key of {n} bytes does not fit a {len(data)}-byte message")
    try:
        key = bytes(data[_LEN.size:_LEN.size + n]).decode()
    except UnicodeDecodeError:
        raise wire.WireError("envelope", "key is not UTF-8") from None
    return key, bytes(data[_LEN.size + n:])


# ----------------------------------------------------------------------------- writing


class RecordingWriter:
    """Writes a recording, with the Foxglove SDK's MCAP writer (its chunking, zstd compression and
    protobuf encoding run in native code: about 1 µs per message).

    Parameters
    ----------
    path : output file (created or replaced).
    metadata : string pairs stored in the ``limbstream`` metadata record (settings, host, ...).
    chunk_size : uncompressed bytes per chunk at most (a chunk also ends at every :meth:`flush`).
    skeleton : also write exact pose frames as Foxglove skeletons.

    Raises RecordingError naming ``path`` if it cannot be created.
    """

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None, chunk_size: int = 1 << 20,
                 skeleton: bool = True):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.path = Path(path)
        try:
            open(self.path, "wb").close()  # a clear error for an unwritable path
        except OSError as exc:
            raise RecordingError(f"{path}: cannot write ({exc.strerror or exc})") from None
        self._context = foxglove.Context()  # this file's channels only
        # no message index records: 16 uncompressed bytes per message (a third of a segment point's
        # stored size); readers find their way through the chunk index and the chunks themselves
        options = MCAPWriteOptions(profile=PROFILE, chunk_size=chunk_size, compression=MCAPCompression.Zstd,
                                   emit_message_indexes=False)
        self._mcap = foxglove.open_mcap(self.path, allow_overwrite=True, context=self._context,
                                        writer_options=options)
        self._mcap.write_metadata(METADATA_NAME, {"wire_version": str(wire.VERSION), **(metadata or {})})
        self.channels = {
            kind: foxglove.Channel(TOPICS[kind], message_encoding=MESSAGE_ENCODING, context=self._context,
                                   schema=foxglove.Schema(name=SCHEMAS[kind][0], encoding=MESSAGE_ENCODING,
                                                          data=SCHEMAS[kind][1]))
            for kind in KINDS
        }
        self._fox = None
        if skeleton:
            from limbstream.services.outputs import foxglove as fox

            self._fox = fox
        self._skeletons: dict[str, tuple] = {}  # subject -> (channel, slot, where a frame without a root is drawn)
        self._prefixes: dict[str, bytes] = {}
        self._poses: dict[str, object] = {}  # subject -> where its skeleton is drawn
        self.counts: Counter = Counter()
        self.closed = False

    def add(self, kind: str, key: str, payload: bytes, log_ns: int) -> None:
        """One message of ``kind`` (see :data:`KINDS`) received on ``key`` at ``log_ns`` (ns since the Unix epoch)."""
        prefix = self._prefixes.get(key)
        if prefix is None:
            raw = key.encode()
            prefix = self._prefixes[key] = _LEN.pack(len(raw)) + raw
        self.channels[kind].log(prefix + payload, log_time=log_ns)
        self.counts[kind] += 1

    def add_skeleton(self, subject: str, frame: wire.PoseFrame, log_ns: int) -> None:
        """``frame`` of ``subject`` as a foxglove.SceneUpdate on :func:`skeleton_topic`, built as
        ``limbstream foxglove`` builds it (``limbstream.services.outputs.foxglove.scene_update``), in frame
        ``world``, placed as that output places subjects: the n-th subject seen here (from 0) in
        slot n, at each frame's root where it carries one."""
        if self._fox is None:
            return
        known = self._skeletons.get(subject)
        if known is None:
            from foxglove.channels import SceneUpdateChannel

            slot = len(self._skeletons)
            known = self._skeletons[subject] = (SceneUpdateChannel(skeleton_topic(subject), context=self._context),
                                                slot, self._fox.placement(slot, self._fox.leg_m(frame)))
        channel, slot, where = known
        if frame.has_root:
            where = self._fox.placement(slot, root=frame.root)
        channel.log(self._fox.scene_update(subject, frame, where), log_time=log_ns)
        self.counts["skeleton"] += 1

    def flush(self) -> None:
        """End the chunk in progress and hand everything to the OS (survives a SIGKILL)."""
        self._mcap.flush()

    @property
    def size(self) -> int:
        """Bytes in the file so far."""
        try:
            return self.path.stat().st_size
        except OSError:
            return 0

    def discard(self) -> None:
        """Close and delete the file (nothing was recorded)."""
        self.close()
        self.path.unlink(missing_ok=True)

    def close(self) -> None:
        """Write the indexes and summary and close the file."""
        if not self.closed:
            self.closed = True
            self._mcap.close()


# ----------------------------------------------------------------------------- reading


class Entry(NamedTuple):
    """One recorded message of a :data:`TOPICS` channel.

    Attributes: kind, key (the Zenoh key), payload (wire bytes), log_ns (receive time, ns since
    the Unix epoch).
    """

    kind: str
    key: str
    payload: bytes
    log_ns: int


@dataclass
class Recording:
    """A recording opened for reading (nothing is read before :meth:`entries`).

    Parameters
    ----------
    path : the MCAP file.

    Attributes (known once :meth:`entries` has run to its end)
    ----------
    metadata : the ``limbstream`` metadata record.
    truncated : why the file ends early (no summary: the writer was killed, or the file was
        cut), or "" for a properly closed file. Everything before that point was read.
    bad : envelopes that could not be opened, by kind.
    """

    path: Path
    metadata: dict = field(default_factory=dict)
    truncated: str = ""
    bad: Counter = field(default_factory=Counter)

    def __post_init__(self):
        self.path = Path(self.path)
        if not self.path.is_file():
            raise RecordingError(f"{self.path}: no such file")
        try:
            with open(self.path, "rb") as f:
                magic = f.read(8)
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot read ({exc.strerror or exc})") from None
        if magic != b"\x89MCAP0\r\n":
            raise RecordingError(f"{self.path}: not an MCAP file")

    def check(self) -> None:
        """RecordingError unless the file holds a limbstream channel (reads up to the first one)."""
        for _ in self.entries((), until_channel=True):
            pass

    def entries(self, kinds: Iterable[str] = KINDS, until_channel: bool = False) -> Iterator[Entry]:
        """The messages of ``kinds`` in file order (= receive order). RecordingError if the file
        is not a limbstream recording or holds no complete chunk; a file that ends early ends
        the iteration (see :attr:`truncated`). ``until_channel``: stop at the first limbstream
        channel (:meth:`check`)."""
        wanted = set(kinds)
        channels: dict[int, str] = {}  # channel id -> kind, for limbstream channels
        foreign: set[str] = set()
        ended = False
        with open(self.path, "rb") as f:
            for record in self._records(f):
                if record is None or isinstance(record, DataEnd | Footer):
                    ended = True
                    break
                if isinstance(record, Message):
                    entry = self._entry(record, channels.get(record.channel_id), wanted)
                    if entry is not None:
                        yield entry
                elif isinstance(record, Channel):
                    if record.topic in TOPIC_KINDS and record.message_encoding == MESSAGE_ENCODING:
                        channels[record.id] = TOPIC_KINDS[record.topic]
                        if until_channel:
                            return
                    elif not record.topic.endswith("/skeleton"):
                        foreign.add(record.topic)
                elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                    self.metadata = dict(record.metadata)
                elif isinstance(record, Header) and record.profile not in (PROFILE, ""):
                    foreign.add(f"profile {record.profile!r}")
        self._found(bool(channels), foreign, ended)

    def _records(self, f) -> Iterator[object]:
        """The records of the open file ``f`` in order, then None at the end of its records; a file
        cut between two records (the writer stopped there) or inside one (:attr:`truncated`) just
        stops."""
        records = StreamReader(f, record_size_limit=1 << 30).records
        while True:
            at = f.tell()  # where the next record starts (or records of a chunk already read)
            try:
                record = next(records)
            except StopIteration:
                yield None
                return
            except (McapError, struct.error, ValueError, EOFError) as exc:
                if not (at >= os.fstat(f.fileno()).st_size and isinstance(exc, EndOfFile)):
                    self.truncated = (f"cut inside a record at byte {at} "
                                      f"({type(exc).__name__}{': ' + str(exc) if str(exc) else ''})")
                return
            yield record

    def _entry(self, record: Message, kind: str | None, wanted: set[str]) -> Entry | None:
        """The entry of a message on a limbstream channel of a wanted kind (a bad envelope is counted)."""
        if kind is None or kind not in wanted:
            return None
        try:
            key, payload = open_envelope(record.data)
        except wire.WireError:
            self.bad[kind] += 1
            return None
        return Entry(kind, key, payload, record.log_time)

    def _found(self, limbstream: bool, foreign: set[str], ended: bool) -> None:
        """After reading: RecordingError if no limbstream channel was found (a foreign recording,
        or one cut before its first complete chunk); else note a file the recorder did not close."""
        if not limbstream:
            if foreign:
                raise RecordingError(f"{self.path}: not a limbstream recording: no {TOPICS['seg']} or other "
                                     f"limbstream channel (it holds {', '.join(sorted(foreign)[:5])})")
            if not ended:
                raise RecordingError(f"{self.path}: truncated before its first complete chunk"
                                     + (f" ({self.truncated})" if self.truncated else ""))
            raise RecordingError(f"{self.path}: not a limbstream recording: no limbstream channel")
        if not ended and not self.truncated:
            self.truncated = "no summary (the recorder did not close it)"


def now_ns() -> int:
    """Receive-time clock of recordings: ns since the Unix epoch."""
    return time.time_ns()
