"""Motion feeds: what each subject's IMUs measure at sample k, where this process stands in for
the IMUs (emulated devices; a device on a serial link fed its motion).

A feed turns a motion source into a sample stream on a uniform grid at the device rate:
files are resampled (SLERP) to that rate and looped, or played once (a stream of
``length`` samples); the built-in generator is endless, produced chunk by chunk,
continuous across chunks.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from limbstream import quat
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
        if not 0.0 <= start < 1.0:
            raise ValueError(f"start must be in [0, 1), got {start}")
        self.motion = resample(motion, fs)
        self.q = np.roll(self.motion.q.astype(np.float32), -int(start * len(self.motion.q)), axis=0)
        self.segments = self.motion.segments
        self.rest_pose = self.motion.rest_pose
        self.orientations = self.motion.orientations  # wire.ORIENTATIONS
        self.length = len(self.q) if once else None

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) float32 orientations at sample k; IndexError past the end of a finite stream."""
        if self.length is not None and not 0 <= k < self.length:
            raise IndexError(f"sample {k} of a {self.length}-sample stream ({self.motion.name})")
        return self.q[k % len(self.q)]


class GeneratorFeed:
    """The built-in synthetic motion of one subject, generated in chunks as time goes on.

    Chunk boundaries are staggered by seed, so many subjects in one process do not all
    generate their next chunk on the same tick.
    """

    CHUNK_S = 10.0
    rest_pose = "standing"
    orientations = "segments"  # wire.ORIENTATIONS: the generated segments' own

    def __init__(self, seed: int, fs: float, noise_deg: float = 0.0):
        self.source = GeneratorSource(seed=seed, fs=fs, noise_deg=noise_deg)
        self.segments = self.source.segments
        self.chunk_len = int(round(self.CHUNK_S * fs))
        self.offset = (seed * 7919) % self.chunk_len
        self.length = None
        self._start = 0
        self._chunk = np.zeros((0, len(self.segments), 4), np.float32)

    def sample(self, k: int) -> np.ndarray:
        """(S, 4) float32 orientations at sample k."""
        i = k - self._start
        if not 0 <= i < len(self._chunk):
            c = (k + self.offset) // self.chunk_len
            self._start = max(0, c * self.chunk_len - self.offset)
            end = (c + 1) * self.chunk_len - self.offset
            self._chunk = self.source.chunk(self._start, end - self._start)[1].astype(np.float32)
            i = k - self._start
        return self._chunk[i]
