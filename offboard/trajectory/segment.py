"""What every trajectory segment shares: a duration, a name, a kind, and clamped time.

A segment answers ``reference(t_s)`` for ``0 <= t_s < duration_s`` from its own formula
(``_evaluate``); before its start it holds the start point and from ``duration_s`` on it holds
the end point, both with zero velocity, acceleration and yaw rate (the ``Trajectory``
contract of ``base.py``).
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from offboard.trajectory.base import Phase, PhaseKind, Reference
from offboard.model.rotations import wrap_pi

__all__ = ["LENGTH_EPS_M", "PHASE_KINDS", "Segment", "YawMode", "finite", "heading_of", "positive", "vec3", "wrap_pi"]

#: The phase kinds by name, a moving reference first.
PHASE_KINDS = tuple(k.value for k in PhaseKind)


class YawMode(enum.StrEnum):
    """Where a moving segment points the vehicle: one heading throughout (``fixed``), the heading
    of the horizontal velocity (``along-path``), facing a helix's axis (``center``) or each
    waypoint's own yaw, reached on the waypoint (``waypoint``). Each segment type takes those its
    module's ``YAW_MODES`` name."""

    FIXED = "fixed"
    ALONG_PATH = "along-path"
    CENTER = "center"
    WAYPOINT = "waypoint"


#: Below this (m) a displacement counts as none: a zero-length leg, a vertical line's heading.
LENGTH_EPS_M = 1e-9


class Segment(ABC):
    """A trajectory with one name and one kind (one ``Phase``), evaluated on ``[0, duration_s)``.

    Parameters
    ----------
    duration_s : float
        Length of the segment in time, > 0.
    name : str
        Name of its phase in reports (``"helix"``, ``"hold-12m"``).
    kind : PhaseKind
        ``hold`` for a fixed point (steady-state errors), ``track`` otherwise.
    """

    def __init__(self, duration_s: float, name: str, kind: PhaseKind) -> None:
        duration_s = float(duration_s)
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"{name}: duration_s must be finite and > 0, got {duration_s}")
        if kind not in PHASE_KINDS:
            raise ValueError(f"{name}: kind must be one of {PHASE_KINDS}, got {kind!r}")
        self._duration_s = duration_s
        self.name = str(name)
        self.kind = PhaseKind(kind)

    @property
    def duration_s(self) -> float:
        """Length of the segment in seconds; the end point is held after it."""
        return self._duration_s

    def phases(self) -> list[Phase]:
        """One phase spanning the whole segment (subclasses with holds inside split it)."""
        return [Phase(self.name, 0.0, self._duration_s, self.kind)]

    def reference(self, t_s: float) -> Reference:
        """The reference at ``t_s`` seconds from the segment's start (NED, SI units)."""
        if t_s >= self._duration_s:
            return self.end_reference
        if t_s < 0.0:
            return self.start_reference
        return self._evaluate(t_s)

    @cached_property
    def start_reference(self) -> Reference:
        """The start point and yaw, at rest."""
        ref = self._evaluate(0.0)
        return Reference(pos_ned_m=ref.pos_ned_m, yaw_rad=ref.yaw_rad)

    @cached_property
    def end_reference(self) -> Reference:
        """The end point and yaw, at rest (what ``reference`` returns from ``duration_s`` on)."""
        ref = self._evaluate(self._duration_s)
        return Reference(pos_ned_m=ref.pos_ned_m, yaw_rad=ref.yaw_rad)

    @abstractmethod
    def _evaluate(self, t_s: float) -> Reference:
        """The reference for ``0 <= t_s <= duration_s`` (the end included, for ``end_reference``)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, duration_s={self._duration_s:g})"


def vec3(value: ArrayLike, name: str) -> np.ndarray:
    """A finite, read-only 3-vector of floats (raises ``ValueError`` naming ``name``)."""
    arr = np.array(value, dtype=float).reshape(-1)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def finite(value: float, name: str) -> float:
    """``value`` as a float; a ValueError naming ``name`` unless it is finite."""
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def positive(value: float, name: str) -> float:
    """``value`` as a float; a ValueError naming ``name`` unless it is finite and > 0."""
    value = finite(value, name)
    if value <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value:g}")
    return value


def heading_of(direction_ned: np.ndarray) -> float | None:
    """Heading (rad, 0 = north, +pi/2 = east) of a direction's horizontal part; None if vertical."""
    north, east = float(direction_ned[0]), float(direction_ned[1])
    if math.hypot(north, east) < LENGTH_EPS_M:
        return None
    return math.atan2(east, north)
