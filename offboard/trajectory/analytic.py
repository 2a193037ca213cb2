"""Closed-form segments: hold, constant-speed line, helix (and circle), Lissajous (and figure eight).

All in the local NED frame (metres, seconds, radians). Angles around a vertical axis
(``phase_rad``, ``angular_rate_rad_s``) are measured from north (+x) towards east (+y), the
sense of NED yaw: positive is clockwise seen from above. The paper's helix, written in its
x-north, y-east, z-up frame as ``x = 2 cos t, y = 2 sin t, z = 2 + 0.8 t``, is
``Helix(center_ned_m=(0, 0, -2), radius_m=2, angular_rate_rad_s=1, climb_rate_m_s=0.8)``.

Yaw of the moving segments is one of ``YAW_MODES``:

- ``"fixed"``: ``yaw_rad`` throughout;
- ``"along-path"``: the heading of the horizontal velocity;
- ``"center"`` (helix/circle only): facing the axis.

Yaw is continuous within a segment (never wrapped to [-pi, pi) midway); consumers compare
yaw angles modulo 2 pi.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from offboard.trajectory.base import PhaseKind, Reference
from offboard.trajectory.segment import LENGTH_EPS_M, Segment, YawMode, finite, heading_of, positive, vec3, wrap_pi

#: The yaw modes of the moving segments here (``Line`` and ``Lissajous`` take the first two).
YAW_MODES = (YawMode.FIXED.value, YawMode.ALONG_PATH.value, YawMode.CENTER.value)

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


def _check_yaw_mode(yaw_mode: YawMode, allowed: tuple[str, ...]) -> YawMode:
    if yaw_mode not in allowed:
        raise ValueError(f"yaw_mode must be one of {allowed}, got {yaw_mode!r}")
    return YawMode(yaw_mode)


class Hold(Segment):
    """Stay at a point with a fixed yaw (a position-control set point, kind ``hold``).

    Parameters
    ----------
    pos_ned_m : array_like, shape (3,)
        The point, NED metres.
    yaw_rad : float
        Heading held, radians.
    duration_s : float
        How long, seconds.
    name : str
        Phase name.
    """

    def __init__(self, pos_ned_m: ArrayLike, yaw_rad: float, duration_s: float, name: str = "hold") -> None:
        super().__init__(duration_s, name, PhaseKind.HOLD)
        self._ref = Reference(pos_ned_m=vec3(pos_ned_m, "pos_ned_m"), yaw_rad=finite(yaw_rad, "yaw_rad"))

    @property
    def pos_ned_m(self) -> np.ndarray:
        """The position held, NED, m."""
        return self._ref.pos_ned_m

    @property
    def yaw_rad(self) -> float:
        """The heading held, rad."""
        return self._ref.yaw_rad

    def _evaluate(self, t_s: float) -> Reference:
        return self._ref


class Line(Segment):
    """Straight line at constant speed: the velocity steps at both ends (piecewise-linear path).

    Parameters
    ----------
    start_ned_m, end_ned_m : array_like, shape (3,)
        End points, NED metres (distinct).
    speed_m_s : float
        Speed along the line, > 0.
    yaw_rad : float
        Heading for ``yaw_mode="fixed"`` (and for a vertical line in ``"along-path"``).
    yaw_mode : {"fixed", "along-path"}
    name : str
    """

    def __init__(
        self,
        start_ned_m: ArrayLike,
        end_ned_m: ArrayLike,
        speed_m_s: float,
        yaw_rad: float = 0.0,
        yaw_mode: YawMode = YawMode.FIXED,
        name: str = "line",
    ) -> None:
        start = vec3(start_ned_m, "start_ned_m")
        end = vec3(end_ned_m, "end_ned_m")
        speed = positive(speed_m_s, "speed_m_s")
        delta = end - start
        length = float(np.linalg.norm(delta))
        if length < LENGTH_EPS_M:
            raise ValueError(f"{name}: start and end coincide; a line needs two distinct points")
        super().__init__(length / speed, name, PhaseKind.TRACK)
        self.start_ned_m = start
        self.end_ned_m = end
        self.length_m = length
        self._vel = delta / length * speed
        self._vel.setflags(write=False)
        yaw = finite(yaw_rad, "yaw_rad")
        if _check_yaw_mode(yaw_mode, YAW_MODES[:2]) is YawMode.ALONG_PATH:
            heading = heading_of(delta)
            yaw = yaw if heading is None else heading
        self.yaw_rad = yaw

    def _evaluate(self, t_s: float) -> Reference:
        return Reference(self.start_ned_m + self._vel * t_s, self._vel, _ZERO3, self.yaw_rad, 0.0)


class Helix(Segment):
    """Helix about a vertical axis (a circle when ``climb_rate_m_s`` is 0), analytic derivatives.

    ``pos(t) = center + r (cos phi, sin phi, 0) + (0, 0, -climb t)`` with ``phi = phase + w t``.

    Parameters
    ----------
    center_ned_m : array_like, shape (3,)
        Point on the axis at t = 0 (its down component is the start height), NED metres.
    radius_m : float
        > 0.
    angular_rate_rad_s : float
        w, nonzero; positive turns from north towards east (clockwise seen from above).
    climb_rate_m_s : float
        Upward speed (positive climbs, i.e. NED down decreases).
    duration_s : float
    phase_rad : float
        Angle at t = 0 from north towards east.
    yaw_rad : float
        Heading for ``yaw_mode="fixed"``.
    yaw_mode : {"fixed", "along-path", "center"}
    name : str
    """

    def __init__(
        self,
        center_ned_m: ArrayLike,
        radius_m: float,
        angular_rate_rad_s: float,
        climb_rate_m_s: float,
        duration_s: float,
        phase_rad: float = 0.0,
        yaw_rad: float = 0.0,
        yaw_mode: YawMode = YawMode.FIXED,
        name: str = "helix",
    ) -> None:
        super().__init__(duration_s, name, PhaseKind.TRACK)
        self.center_ned_m = vec3(center_ned_m, "center_ned_m")
        self.radius_m = positive(radius_m, "radius_m")
        self.angular_rate_rad_s = finite(angular_rate_rad_s, "angular_rate_rad_s")
        if self.angular_rate_rad_s == 0.0:
            raise ValueError(f"{name}: angular_rate_rad_s must be nonzero (use a line or a hold)")
        self.climb_rate_m_s = finite(climb_rate_m_s, "climb_rate_m_s")
        self.phase_rad = finite(phase_rad, "phase_rad")
        self.yaw_mode = _check_yaw_mode(yaw_mode, YAW_MODES)
        yaw = finite(yaw_rad, "yaw_rad")
        # yaw = phi + offset in the moving modes: tangent is phi +- pi/2, facing the axis phi + pi.
        if self.yaw_mode is YawMode.ALONG_PATH:
            offset = math.copysign(0.5 * math.pi, self.angular_rate_rad_s)
        else:
            offset = math.pi
        self._yaw0 = yaw if self.yaw_mode is YawMode.FIXED else wrap_pi(self.phase_rad + offset)
        self._yaw_rate = 0.0 if self.yaw_mode is YawMode.FIXED else self.angular_rate_rad_s

    @property
    def length_m(self) -> float:
        """Arc length of the helix."""
        speed = math.hypot(self.radius_m * self.angular_rate_rad_s, self.climb_rate_m_s)
        return speed * self.duration_s

    def _evaluate(self, t_s: float) -> Reference:
        w = self.angular_rate_rad_s
        r = self.radius_m
        phi = self.phase_rad + w * t_s
        c, s = math.cos(phi), math.sin(phi)
        cx, cy, cz = self.center_ned_m
        return Reference(
            np.array((cx + r * c, cy + r * s, cz - self.climb_rate_m_s * t_s)),
            np.array((-r * w * s, r * w * c, -self.climb_rate_m_s)),
            np.array((-r * w * w * c, -r * w * w * s, 0.0)),
            self._yaw0 + self._yaw_rate * t_s,
            self._yaw_rate,
        )


def circle(
    center_ned_m: ArrayLike,
    radius_m: float,
    angular_rate_rad_s: float,
    duration_s: float,
    phase_rad: float = 0.0,
    yaw_rad: float = 0.0,
    yaw_mode: YawMode = YawMode.FIXED,
    name: str = "circle",
) -> Helix:
    """A horizontal circle at the height of ``center_ned_m``: a helix that does not climb."""
    return Helix(center_ned_m, radius_m, angular_rate_rad_s, 0.0, duration_s, phase_rad, yaw_rad, yaw_mode, name)


class Lissajous(Segment):
    """Lissajous curve, one sine per axis: ``pos_i(t) = center_i + a_i sin(w_i t + p_i)``.

    Parameters
    ----------
    center_ned_m : array_like, shape (3,)
        Centre, NED metres.
    amplitude_m : array_like, shape (3,)
        a_i along north, east, down (>= 0, one at least > 0).
    angular_rate_rad_s : array_like, shape (3,)
        w_i, rad/s.
    phase_rad : array_like, shape (3,)
        p_i, rad.
    duration_s : float
    yaw_rad : float
        Heading for ``yaw_mode="fixed"``.
    yaw_mode : {"fixed", "along-path"}
        ``"along-path"`` needs horizontal motion at every instant; its heading is unwrapped
        against a table precomputed at construction, so it stays continuous.
    name : str
    """

    #: Spacing of the unwrapping table for along-path yaw (s).
    _TABLE_DT_S = 2e-3

    def __init__(
        self,
        center_ned_m: ArrayLike,
        amplitude_m: ArrayLike,
        angular_rate_rad_s: ArrayLike,
        phase_rad: ArrayLike,
        duration_s: float,
        yaw_rad: float = 0.0,
        yaw_mode: YawMode = YawMode.FIXED,
        name: str = "lissajous",
    ) -> None:
        super().__init__(duration_s, name, PhaseKind.TRACK)
        self.center_ned_m = vec3(center_ned_m, "center_ned_m")
        self.amplitude_m = vec3(amplitude_m, "amplitude_m")
        self.angular_rate_rad_s = vec3(angular_rate_rad_s, "angular_rate_rad_s")
        self.phase_rad = vec3(phase_rad, "phase_rad")
        if np.any(self.amplitude_m < 0) or not np.any(self.amplitude_m * np.abs(self.angular_rate_rad_s) > 0):
            raise ValueError(f"{name}: amplitudes must be >= 0 with at least one moving axis, got {self.amplitude_m.tolist()}")
        self.yaw_mode = _check_yaw_mode(yaw_mode, YAW_MODES[:2])
        self.yaw_rad = finite(yaw_rad, "yaw_rad")
        self._table: np.ndarray | None = None
        if self.yaw_mode is YawMode.ALONG_PATH:
            n = int(math.ceil(self.duration_s / self._TABLE_DT_S)) + 1
            t = np.linspace(0.0, self.duration_s, n)
            arg = self.angular_rate_rad_s[:2, None] * t + self.phase_rad[:2, None]
            vel = self.amplitude_m[:2, None] * self.angular_rate_rad_s[:2, None] * np.cos(arg)
            speed_h = np.hypot(vel[0], vel[1])
            if speed_h.min() < 1e-3:
                k = int(np.argmin(speed_h))
                raise ValueError(
                    f"{name}: along-path yaw needs horizontal motion throughout; the horizontal "
                    f"speed vanishes near t = {t[k]:.3g} s"
                )
            table = np.unwrap(np.arctan2(vel[1], vel[0]))
            table -= 2.0 * math.pi * round(table[0] / (2.0 * math.pi))  # start in [-pi, pi]
            self._table = table
            self._table_dt = self.duration_s / (n - 1)

    def _evaluate(self, t_s: float) -> Reference:
        arg = self.angular_rate_rad_s * t_s + self.phase_rad
        s, c = np.sin(arg), np.cos(arg)
        aw = self.amplitude_m * self.angular_rate_rad_s
        pos = self.center_ned_m + self.amplitude_m * s
        vel = aw * c
        acc = -aw * self.angular_rate_rad_s * s
        if self._table is None:
            return Reference(pos, vel, acc, self.yaw_rad, 0.0)
        vn, ve = float(vel[0]), float(vel[1])
        an, ae = float(acc[0]), float(acc[1])
        raw = math.atan2(ve, vn)
        near = float(self._table[min(int(round(t_s / self._table_dt)), len(self._table) - 1)])
        yaw = raw + 2.0 * math.pi * round((near - raw) / (2.0 * math.pi))
        yaw_rate = (vn * ae - ve * an) / (vn * vn + ve * ve)
        return Reference(pos, vel, acc, yaw, yaw_rate)


def figure_eight(
    center_ned_m: ArrayLike,
    length_m: float,
    width_m: float,
    period_s: float,
    duration_s: float,
    yaw_rad: float = 0.0,
    yaw_mode: YawMode = YawMode.FIXED,
    name: str = "figure-eight",
) -> Lissajous:
    """A horizontal figure eight: ``north = L/2 sin(w t)``, ``east = W/2 sin(2 w t)``, ``w = 2 pi / period``.

    It starts at the centre heading north-east, crosses it every half period, and spans
    ``length_m`` along north and ``width_m`` along east.
    """
    length_m = positive(length_m, "length_m")
    width_m = positive(width_m, "width_m")
    w = 2.0 * math.pi / positive(period_s, "period_s")
    return Lissajous(
        center_ned_m,
        (0.5 * length_m, 0.5 * width_m, 0.0),
        (w, 2.0 * w, 0.0),
        (0.0, 0.0, 0.0),
        duration_s,
        yaw_rad,
        yaw_mode,
        name,
    )
