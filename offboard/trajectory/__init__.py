"""Trajectories in the local NED frame; see ``base.Trajectory``.

Segments (each one named phase): ``Hold``, ``Line``, ``Helix`` (``circle``), ``Lissajous``
(``figure_eight``), ``Polygon`` (``square``), ``WaypointLegs`` (``Waypoint``) and
``VerticalMove`` (take-off, descent, landing). ``Sequence`` plays segments one after another.
"""

from offboard.trajectory.analytic import Helix, Hold, Line, Lissajous, circle, figure_eight
from offboard.trajectory.base import Phase, PhaseKind, Reference, Trajectory
from offboard.trajectory.polygon import Polygon, square
from offboard.trajectory.segment import Segment
from offboard.trajectory.sequence import Sequence
from offboard.trajectory.waypoints import VerticalMove, Waypoint, WaypointLegs

__all__ = [
    "Helix",
    "Hold",
    "Line",
    "Lissajous",
    "Phase",
    "PhaseKind",
    "Polygon",
    "Reference",
    "Segment",
    "Sequence",
    "Trajectory",
    "VerticalMove",
    "Waypoint",
    "WaypointLegs",
    "circle",
    "figure_eight",
    "square",
]
