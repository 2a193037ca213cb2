"""The one question a trajectory answers: where should the vehicle be at time t.

Every trajectory (helix, hold, line, circle, polygon, waypoint legs, a sequence of them) is an
object with ``reference(t_s) -> Reference`` in the local NED frame, plus its duration and the
named phases a report groups errors by. The controller samples it at n and n+1; how a mission
file chose and parameterised it is not the trajectory's business.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike


def _vec3(value: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (3,):
        raise ValueError(f"{name} must have 3 components, got {arr.shape[0]}")
    x, y, z = arr.tolist()  # three floats: cheaper to check than a numpy reduction, per sample
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f"{name} must be finite, got {[x, y, z]}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Reference:
    """A reference sample in the local NED frame (metres, seconds, radians).

    Attributes
    ----------
    pos_ned_m, vel_ned_m_s, acc_ned_m_s2 : ndarray, shape (3,)
        Position, velocity and acceleration, north-east-down.
    yaw_rad : float
        Heading, NED convention (0 = north, +pi/2 = east).
    yaw_rate_rad_s : float
        Time derivative of ``yaw_rad``.
    """

    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_ned_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0

    def __post_init__(self) -> None:
        p, v, a = self.pos_ned_m, self.vel_ned_m_s, self.acc_ned_m_s2
        if type(p) is type(v) is type(a) is np.ndarray and p.dtype == v.dtype == a.dtype == np.float64 \
                and p.shape == v.shape == a.shape == (3,):  # fmt: skip
            # a trajectory's own arrays, twice a sample: one finiteness check of their sum (nan
            # and inf carry through it; a sum that overflows takes the checks below, which name
            # the component)
            yaw, yaw_rate = float(self.yaw_rad), float(self.yaw_rate_rad_s)
            if math.isfinite(sum(p.tolist()) + sum(v.tolist()) + sum(a.tolist()) + yaw + yaw_rate):
                for name, arr in (("pos_ned_m", p), ("vel_ned_m_s", v), ("acc_ned_m_s2", a)):
                    view = arr.view()  # read-only views, as _vec3's: the caller's arrays stay as they are
                    view.setflags(write=False)
                    object.__setattr__(self, name, view)
                object.__setattr__(self, "yaw_rad", yaw)
                object.__setattr__(self, "yaw_rate_rad_s", yaw_rate)
                return
        object.__setattr__(self, "pos_ned_m", _vec3(self.pos_ned_m, "pos_ned_m"))
        object.__setattr__(self, "vel_ned_m_s", _vec3(self.vel_ned_m_s, "vel_ned_m_s"))
        object.__setattr__(self, "acc_ned_m_s2", _vec3(self.acc_ned_m_s2, "acc_ned_m_s2"))
        yaw, yaw_rate = float(self.yaw_rad), float(self.yaw_rate_rad_s)
        if not math.isfinite(yaw):
            raise ValueError(f"yaw_rad must be finite, got {yaw}")
        if not math.isfinite(yaw_rate):
            raise ValueError(f"yaw_rate_rad_s must be finite, got {yaw_rate}")
        object.__setattr__(self, "yaw_rad", yaw)
        object.__setattr__(self, "yaw_rate_rad_s", yaw_rate)


class PhaseKind(enum.StrEnum):
    """What a phase's reference does: moves (``track``: tracking errors) or stays on a fixed point
    (``hold``: the steady-state errors a report gives apart)."""

    TRACK = "track"
    HOLD = "hold"


@dataclass(frozen=True)
class Phase:
    """A named time span of a trajectory, for reports (``start_s <= t < end_s``)."""

    name: str
    start_s: float
    end_s: float
    kind: PhaseKind = PhaseKind.TRACK

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", PhaseKind(self.kind))  # a caller's word: its enum


@runtime_checkable
class Trajectory(Protocol):
    """What every trajectory implements."""

    @property
    def duration_s(self) -> float:
        """Length of the trajectory in seconds; ``reference(t)`` holds the end point after it."""
        ...

    def phases(self) -> list[Phase]:
        """The named phases covering ``[0, duration_s]``, in order."""
        ...

    def reference(self, t_s: float) -> Reference:
        """The reference at time ``t_s`` (seconds from the trajectory's start)."""
        ...


class ReferencePairs:
    """The controller's two references of each sample: ``pair(t) = (reference(t), reference(t + To))``.

    Sample n's second reference is usually sample n + 1's first (where ``t + To`` is the next
    sample's time to the last bit): it is then handed on instead of evaluated again.
    """

    def __init__(self, trajectory: Trajectory, sample_time_s: float) -> None:
        self.trajectory = trajectory
        self.sample_time_s = sample_time_s
        self._next_t_s = math.nan
        self._next: Reference | None = None

    def pair(self, t_s: float) -> tuple[Reference, Reference]:
        """(ref_n, ref_n1) of the sample at ``t_s``.

        At a sample's time ``t_s = n To`` (as the loops compute it) the second reference is taken
        at ``(n + 1) To``, the next sample's time to the last bit, where ``t_s + To`` missed it by
        a rounding in 72 of the helix's 241 samples and cost a third evaluation."""
        to = self.sample_time_s
        ref_n = self._next if t_s == self._next_t_s and self._next is not None else self.trajectory.reference(t_s)
        n = round(t_s / to)
        self._next_t_s = (n + 1) * to if n * to == t_s else t_s + to
        self._next = self.trajectory.reference(self._next_t_s)
        return ref_n, self._next
