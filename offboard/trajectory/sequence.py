"""Segments one after another in time.

A ``Sequence`` plays each segment for its duration, then the next, from the first segment's
start. It does not join them: if a segment starts somewhere other than where the previous one
ended, the reference jumps there, as the paper's does at t = 12 s (helix to the hold at 12 m)
and at t = 25 s (the step down to the ground). Mission files decide where each segment starts
(explicitly, or where the previous one ended); the sequence just keeps time.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence as SequenceABC

import numpy as np

from offboard.trajectory.base import Phase, Reference, Trajectory


class Sequence:
    """Concatenate trajectories in time.

    Parameters
    ----------
    segments : sequence of Trajectory
        Played in order; each for its ``duration_s``; at least one.
    """

    def __init__(self, segments: SequenceABC[Trajectory]) -> None:
        if not segments:
            raise ValueError("a sequence needs at least one segment")
        self.segments = tuple(segments)
        starts = np.concatenate([[0.0], np.cumsum([float(s.duration_s) for s in self.segments])])
        self.starts_s = tuple(float(t) for t in starts[:-1])
        self._duration_s = float(starts[-1])
        last = self.segments[-1].reference(self.segments[-1].duration_s)
        self._end = Reference(pos_ned_m=last.pos_ned_m, yaw_rad=last.yaw_rad)
        self._phases = [
            Phase(p.name, p.start_s + t0, p.end_s + t0, p.kind)
            for seg, t0 in zip(self.segments, self.starts_s)
            for p in seg.phases()
        ]

    @property
    def duration_s(self) -> float:
        """Sum of the segments' durations (s)."""
        return self._duration_s

    def phases(self) -> list[Phase]:
        """Every segment's phases, shifted to the sequence's time."""
        return list(self._phases)

    def reference(self, t_s: float) -> Reference:
        """The reference of the segment playing at ``t_s``; the final point after the end."""
        if t_s >= self._duration_s:
            return self._end
        k = bisect_right(self.starts_s, t_s) - 1
        if k < 0:
            return self.segments[0].reference(t_s)  # before the start: the segment holds its start
        return self.segments[k].reference(t_s - self.starts_s[k])

    def segment_at(self, t_s: float) -> int:
        """Index of the segment playing at ``t_s`` (clamped to the first and the last)."""
        return min(max(bisect_right(self.starts_s, t_s) - 1, 0), len(self.segments) - 1)

    def __repr__(self) -> str:
        return f"Sequence({len(self.segments)} segments, duration_s={self._duration_s:g})"
