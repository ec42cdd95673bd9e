"""Full-body frames of one subject from its device tracks (DESIGN section 4).

Exact frames: on a fixed grid (multiples of the output period in device time), emitted once
every active device has a segment point at or after the frame time (the watermark), so the
SLERP reconstruction in them is final. A device that is offline or has ended its stream
does not hold the watermark back; its segment is held at its last point and the frame is
flagged MISSING. Live frames: at the newest device time seen, every segment held at its
newest point (a receiver's best guess "now"; its error is reported separately).
"""
from __future__ import annotations

import numpy as np

from limbstream import wire
from limbstream.skeleton import Skeleton
from limbstream.sources import SEGMENTS
from services.aggregator.track import DeviceTrack

MAX_FRAMES_PER_CALL = 500
"""Most exact frames one call builds (catch-up after recovery proceeds over several ticks)."""


class SubjectFusion:
    """Frame builder of one subject.

    Parameters
    ----------
    subject : its key chunk.
    rate : exact frame rate, Hz.
    skeleton : forward-kinematics model for the joint positions.
    """

    def __init__(self, subject: str, rate: float, skeleton: Skeleton):
        self.subject, self.skeleton = subject, skeleton
        self.period_us = 1e6 / rate
        self.tracks: dict[str, DeviceTrack] = {}
        self.next_frame: int | None = None  # grid index k of the next exact frame (t = k * period)
        self.exact_seq = 0
        self.live_seq = 0
        self.frames = 0
        self.skipped = 0

    def watermark(self) -> int | None:
        """Device time (us) up to which every frame is final, or None if nothing is known."""
        with_points = [t for t in self.tracks.values() if t.n]
        active = [t for t in with_points if t.online and not t.final]
        basis = active or with_points
        return min(t.watermark for t in basis) if basis else None

    def _frame_times(self, max_backlog_s: float) -> np.ndarray:
        wm = self.watermark()
        if wm is None:
            return np.zeros(0, np.int64)
        if self.next_frame is None:
            start = max(t.first_t for t in self.tracks.values() if t.n)
            self.next_frame = int(np.ceil(start / self.period_us))
        last = int(np.floor(wm / self.period_us))
        backlog = last - self.next_frame + 1
        limit = int(max_backlog_s * 1e6 / self.period_us)
        if backlog > limit:  # far behind (e.g. long outage): jump, count what is skipped
            self.skipped += backlog - limit
            self.next_frame = last - limit + 1
        count = max(0, min(last - self.next_frame + 1, MAX_FRAMES_PER_CALL))
        k = self.next_frame + np.arange(count)
        self.next_frame += count
        return np.round(k * self.period_us).astype(np.int64)

    def _orientations(self, t_us: np.ndarray, held: bool) -> tuple[np.ndarray, int]:
        """(F, 10, 4) orientations and the frame flags common to all F frames."""
        q = np.zeros((len(t_us), len(SEGMENTS), 4))
        q[..., 0] = 1.0
        flags = 0
        for s, name in enumerate(SEGMENTS):
            track = self.tracks.get(name)
            if track is None or not track.n:
                flags |= wire.FRAME_MISSING
                continue
            q[:, s] = track.held_at(t_us + 1) if held else track.orientation_at(t_us)
            if not track.online or (not held and track.watermark < t_us[-1]):
                flags |= wire.FRAME_MISSING
        return q, flags

    def exact_frames(self, max_backlog_s: float = 60.0) -> list[wire.PoseFrame]:
        """Every exact frame that became final since the last call (oldest first)."""
        t_us = self._frame_times(max_backlog_s)
        if len(t_us) == 0:
            return []
        q, flags = self._orientations(t_us, held=False)
        gap = np.zeros(len(t_us), bool)
        for track in self.tracks.values():
            if track.gap_spans:
                gap |= track.in_gap(t_us)
        joints = self.skeleton.positions(q)
        frames = []
        for i, t in enumerate(t_us):
            frames.append(wire.PoseFrame(self.exact_seq, int(t), wire.KIND_EXACT,
                                         flags | (wire.FRAME_GAP if gap[i] else 0), q[i], joints[i]))
            self.exact_seq += 1
        self.frames += len(frames)
        return frames

    def live_frame(self) -> wire.PoseFrame | None:
        """A frame at the newest device time seen, every segment held at its newest point."""
        latest = [t.latest_t_us for t in self.tracks.values() if t.latest_t_us is not None and t.n]
        if not latest:
            return None
        t_us = np.array([max(latest)], np.int64)
        q, flags = self._orientations(t_us, held=True)
        frame = wire.PoseFrame(self.live_seq, int(t_us[0]), wire.KIND_LIVE, flags, q[0],
                               self.skeleton.positions(q)[0])
        self.live_seq += 1
        return frame

    def prune(self) -> None:
        """Let every track forget points before the next exact frame."""
        if self.next_frame is not None:
            needed = int(self.next_frame * self.period_us)
            for track in self.tracks.values():
                track.prune(needed)
