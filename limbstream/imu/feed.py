"""A subject's ideal sensor readings by sample number: what emulated devices read, tick by tick.

A :class:`ReadingFeed` plays a motion source as devices would wear it, at the sensor rate:

- a recorded motion once, or looped: every pass is the calibration script (as
  :class:`limbstream.calibration.ScriptedFeed` plays it for modelled sensors: rest pose, mounting
  pose, the moves between them), the motion, then a move back to the rest pose where the next
  pass begins; the root (if the motion has one) stays where the motion starts during the script
  and where it ends during the move back, and each pass starts where the last one ended;
- the built-in generator, endless: the script, then the generator.

Readings are made in chunks of :data:`CHUNK_S` from the source's samples with :data:`MARGIN_S`
more on each side (smoothing and spline then agree with those of the whole stream to far below
the noise of any part), so a device asking for one sample reads what it would in a whole
recording. :func:`record` makes a whole :class:`~limbstream.sources.raw.RawRecording`.
"""
from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from limbstream import calibration, quat
from limbstream.body import PAPER10, Body
from limbstream.imu.devices import ImuDevices
from limbstream.imu.kinematics import Readings, SmoothMotion, readings, to_earth
from limbstream.skeleton import Skeleton
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource
from limbstream.sources.raw import RawRecording

CHUNK_S = 10.0
"""Readings computed at once, s of sensor time."""
MARGIN_S = 1.0
"""Source samples beyond a chunk's ends that make its readings those of the whole stream, s."""
GENERATOR_FS = 100.0
"""The rate the built-in generator is sampled at before it is smoothed and interpolated, Hz."""


def scripted(motion: Motion, back_to_rest: bool = False) -> Motion:
    """The calibration script, then ``motion`` (and, with ``back_to_rest``, a move back to the
    rest pose), at the motion's rate, t from 0; the root held still outside the motion.

    Raises
    ------
    ValueError if the motion is not sampled at a uniform rate (:func:`uniform_rate`).
    """
    fs = uniform_rate(motion)
    q, _, _ = calibration.with_script(motion.q, fs, motion.segments)
    before = len(q) - len(motion.t)
    parts, after = [q], 0
    if back_to_rest:
        after = _moves(fs)
        u = np.repeat((np.arange(1, after + 1) / (after + 1))[:, None], q.shape[1], axis=1)
        parts.append(quat.slerp(quat.normalize(q[-1:]), np.array([1.0, 0.0, 0.0, 0.0]), u))
    root = motion.root
    if root is not None:
        root = np.concatenate([np.repeat(root[:1], before, axis=0), root, np.repeat(root[-1:], after, axis=0)])
    q = np.concatenate(parts)
    return Motion(np.arange(len(q)) / fs, q, motion.segments, motion.name, motion.rest_pose, root)


def uniform_rate(motion: Motion) -> float:
    """The motion's sample rate, Hz; ValueError if its samples are not evenly spaced (a feed
    counts samples, and the script is played at the motion's rate)."""
    fs = motion.fs
    if len(motion.t) < 2 or not np.allclose(np.diff(motion.t), 1.0 / fs, rtol=1e-4):
        raise ValueError(f"motion {motion.name!r}: sensors are emulated from evenly spaced samples (resample it first)")
    return fs


def script_samples(fs: float) -> int:
    """Samples of the calibration script at ``fs`` Hz, before the motion's first."""
    return len(calibration.with_script(np.array([[[1.0, 0.0, 0.0, 0.0]]]), fs, ("hip",))[0]) - 1


def _moves(fs: float) -> int:
    """Samples of a move between poses at ``fs`` Hz (as in the calibration script)."""
    return max(1, round(calibration.MOVE_S * fs))


