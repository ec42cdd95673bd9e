"""Motion feeds: what each subject's IMUs measure at sample k, where this process stands in for
the IMUs (emulated devices; a device on a serial link fed its motion).

A feed turns a motion source into a sample stream on a uniform grid at the device rate:
files are resampled (SLERP) to that rate and looped, or played once (a stream of
``length`` samples); the built-in generator is endless, produced chunk by chunk,
continuous across chunks.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from limbstream import quat
from limbstream.body import PAPER10, Body, Layout, builtin_layout
from limbstream.sources import Motion
from limbstream.sources.generator import GeneratorSource


def resample(motion: Motion, fs: float) -> Motion:
    """The motion on a uniform grid at ``fs`` Hz from its first sample (SLERP per segment)."""
    if abs(motion.fs - fs) < 1e-6 * fs and np.allclose(np.diff(motion.t), 1.0 / fs, rtol=1e-6, atol=1e-9):
        return motion
    t = motion.t[0] + np.arange(int(np.floor((motion.t[-1] - motion.t[0]) * fs)) + 1) / fs
    q = np.stack([quat.interpolate(motion.t, motion.q[:, s], t) for s in range(motion.q.shape[1])], axis=1)
    root = None if motion.root is None else np.stack([np.interp(t, motion.t, r) for r in motion.root.T], axis=1)
    return dataclasses.replace(motion, t=t, q=q, root=root)


class LoopFeed:
    """A recorded motion at ``fs``, replayed in a loop (``once``: a finite stream).

    Parameters
    ----------
    motion : Motion
    fs : float, device rate, Hz.
    once : bool, end after one pass instead of looping: ``length`` is then the number of
        samples of the stream (the resampled clip's), else None.
    start : where in the clip the stream begins, a fraction of it in [0, 1) (a pass still plays
        the whole clip, wrapping round).
    """

    def __init__(self, motion: Motion, fs: float, once: bool = False, start: float = 0.0):
        self.motion = resample(motion, fs)
        self.q = self.motion.q.astype(np.float32)  # (m, S, 4), shared by the feeds starting_at other places
        self.offset = _start_sample(start, len(self.q))
        self.segments = self.motion.segments
        self.rest_pose = self.motion.rest_pose
        self.orientations = self.motion.orientations  # wire.ORIENTATIONS
        self.body = self.motion.body  # its wearer's dimensions (None: the default adult), its devices announce
        self.length = len(self.q) if once else None

    def starting_at(self, start: float) -> LoopFeed:
        """The same clip ``start`` (a fraction, as the constructor's) into it, its arrays shared: the
        feeds of many subjects of one clip hold it once."""
        feed = copy.copy(self)
        feed.offset = _start_sample(start, len(self.q))
        return feed

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) float32 orientations at sample k; IndexError past the end of a finite stream."""
        if self.length is not None and not 0 <= k < self.length:
            raise IndexError(f"sample {k} of a {self.length}-sample stream ({self.motion.name})")
        return self.q[(k + self.offset) % len(self.q)]


def _start_sample(start: float, samples: int) -> int:
    """The sample ``start`` (a fraction in [0, 1)) into a clip of ``samples``; ValueError otherwise."""
    if not 0.0 <= start < 1.0:
        raise ValueError(f"start must be in [0, 1), got {start}")
    return int(start * samples)


class GeneratorFeed:
    """The built-in synthetic motion of one subject, generated in chunks as time goes on: the
    segments of ``layout`` (a built-in's name or a Layout, :class:`GeneratorSource`).

    Chunk boundaries are staggered by seed, so many subjects in one process do not all
    generate their next chunk on the same tick. Its ``body`` (which its devices announce;
    ``limbstream emulate --height-m`` sets another): paper10's None (the default adult, drawn with
    the aggregator's skeleton), another layout's default body (it names the layout; a layout file's
    travels whole), None for a layout file that gives no height fraction for a bone.
    """

    CHUNK_S = 10.0
    rest_pose = "standing"
    orientations = "segments"  # wire.ORIENTATIONS: the generated segments' own

    def __init__(self, seed: int, fs: float, noise_deg: float = 0.0, layout: str | Layout = "paper10"):
        self.source = GeneratorSource(seed=seed, fs=fs, noise_deg=noise_deg, layout=layout)
        self.segments = self.source.segments
        lay = builtin_layout(layout) if isinstance(layout, str) else layout
        self.body: Body | None = None if lay == PAPER10 else _default_body(lay)
        self.chunk_len = int(round(self.CHUNK_S * fs))
        self.offset = (seed * 7919) % self.chunk_len
        self.length = None
        self._start = 0
        self._chunk = np.zeros((0, len(self.segments), 4), np.float32)

    def chunk_at(self, k: int) -> tuple[int, np.ndarray]:
        """(its first sample, (n, S, 4) float32) the chunk that holds sample k (generated when k
        is not in the current one)."""
        if not 0 <= k - self._start < len(self._chunk):
            c = (k + self.offset) // self.chunk_len
            self._start = max(0, c * self.chunk_len - self.offset)
            end = (c + 1) * self.chunk_len - self.offset
            self._chunk = self.source.chunk(self._start, end - self._start)[1].astype(np.float32)
        return self._start, self._chunk

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) float32 orientations at sample k."""
        start, chunk = self.chunk_at(k)
        return chunk[k - start]


def _default_body(layout: Layout) -> Body | None:
    """``layout``'s default body (None: it gives no height fraction for a bone)."""
    try:
        return Body.default(layout)
    except ValueError:
        return None


class FeedRows:
    """Sample k of each of several feeds, stacked: one tick's values of all their devices.

    The built-in generator's feeds (their chunks all of one length L) are read from one ring of
    their current chunks by sample: row k % L holds sample k of every one of them (each chunk
    written there when it is made), so a tick reads one contiguous row; other feeds one by one. A
    finite feed holds its last sample past its end.

    Parameters
    ----------
    feeds : list of feeds, in the order of their rows.
    """

    def __init__(self, feeds: list):
        self.feeds = feeds
        self._first = np.cumsum([0] + [len(f.segments) for f in feeds])  # feed i's rows: first[i] .. first[i + 1]
        gen = [i for i, f in enumerate(feeds) if isinstance(f, GeneratorFeed)]
        shapes = {(feeds[i].chunk_len, len(feeds[i].segments)) for i in gen}
        if len(shapes) != 1:  # none, or chunks of different shapes: every feed one by one
            gen, shapes = [], {(0, 0)}
        chunk_len, segments = shapes.pop()
        self._gen = np.array(gen, np.int64)
        self._segments = segments
        self._ring = np.zeros((chunk_len, len(gen) * segments, 4), np.float32)  # row k % L: their samples k
        self._start = np.zeros(len(gen), np.int64)  # the first sample of each one's current chunk
        self._len = np.zeros(len(gen), np.int64)    # its samples (0: none yet)
        self._gen_rows = (self._first[self._gen][:, None] + np.arange(segments)).ravel()
        self._others = [i for i in range(len(feeds)) if i not in set(gen)]

    def rows(self, k: int, count: int) -> np.ndarray:
        """(rows of the first ``count`` feeds, 4) float32: each one's sample k."""
        out = np.empty((self._first[count], 4), np.float32)
        gen = np.searchsorted(self._gen, count)  # generator feeds among the first count
        if gen:
            i = k - self._start[:gen]
            ring, width = self._ring, self._segments
            for g in np.flatnonzero((i < 0) | (i >= self._len[:gen])).tolist():
                start, chunk = self.feeds[self._gen[g]].chunk_at(k)
                ring[np.arange(start, start + len(chunk)) % len(ring), g * width:(g + 1) * width] = chunk
                self._start[g], self._len[g] = start, len(chunk)
            out[self._gen_rows[:gen * width]] = ring[k % len(ring), :gen * width]
        for f in self._others:
            if f < count:
                feed = self.feeds[f]
                out[self._first[f]:self._first[f + 1]] = feed.sample(k if feed.length is None else min(k, feed.length - 1))
        return out
