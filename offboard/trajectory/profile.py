"""Speed profiles along a path: how far along (s), how fast (s_dot), how hard (s_ddot).

``Trapezoid`` moves a distance ``length_m`` starting at ``v_start`` and ending at ``v_end``
with ``|s_ddot| <= accel_m_s2`` and ``s_dot <= v_max``: accelerate, cruise, decelerate (the
cruise phase vanishes on short pieces: a triangle). It is the time-optimal profile under those
limits, the one PX4's and ArduPilot's position controllers approximate between waypoints.
Velocity is continuous; acceleration steps between the three phases.

``boundary_speeds`` chooses the speeds at the junctions of a chain of pieces (lines, arcs)
so that every piece is feasible: a forward pass limits how fast the chain can be going after
accelerating from rest, a backward pass how fast it may be going and still stop in time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from offboard.trajectory.segment import finite, positive


class Trapezoid:
    """Trapezoidal speed profile over a distance.

    Parameters
    ----------
    length_m : float
        Distance to travel, > 0.
    v_start_m_s, v_end_m_s : float
        Speeds at the start and end, >= 0; reachable from each other within ``length_m``
        (``|v_end**2 - v_start**2| <= 2 accel length``), up to rounding.
    v_max_m_s : float
        Cruise speed, > 0 and >= both end speeds.
    accel_m_s2 : float
        Acceleration limit, > 0.
    """

    __slots__ = ("length_m", "v0", "v1", "v_peak", "accel", "t_accel", "t_cruise_end", "duration_s", "s_accel", "s_cruise_end")

    def __init__(self, length_m: float, v_start_m_s: float, v_end_m_s: float, v_max_m_s: float, accel_m_s2: float) -> None:
        length = positive(length_m, "length_m")
        v0 = finite(v_start_m_s, "v_start_m_s")
        v1 = finite(v_end_m_s, "v_end_m_s")
        v_max = positive(v_max_m_s, "v_max_m_s")
        accel = positive(accel_m_s2, "accel_m_s2")
        if v0 < 0 or v1 < 0:
            raise ValueError(f"end speeds must be >= 0, got {v0:g} and {v1:g}")
        # Tolerate rounding from boundary_speeds, then clip the end speeds into the feasible set.
        v0 = min(v0, v_max)
        v1 = min(v1, v_max, math.sqrt(v0 * v0 + 2.0 * accel * length))
        v0 = min(v0, math.sqrt(v1 * v1 + 2.0 * accel * length))
        v_peak = min(v_max, math.sqrt(accel * length + 0.5 * (v0 * v0 + v1 * v1)))
        v_peak = max(v_peak, v0, v1)
        s_accel = (v_peak * v_peak - v0 * v0) / (2.0 * accel)
        s_decel = (v_peak * v_peak - v1 * v1) / (2.0 * accel)
        s_cruise = max(0.0, length - s_accel - s_decel)
        if v_peak <= 0.0:
            raise ValueError("a piece of positive length needs a positive speed somewhere")
        self.length_m = length
        self.v0, self.v1, self.v_peak, self.accel = v0, v1, v_peak, accel
        self.t_accel = (v_peak - v0) / accel
        self.t_cruise_end = self.t_accel + s_cruise / v_peak
        self.duration_s = self.t_cruise_end + (v_peak - v1) / accel
        self.s_accel = s_accel
        self.s_cruise_end = s_accel + s_cruise

    def at(self, t_s: float) -> tuple[float, float, float]:
        """Distance (m), speed (m/s) and tangential acceleration (m/s^2) at ``t_s`` seconds.

        ``t_s`` is clamped to ``[0, duration_s]``.
        """
        if t_s <= 0.0:
            return 0.0, self.v0, (self.accel if self.t_accel > 0.0 else 0.0)
        if t_s < self.t_accel:
            return self.v0 * t_s + 0.5 * self.accel * t_s * t_s, self.v0 + self.accel * t_s, self.accel
        if t_s < self.t_cruise_end:
            return self.s_accel + self.v_peak * (t_s - self.t_accel), self.v_peak, 0.0
        if t_s < self.duration_s:
            tau = t_s - self.t_cruise_end
            s = self.s_cruise_end + self.v_peak * tau - 0.5 * self.accel * tau * tau
            return min(s, self.length_m), self.v_peak - self.accel * tau, -self.accel
        return self.length_m, self.v1, 0.0

    def __repr__(self) -> str:
        return (
            f"Trapezoid(length_m={self.length_m:g}, v0={self.v0:g}, v_peak={self.v_peak:g}, "
            f"v1={self.v1:g}, accel={self.accel:g}, duration_s={self.duration_s:g})"
        )


def boundary_speeds(
    lengths_m: Sequence[float],
    speed_limits_m_s: Sequence[float],
    constant_speed: Sequence[bool],
    accel_m_s2: float,
) -> list[float]:
    """Speeds at the junctions of a chain of pieces that starts and ends at rest.

    Parameters
    ----------
    lengths_m : sequence of float
        Length of each piece, > 0.
    speed_limits_m_s : sequence of float
        Highest speed allowed on each piece, > 0.
    constant_speed : sequence of bool
        Pieces flown at one speed throughout (arcs: no tangential acceleration, so that the
        centripetal acceleration alone stays within the limit).
    accel_m_s2 : float
        Tangential acceleration limit, > 0.

    Returns
    -------
    list of float
        ``len(lengths_m) + 1`` speeds: at the start (0), at each junction, at the end (0).
    """
    n = len(lengths_m)
    v = [0.0] * (n + 1)
    for k in range(1, n):
        v[k] = min(speed_limits_m_s[k - 1], speed_limits_m_s[k])
    for k in range(n):  # forward: how fast we can be after accelerating from rest
        reach = v[k] if constant_speed[k] else math.sqrt(v[k] * v[k] + 2.0 * accel_m_s2 * lengths_m[k])
        v[k + 1] = min(v[k + 1], reach)
    for k in range(n - 1, -1, -1):  # backward: how fast we may be and still stop in time
        reach = v[k + 1] if constant_speed[k] else math.sqrt(v[k + 1] * v[k + 1] + 2.0 * accel_m_s2 * lengths_m[k])
        v[k] = min(v[k], reach)
    return v