class ReadingFeed:
    """Ideal segment-frame readings of one subject's sensors at ``rate`` Hz, by sample number
    (sample ``k`` at ``k / rate`` s from the start of the stream).

    Parameters
    ----------
    source : a recorded Motion (uniform rate) or the built-in GeneratorSource (any ``fs``: it
        is sampled at :data:`GENERATOR_FS`).
    rate : sensor rate, Hz.
    once : play a recorded motion once (``length`` samples) instead of looping it.
    script : begin (every pass) with the calibration script.
    skeleton : bone lengths of the sensors' places.
    """

    def __init__(self, source: Motion | GeneratorSource, rate: float, once: bool = False, script: bool = True,
                 skeleton: Skeleton | None = None):
        if not rate > 0:
            raise ValueError(f"sensor rate must be > 0 Hz, got {rate}")
        self.rate, self.skeleton = float(rate), skeleton
        if isinstance(source, GeneratorSource):
            self._source: _Samples = _GeneratorSamples(source, script)
        else:
            self._source = _ClipSamples(source, loop=not once, script=script)
        self.segments, self.rest_pose = self._source.segments, self._source.rest_pose
        self.body = None if isinstance(source, GeneratorSource) else _layout_body(source)
        self.script_s = self._source.script_s
        span = self._source.span_s
        self.length = None if span is None else int(math.floor(span * self.rate + 1e-9)) + 1
        self._chunk_len = max(1, round(CHUNK_S * self.rate))
        self._chunks: dict[int, Readings] = {}

    def readings(self, k: np.ndarray) -> Readings:
        """Readings of sample numbers ``k`` (m,) (any order): t (m,), q (m, S, 4), gyr and acc
        (m, S, 3). IndexError past the end of a motion played once."""
        k = np.asarray(k, np.int64)
        if self.length is not None and len(k) and (k.min() < 0 or k.max() >= self.length):
            raise IndexError(f"samples {k.min()}..{k.max()} of a {self.length}-sample stream")
        chunk, row = np.divmod(k, self._chunk_len)
        width = {"q": 4, "gyr": 3, "acc": 3}
        out = {name: np.empty((len(k), len(self.segments), w)) for name, w in width.items()}
        for c in np.unique(chunk):
            here = chunk == c
            part = self._chunk(int(c))
            for name in out:
                out[name][here] = getattr(part, name)[row[here]]
        return Readings(k / self.rate, out["q"], out["gyr"], out["acc"], self.segments)

    def _chunk(self, c: int) -> Readings:
        """The readings of chunk ``c``'s samples, from the source around it (the two latest chunks
        are kept: the devices of a subject ask for nearby samples)."""
        if c not in self._chunks:
            fs = self._source.fs
            start = math.floor(c * self._chunk_len / self.rate * fs) - math.ceil(MARGIN_S * fs)
            count = math.ceil(self._chunk_len / self.rate * fs) + 2 * math.ceil(MARGIN_S * fs) + 2
            q, root = self._source.samples(start, count)
            motion = Motion((start + np.arange(count)) / fs, q, self.segments, rest_pose=self.rest_pose, root=root,
                            body=self.body)
            k = c * self._chunk_len + np.arange(self._chunk_len)
            if self.length is not None:
                k = k[k < self.length]
            self._chunks = {key: value for key, value in self._chunks.items() if key == c - 1}
            self._chunks[c] = readings(SmoothMotion(motion), k / self.rate, self.rate, self.skeleton)
        return self._chunks[c]


def _layout_body(motion: Motion) -> Body | None:
    """The body the sensors of ``motion`` are placed on (:func:`.kinematics.readings`): none for
    ``paper10`` (the :class:`Skeleton`'s) or a motion without a body of its own; else its layout's
    default body, as for a motion of a built-in layout without one (a layout file's segments name
    no built-in layout, so its body carries it), or its own where the layout gives no height
    fractions."""
    if motion.body is None or motion.body.layout == PAPER10:
        return None
    try:
        return Body.default(motion.body.layout)
    except ValueError:
        return motion.body


