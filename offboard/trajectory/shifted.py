"""A trajectory moved by a constant NED offset: a geo-referenced mission in the vehicle's frame.

A waypoint file's local frame is centred on its own home; the vehicle's on its HOME_POSITION's
local origin. ``offboard fly`` moves the mission by where its home lies in the vehicle's frame
(``offboard.missions.geo.mission_offset_ned``) and ``offboard replay`` moves it again by the same
offset, so the references compared with the flown path are the ones that were flown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from offboard.trajectory.base import Phase, Reference, Trajectory

#: Offsets smaller than this on every axis (m) leave the trajectory as it is.
MIN_SHIFT_M = 1e-3


@dataclass(frozen=True)
class ShiftedTrajectory:
    """``trajectory`` with every position moved by ``offset_ned_m`` (velocities, yaw unchanged)."""

    trajectory: Trajectory
    offset_ned_m: tuple[float, float, float]

    @property
    def duration_s(self) -> float:
        """The shifted trajectory's duration (unchanged), s."""
        return self.trajectory.duration_s

    def phases(self) -> list[Phase]:
        """The shifted trajectory's phases (unchanged)."""
        return self.trajectory.phases()

    def reference(self, t_s: float) -> Reference:
        """The reference at ``t_s``, its position moved by the offset."""
        r = self.trajectory.reference(t_s)
        return Reference(r.pos_ned_m + np.asarray(self.offset_ned_m), r.vel_ned_m_s, r.acc_ned_m_s2, r.yaw_rad, r.yaw_rate_rad_s)


def shift_trajectory(trajectory: Trajectory, offset_ned_m: tuple[float, float, float] | None) -> Trajectory:
    """``trajectory`` moved by ``offset_ned_m`` (NED, m); unchanged for None or an offset below
    ``MIN_SHIFT_M`` on every axis (the same rule for the flight and its replay)."""
    if offset_ned_m is None or max(abs(float(v)) for v in offset_ned_m) <= MIN_SHIFT_M:
        return trajectory
    north, east, down = (float(v) for v in offset_ned_m)
    return ShiftedTrajectory(trajectory, (north, east, down))
