"""Polygon flown at constant speed: piecewise linear, the velocity steps at every corner.

This is the paper's Simulation 3 reference (a square of side 5 m at 5 m height): "the problem
generated at corners are the sharp variations in reference, which cause large control errors"
(Section 4). For corners the vehicle can follow, use ``WaypointLegs`` instead.
"""

from __future__ import annotations

import enum
from bisect import bisect_right

import numpy as np
from numpy.typing import ArrayLike

from offboard.trajectory.base import PhaseKind, Reference
from offboard.trajectory.segment import LENGTH_EPS_M, Segment, YawMode, finite, heading_of, positive, vec3, wrap_pi

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


class FirstSide(enum.StrEnum):
    """Which way a square leaves its corner: ``north`` (then east, south, west: clockwise seen from
    above) or ``east`` (then north, west, south)."""

    NORTH = "north"
    EAST = "east"


class Polygon(Segment):
    """Visit vertices in order along straight sides at one constant speed.

    Parameters
    ----------
    vertices_ned_m : array_like, shape (n, 3)
        Corners, NED metres, n >= 2; consecutive vertices distinct. The path starts at the first.
    speed_m_s : float
        Speed along every side, > 0.
    closed : bool
        Return to the first vertex at the end.
    laps : int
        How many times the polygon is flown (>= 1; > 1 needs ``closed``).
    yaw_rad : float
        Heading for ``yaw_mode="fixed"``.
    yaw_mode : {"fixed", "along-path"}
        ``"along-path"``: each side's heading; the yaw steps at the corners like the velocity.
    name : str
    """

    def __init__(
        self,
        vertices_ned_m: ArrayLike,
        speed_m_s: float,
        closed: bool = True,
        laps: int = 1,
        yaw_rad: float = 0.0,
        yaw_mode: YawMode = YawMode.FIXED,
        name: str = "polygon",
    ) -> None:
        verts = np.array(vertices_ned_m, dtype=float)
        if verts.ndim != 2 or verts.shape[1] != 3 or verts.shape[0] < 2:
            raise ValueError(f"{name}: vertices_ned_m must be a list of at least 2 points of 3 numbers")
        if not np.all(np.isfinite(verts)):
            raise ValueError(f"{name}: vertices_ned_m must be finite")
        if int(laps) != laps or laps < 1:
            raise ValueError(f"{name}: laps must be an integer >= 1, got {laps}")
        if laps > 1 and not closed:
            raise ValueError(f"{name}: more than one lap needs a closed polygon")
        if yaw_mode not in (YawMode.FIXED, YawMode.ALONG_PATH):
            raise ValueError(f"{name}: yaw_mode must be 'fixed' or 'along-path', got {yaw_mode!r}")
        speed = positive(speed_m_s, "speed_m_s")
        path = np.vstack([verts, verts[:1]]) if closed else verts
        path = np.vstack([path] + [path[1:]] * (int(laps) - 1))
        deltas = np.diff(path, axis=0)
        lengths = np.linalg.norm(deltas, axis=1)
        if np.any(lengths < LENGTH_EPS_M):
            k = int(np.argmin(lengths))
            raise ValueError(f"{name}: vertices {k} and {k + 1} coincide")
        durations = lengths / speed
        starts = np.concatenate([[0.0], np.cumsum(durations)])
        super().__init__(float(starts[-1]), name, PhaseKind.TRACK)
        verts.setflags(write=False)
        self.vertices_ned_m = verts
        self.speed_m_s = speed
        self.length_m = float(lengths.sum())
        self._corners = [vec3(p, "vertex") for p in path[:-1]]
        self._end = vec3(path[-1], "vertex")
        self._vels = []
        for d, length in zip(deltas, lengths):
            v = d / length * speed
            v.setflags(write=False)
            self._vels.append(v)
        self._starts = starts[:-1].tolist()
        yaw = finite(yaw_rad, "yaw_rad")
        self._yaws: list[float] = []
        for d in deltas:
            heading = heading_of(d) if yaw_mode == YawMode.ALONG_PATH else None
            # unwrap against the previous side so the yaw steps by the turn, never by 2 pi
            yaw = yaw if heading is None else (heading if not self._yaws else yaw + wrap_pi(heading - yaw))
            self._yaws.append(yaw)

    def _evaluate(self, t_s: float) -> Reference:
        if t_s >= self.duration_s:
            return Reference(self._end, yaw_rad=self._yaws[-1])
        k = bisect_right(self._starts, t_s) - 1
        vel = self._vels[k]
        return Reference(self._corners[k] + vel * (t_s - self._starts[k]), vel, _ZERO3, self._yaws[k], 0.0)


def square(
    corner_ned_m: ArrayLike,
    side_m: float,
    speed_m_s: float,
    first_side: FirstSide = FirstSide.NORTH,
    laps: int = 1,
    yaw_rad: float = 0.0,
    yaw_mode: YawMode = YawMode.FIXED,
    name: str = "square",
) -> Polygon:
    """A horizontal square from ``corner_ned_m``, closed, at constant speed.

    ``first_side="north"`` flies north, east, south, west (clockwise seen from above): with
    the corner at the origin, the paper's corners (0, 0), (5, 0), (5, 5), (0, 5), back to (0, 0).
    ``first_side="east"`` flies east, north, west, south.
    """
    c = vec3(corner_ned_m, "corner_ned_m")
    a = positive(side_m, "side_m")
    if first_side == FirstSide.NORTH:
        offsets = [(0, 0), (a, 0), (a, a), (0, a)]
    elif first_side == FirstSide.EAST:
        offsets = [(0, 0), (0, a), (a, a), (a, 0)]
    else:
        raise ValueError(f"{name}: first_side must be 'north' or 'east', got {first_side!r}")
    verts = [(c[0] + n, c[1] + e, c[2]) for n, e in offsets]
    return Polygon(verts, speed_m_s, True, laps, yaw_rad, yaw_mode, name)