class _Samples(Protocol):
    """A motion source's samples at its rate ``fs``, by sample number (any, even negative)."""

    segments: tuple[str, ...]
    rest_pose: str
    fs: float
    span_s: float | None  # the stream's length, s (None: endless)
    script_s: float  # the calibration script before the motion, s

    def samples(self, start: int, count: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(count, S, 4) orientations and (count, 3) root positions (or None) of samples
        ``start .. start + count - 1``."""
        ...


class _ClipSamples:
    """A recorded motion's samples (after the script), looped or held at its ends."""

    def __init__(self, motion: Motion, loop: bool, script: bool):
        played = scripted(motion, back_to_rest=loop) if script else motion
        self.segments, self.rest_pose, self.fs = motion.segments, motion.rest_pose, uniform_rate(motion)
        self.script_s = script_samples(self.fs) / self.fs if script else 0.0
        self.q, self.root, self.loop = quat.continuous(played.q), played.root, loop
        self.span_s = None if loop else (len(self.q) - 1) / self.fs

    def samples(self, start: int, count: int) -> tuple[np.ndarray, np.ndarray | None]:
        i = np.arange(start, start + count)
        n = len(self.q)
        j = np.mod(i, n) if self.loop else np.clip(i, 0, n - 1)
        root = None
        if self.root is not None:
            root = self.root[j] + ((i // n)[:, None] * (self.root[-1] - self.root[0]) if self.loop else 0.0)
        return self.q[j], root


class _GeneratorSamples:
    """The built-in generator's noise-free orientations at :data:`GENERATOR_FS`, after the script
    (its own orientation noise is not a sensor's: the part's errors are added per device)."""

    def __init__(self, source: GeneratorSource, script: bool):
        self.source, self.segments, self.rest_pose = source, source.segments, "standing"
        self.fs = GENERATOR_FS
        self.span_s: float | None = None
        first = source.orientations(np.zeros(1))
        self.script = calibration.with_script(first, GENERATOR_FS, self.segments)[0][:-1] if script else first[:0]
        self.script_s = script_samples(self.fs) / self.fs if script else 0.0

    def samples(self, start: int, count: int) -> tuple[np.ndarray, None]:
        i = np.arange(start, start + count) - len(self.script)  # the generator's own sample numbers
        q = self.source.orientations(np.maximum(i, 0) / self.fs)
        early = i < 0
        if early.any() and len(self.script):
            q[early] = self.script[np.maximum(i[early] + len(self.script), 0)]
        return quat.continuous(q), None


def record(motion: Motion, devices: ImuDevices, script: bool = True, skeleton: Skeleton | None = None) -> RawRecording:
    """What ``devices`` (one per segment of ``motion``, in its order) read over the whole motion,
    played once (after the calibration script, by default).

    Returns
    -------
    RawRecording of the sensors named by their segments; ``truth`` their true orientations
    (segment and mounting) in the Z-up earth frame; ``movement`` the motion (not the script).
    """
    feed = ReadingFeed(motion, devices.rate, once=True, script=script, skeleton=skeleton)
    if devices.n != len(feed.segments):
        raise ValueError(f"{devices.n} devices for {len(feed.segments)} segments")
    assert feed.length is not None
    k = np.arange(feed.length)
    ideal = feed.readings(k)
    n, s = len(k), len(feed.segments)
    gyr, acc = devices.read(np.tile(np.arange(s), n), np.repeat(k, s), ideal.gyr.reshape(-1, 3), ideal.acc.reshape(-1, 3))
    truth = to_earth(quat.multiply(ideal.q, devices.mounting[None]))
    return RawRecording(ideal.t, gyr.reshape(n, s, 3), acc.reshape(n, s, 3), feed.segments, feed.segments,
                        truth=truth, movement=ideal.t >= feed.script_s - 1e-9, name=f"{motion.name} ({devices.model.name})")
