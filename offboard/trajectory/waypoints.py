"""Waypoint legs, time-parameterised: straight legs, corners stopped at or blended, speed limits.

Geometry. The path runs from a start point through each waypoint in turn. At an interior
waypoint the corner is either

- **stopped at** (``corners="stop"``, or the waypoint asks for a hold or a stop): the vehicle
  comes to rest on the waypoint, holds there if asked, turns in place if its yaw must change;
- **blended**: the two legs are joined by a circular arc tangent to both, leaving each leg
  ``d = min(blend radius, half of either leg)`` before the waypoint (the waypoint's
  acceptance radius, as PX4 and ArduPilot cut corners). A reversal (turn > 179 deg) is
  always stopped at.

Timing. Each run between two stops is flown time-optimally under three limits: the speed
(cruise speed, changeable per waypoint), the tangential acceleration ``accel_m_s2`` on the
straight parts (trapezoidal speed profile, ``profile.Trapezoid``), and the centripetal
acceleration ``v**2 / r <= accel_m_s2`` on the arcs, which are flown at constant speed. So
velocity is continuous everywhere, the acceleration magnitude never exceeds ``accel_m_s2``,
and the acceleration steps where a profile phase or a piece changes.

Yaw (``yaw_mode``):

- ``"fixed"``: ``yaw_rad`` throughout (a step at the start if it differs from ``start_yaw_rad``);
- ``"along-path"``: the heading of the horizontal velocity, continuous on arcs; at stops
  (and at the start) the vehicle turns in place, a smoothstep in yaw whose peak rate is
  ``max_yaw_rate_rad_s``; vertical legs keep the heading of the next leg that has one;
  arcs are slowed so that the heading rate stays within ``max_yaw_rate_rad_s``;
- ``"waypoint"``: each waypoint's ``yaw_rad`` (``None`` keeps the previous one); between
  waypoints the yaw is linear in distance travelled, the shorter way round, reaching the
  waypoint's value on the waypoint (mid-arc for a blended corner).
"""

from __future__ import annotations

import enum
import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from offboard.trajectory.base import Phase, PhaseKind, Reference
from offboard.trajectory.profile import Trapezoid, boundary_speeds
from offboard.trajectory.segment import LENGTH_EPS_M, Segment, YawMode, finite, heading_of, positive, vec3, wrap_pi



class CornerMode(enum.StrEnum):
    """What the legs do at an interior waypoint (module docstring): come to rest on it (``stop``)
    or cut it by an arc tangent to both legs (``blend``)."""

    STOP = "stop"
    BLEND = "blend"


#: The corner modes by name, the default first.
CORNER_MODES = tuple(c.value for c in CornerMode)
#: The yaw modes of waypoint legs.
YAW_MODES = (YawMode.FIXED.value, YawMode.ALONG_PATH.value, YawMode.WAYPOINT.value)

#: Turns sharper than this (rad) are always stopped at: the arc would be a U-turn on the spot.
MAX_BLEND_TURN_RAD = math.radians(179.0)
#: Defaults, as PX4's multicopter parameters: NAV_ACC_RAD, MPC_YAWRAUTO_MAX.
DEFAULT_BLEND_RADIUS_M = 2.0
DEFAULT_MAX_YAW_RATE_RAD_S = math.radians(45.0)
#: In along-path yaw, an arc whose tangent loses its horizontal part is stopped at instead.
_MIN_HORIZONTAL_TANGENT = 0.05

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


@dataclass(frozen=True)
class Waypoint:
    """A point to fly through, with what to do there.

    Attributes
    ----------
    pos_ned_m : tuple of 3 floats
        Position, NED metres.
    yaw_rad : float or None
        Heading on reaching the waypoint (``yaw_mode="waypoint"``); None keeps the previous one.
    hold_s : float
        Stop and hold this long (seconds, >= 0).
    speed_m_s : float or None
        Cruise speed from the leg that ends here onwards (like MAV_CMD_DO_CHANGE_SPEED).
    blend_radius_m : float or None
        Corner cut distance here (None: the legs' default).
    stop : bool
        Come to rest here even when corners are blended.
    label : str
        Name in phase names (default ``wp<k>``, k counted from 1).
    """

    pos_ned_m: tuple[float, float, float]
    yaw_rad: float | None = None
    hold_s: float = 0.0
    speed_m_s: float | None = None
    blend_radius_m: float | None = None
    stop: bool = False
    label: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "pos_ned_m", tuple(vec3(self.pos_ned_m, "pos_ned_m").tolist()))
        if self.yaw_rad is not None:
            object.__setattr__(self, "yaw_rad", finite(self.yaw_rad, "yaw_rad"))
        hold = finite(self.hold_s, "hold_s")
        if hold < 0:
            raise ValueError(f"hold_s must be >= 0, got {hold:g}")
        object.__setattr__(self, "hold_s", hold)
        if self.speed_m_s is not None:
            object.__setattr__(self, "speed_m_s", positive(self.speed_m_s, "speed_m_s"))
        if self.blend_radius_m is not None:
            radius = finite(self.blend_radius_m, "blend_radius_m")
            if radius < 0:
                raise ValueError(f"blend_radius_m must be >= 0, got {radius:g}")
            object.__setattr__(self, "blend_radius_m", radius)


# --- pieces: what one stretch of the legs does, evaluated at local time tau ---------------------


class _Line:
    __slots__ = ("p0", "u", "length", "profile", "yaw0", "yaw_slope")

    def __init__(self, p0: np.ndarray, u: np.ndarray, length: float) -> None:
        self.p0, self.u, self.length = p0, u, length
        self.profile: Trapezoid | None = None
        self.yaw0 = 0.0
        self.yaw_slope = 0.0  # rad per metre travelled

    def point(self, s: float) -> np.ndarray:
        return self.p0 + self.u * s

    def tangent(self, s: float) -> np.ndarray:
        return self.u

    def ref(self, tau: float) -> Reference:
        s, v, a = self.profile.at(tau)  # type: ignore[union-attr]
        u = self.u
        return Reference(self.p0 + u * s, u * v, u * a, self.yaw0 + self.yaw_slope * s, self.yaw_slope * v)


class _Arc:
    """Part of a circle: ``c - r n cos(phi) + r u1 sin(phi)`` for phi in [phi0, phi0 + length / r]."""

    __slots__ = ("c", "n", "u1", "r", "phi0", "length", "profile", "yaw0", "yaw_slope", "path_heading", "_t0h")

    def __init__(self, c: np.ndarray, n: np.ndarray, u1: np.ndarray, r: float, phi0: float, length: float) -> None:
        self.c, self.n, self.u1, self.r, self.phi0, self.length = c, n, u1, r, phi0, length
        self.profile: Trapezoid | None = None
        self.yaw0 = 0.0
        self.yaw_slope = 0.0
        self.path_heading = False
        t0 = self.tangent(0.0)
        self._t0h = (float(t0[0]), float(t0[1]))

    def point(self, s: float) -> np.ndarray:
        phi = self.phi0 + s / self.r
        return self.c - self.n * (self.r * math.cos(phi)) + self.u1 * (self.r * math.sin(phi))

    def tangent(self, s: float) -> np.ndarray:
        phi = self.phi0 + s / self.r
        return self.u1 * math.cos(phi) + self.n * math.sin(phi)

    def heading_turn(self, s: float) -> tuple[float, float]:
        """Heading change since the piece's start and its derivative per radian of arc."""
        phi = self.phi0 + s / self.r
        c, sn = math.cos(phi), math.sin(phi)
        tn = self.u1[0] * c + self.n[0] * sn
        te = self.u1[1] * c + self.n[1] * sn
        dn = -self.u1[0] * sn + self.n[0] * c
        de = -self.u1[1] * sn + self.n[1] * c
        an, ae = self._t0h
        turned = math.atan2(an * te - ae * tn, an * tn + ae * te)
        return turned, (tn * de - te * dn) / (tn * tn + te * te)

    def ref(self, tau: float) -> Reference:
        s, v, a = self.profile.at(tau)  # type: ignore[union-attr]
        phi = self.phi0 + s / self.r
        c, sn = math.cos(phi), math.sin(phi)
        tangent = self.u1 * c + self.n * sn
        inward = self.n * c - self.u1 * sn
        pos = self.c - self.n * (self.r * c) + self.u1 * (self.r * sn)
        acc = tangent * a + inward * (v * v / self.r)
        if self.path_heading:
            turned, rate = self.heading_turn(s)
            return Reference(pos, tangent * v, acc, self.yaw0 + turned, rate * v / self.r)
        return Reference(pos, tangent * v, acc, self.yaw0 + self.yaw_slope * s, self.yaw_slope * v)


class _Still:
    """At rest on a point; the yaw goes from yaw0 to yaw1 by a smoothstep (a hold if equal)."""

    __slots__ = ("pos", "yaw0", "yaw1", "duration")

    def __init__(self, pos: np.ndarray, yaw0: float, yaw1: float, duration: float) -> None:
        self.pos, self.yaw0, self.yaw1, self.duration = pos, yaw0, yaw1, duration

    def ref(self, tau: float) -> Reference:
        x = min(max(tau / self.duration, 0.0), 1.0)
        dyaw = self.yaw1 - self.yaw0
        return Reference(
            self.pos, _ZERO3, _ZERO3, self.yaw0 + dyaw * x * x * (3.0 - 2.0 * x), dyaw * 6.0 * x * (1.0 - x) / self.duration
        )


def _turn_duration(dyaw: float, max_rate: float) -> float:
    # smoothstep's peak rate is 1.5 * dyaw / T
    return 1.5 * abs(dyaw) / max_rate


class WaypointLegs(Segment):
    """Fly from ``start_ned_m`` through waypoints with speed and acceleration limits (module doc).

    Parameters
    ----------
    start_ned_m : array_like, shape (3,)
        Where the legs start, at rest (normally where the previous segment ended).
    waypoints : sequence of Waypoint
        At least one.
    cruise_speed_m_s : float
        Speed on the legs until a waypoint changes it, > 0.
    accel_m_s2 : float
        Acceleration limit (tangential on legs, centripetal on arcs), > 0.
    corners : {"stop", "blend"}
    blend_radius_m : float
        Default corner cut distance for ``corners="blend"``, >= 0.
    yaw_mode : {"fixed", "along-path", "waypoint"}
    start_yaw_rad : float
        Yaw at the start.
    yaw_rad : float or None
        The yaw for ``yaw_mode="fixed"`` (None: ``start_yaw_rad``).
    max_yaw_rate_rad_s : float
        Peak yaw rate of turns in place, and the heading-rate limit on arcs (along-path yaw).
    name : str
    """

    def __init__(
        self,
        start_ned_m: ArrayLike,
        waypoints: Sequence[Waypoint],
        cruise_speed_m_s: float,
        accel_m_s2: float,
        corners: CornerMode = CornerMode.STOP,
        blend_radius_m: float = DEFAULT_BLEND_RADIUS_M,
        yaw_mode: YawMode = YawMode.FIXED,
        start_yaw_rad: float = 0.0,
        yaw_rad: float | None = None,
        max_yaw_rate_rad_s: float = DEFAULT_MAX_YAW_RATE_RAD_S,
        name: str = "waypoints",
    ) -> None:
        if corners not in CORNER_MODES:
            raise ValueError(f"{name}: corners must be one of {CORNER_MODES}, got {corners!r}")
        if yaw_mode not in YAW_MODES:
            raise ValueError(f"{name}: yaw_mode must be one of {YAW_MODES}, got {yaw_mode!r}")
        if not waypoints:
            raise ValueError(f"{name}: needs at least one waypoint")
        self.start_ned_m = vec3(start_ned_m, "start_ned_m")
        self.waypoints = tuple(waypoints)
        self.cruise_speed_m_s = positive(cruise_speed_m_s, "cruise_speed_m_s")
        self.accel_m_s2 = positive(accel_m_s2, "accel_m_s2")
        self.corners = CornerMode(corners)
        self.blend_radius_m = finite(blend_radius_m, "blend_radius_m")
        if self.blend_radius_m < 0:
            raise ValueError(f"{name}: blend_radius_m must be >= 0, got {self.blend_radius_m:g}")
        self.yaw_mode = YawMode(yaw_mode)
        self.start_yaw_rad = finite(start_yaw_rad, "start_yaw_rad")
        self.fixed_yaw_rad = self.start_yaw_rad if yaw_rad is None else finite(yaw_rad, "yaw_rad")
        self.max_yaw_rate_rad_s = positive(max_yaw_rate_rad_s, "max_yaw_rate_rad_s")
        self.name = name

        pieces, labels = self._build()
        starts: list[float] = []
        t = 0.0
        for piece in pieces:
            starts.append(t)
            t += piece.profile.duration_s if isinstance(piece, (_Line, _Arc)) else piece.duration  # type: ignore[union-attr]
        if t <= 0.0:
            raise ValueError(f"{name}: nothing to fly: every waypoint is at the start point and asks for no hold or turn")
        super().__init__(t, name, PhaseKind.TRACK)
        self._pieces = pieces
        self._starts = starts
        self._phases = self._make_phases(labels)
        self.length_m = float(sum(p.length for p in pieces if isinstance(p, (_Line, _Arc))))

    # -- construction -------------------------------------------------------------------------

    def _build(self) -> tuple[list, list]:
        """Pieces in time order, and for each its phase: (its kind, waypoint label or None)."""
        wps = self.waypoints
        n = len(wps)
        points = [self.start_ned_m] + [np.array(w.pos_ned_m) for w in wps]
        speeds: list[float] = []
        speed = self.cruise_speed_m_s
        units: list[np.ndarray | None] = []
        lengths: list[float] = []
        for k in range(n):
            speed = wps[k].speed_m_s or speed
            speeds.append(speed)
            delta = points[k + 1] - points[k]
            length = float(np.linalg.norm(delta))
            lengths.append(length)
            units.append(delta / length if length >= LENGTH_EPS_M else None)

        path_yaw = self.yaw_mode is YawMode.ALONG_PATH
        # Corner k joins leg k (ending at waypoint k) and leg k + 1.
        arcs: list[tuple | None] = [None] * n
        stops = [True] * n
        for k in range(n - 1):
            w = wps[k]
            u1, u2 = units[k], units[k + 1]
            if self.corners is CornerMode.STOP or w.hold_s > 0 or w.stop or u1 is None or u2 is None:
                continue
            theta = math.acos(min(1.0, max(-1.0, float(u1 @ u2))))
            if theta < 1e-9:
                stops[k] = False  # straight on: no corner at all
                continue
            if theta > MAX_BLEND_TURN_RAD:
                continue
            radius = self.blend_radius_m if w.blend_radius_m is None else w.blend_radius_m
            d = min(radius, 0.5 * lengths[k], 0.5 * lengths[k + 1])
            if d < 1e-6:
                continue
            r = d / math.tan(0.5 * theta)
            normal = (u2 - u1 * math.cos(theta)) / math.sin(theta)
            arc = _Arc(points[k + 1] - u1 * d + normal * r, normal, u1, r, 0.0, r * theta)
            v_arc = min(speeds[k], speeds[k + 1], math.sqrt(self.accel_m_s2 * r))
            if path_yaw:
                phi = np.linspace(0.0, theta, 257)[:, None]
                tangent = u1 * np.cos(phi) + normal * np.sin(phi)
                dtangent = normal * np.cos(phi) - u1 * np.sin(phi)
                horizontal_sq = tangent[:, 0] ** 2 + tangent[:, 1] ** 2
                if np.sqrt(horizontal_sq.min()) < _MIN_HORIZONTAL_TANGENT:
                    continue
                dheading = (tangent[:, 0] * dtangent[:, 1] - tangent[:, 1] * dtangent[:, 0]) / horizontal_sq
                max_rate = 1.01 * float(np.abs(dheading).max())  # 1 % for what falls between samples
                if max_rate > 0:
                    v_arc = min(v_arc, self.max_yaw_rate_rad_s * r / max_rate)
            arcs[k] = (arc, d, theta, v_arc)
            stops[k] = False

        # Motion pieces in order, with stop markers: ("move", piece, speed_limit, constant, leg)
        # or ("stop", waypoint index). Each arc is split in two halves, so that a waypoint's
        # yaw knot falls on a piece boundary.
        events: list[tuple] = []
        trim_start = 0.0
        for k in range(n):
            u = units[k]
            if u is not None:
                corner = arcs[k]
                trim_end = corner[1] if corner is not None else 0.0
                length = lengths[k] - trim_start - trim_end
                if length > LENGTH_EPS_M:
                    events.append(("move", _Line(points[k] + u * trim_start, u, length), speeds[k], False, k))
            arc_info = arcs[k]
            if arc_info is not None:
                arc, d, theta, v_arc = arc_info
                half = 0.5 * arc.length
                events.append(("move", _Arc(arc.c, arc.n, arc.u1, arc.r, 0.0, half), v_arc, True, k))
                events.append(("knot", k))
                events.append(("move", _Arc(arc.c, arc.n, arc.u1, arc.r, 0.5 * theta, half), v_arc, True, k + 1))
                trim_start = d
            else:
                trim_start = 0.0
                if stops[k]:
                    events.append(("stop", k))
                else:
                    events.append(("knot", k))
        self._assign_yaw(events)
        return self._time(events)

    def _assign_yaw(self, events: list[tuple]) -> None:
        """Set yaw0/yaw_slope (and path_heading) on every motion piece; record turn targets."""
        moves = [e[1] for e in events if e[0] == "move"]
        if self.yaw_mode is YawMode.FIXED:
            for p in moves:
                p.yaw0 = self.fixed_yaw_rad
            return
        if self.yaw_mode is YawMode.ALONG_PATH:
            headings = [heading_of(p.u) if isinstance(p, _Line) else heading_of(p.tangent(0.0)) for p in moves]
            # vertical pieces take the heading of the next piece that has one (else the last one)
            nxt: float | None = None
            for i in range(len(headings) - 1, -1, -1):
                headings[i] = nxt = headings[i] if headings[i] is not None else nxt
            prev = self.start_yaw_rad
            for i, p in enumerate(moves):
                h = headings[i]
                h = prev if h is None else prev + wrap_pi(h - prev)
                p.yaw0 = h
                if isinstance(p, _Arc):
                    p.path_heading = True
                    prev = h + p.heading_turn(p.length)[0]
                else:
                    prev = h
            return
        # "waypoint": knots at each waypoint, linear in distance between them
        yaw = self.start_yaw_rad
        s = 0.0
        segment_pieces: list = []  # pieces since the last knot
        for e in events:
            if e[0] == "move":
                segment_pieces.append(e[1])
                continue
            w = self.waypoints[e[1]]
            target = yaw if w.yaw_rad is None else yaw + wrap_pi(w.yaw_rad - yaw)
            total = sum(p.length for p in segment_pieces)
            slope = (target - yaw) / total if total > 0 else 0.0
            s = 0.0
            for p in segment_pieces:
                p.yaw0 = yaw + slope * s
                p.yaw_slope = slope
                s += p.length
            yaw = target if total > 0 else yaw  # a zero-length leg turns in place (see _time)
            segment_pieces = []

    def _time(self, events: list[tuple]) -> tuple[list, list]:
        pieces: list = []
        labels: list = []
        run: list[tuple] = []
        yaw = self.start_yaw_rad if self.yaw_mode is not YawMode.FIXED else self.fixed_yaw_rad
        pos = self.start_ned_m

        def label(k: int) -> str:
            return self.waypoints[k].label or f"wp{k + 1}"

        def flush_run(stop_label: str) -> None:
            nonlocal pos, yaw
            if not run:
                return
            limits = [e[2] for e in run]
            constant = [e[3] for e in run]
            lens = [e[1].length for e in run]
            v = boundary_speeds(lens, limits, constant, self.accel_m_s2)
            for k, e in enumerate(run):
                p = e[1]
                v_max = max(v[k], v[k + 1]) if constant[k] else limits[k]
                p.profile = Trapezoid(p.length, v[k], v[k + 1], max(v_max, 1e-9), self.accel_m_s2)
                pieces.append(p)
                labels.append((PhaseKind.TRACK, stop_label))
            last = run[-1][1]
            pos = vec3(last.point(last.length), "pos")
            yaw = self._end_yaw(last)
            run.clear()

        def turn_to(target: float) -> None:
            nonlocal yaw
            if abs(target - yaw) > 1e-9:
                pieces.append(_Still(pos, yaw, target, _turn_duration(target - yaw, self.max_yaw_rate_rad_s)))
                labels.append((PhaseKind.TRACK, None))
            yaw = target

        for e in events:
            if e[0] == "move":
                p = e[1]
                if not run:  # leaving a stop (or the start): turn first if the piece starts elsewhere
                    turn_to(p.yaw0)
                run.append(e)
                continue
            if e[0] == "knot":
                continue
            # a stop at waypoint e[1]
            flush_run(label(e[1]))
            w = self.waypoints[e[1]]
            if self.yaw_mode is YawMode.WAYPOINT and w.yaw_rad is not None:
                turn_to(yaw + wrap_pi(w.yaw_rad - yaw))  # only turns after a zero-length leg
            if w.hold_s > 0:
                pieces.append(_Still(pos, yaw, yaw, w.hold_s))
                labels.append((PhaseKind.HOLD, label(e[1])))
        flush_run(label(len(self.waypoints) - 1))
        return pieces, labels

    @staticmethod
    def _end_yaw(piece: _Line | _Arc) -> float:
        if isinstance(piece, _Arc) and piece.path_heading:
            return piece.yaw0 + piece.heading_turn(piece.length)[0]
        return piece.yaw0 + piece.yaw_slope * piece.length

    def _make_phases(self, labels: list) -> list[Phase]:
        """One phase per run between stops (``<name>:to-<wp>``) and per hold (``<name>:hold-<wp>``).

        Without holds the whole segment is one phase named ``name``.
        """
        if all(kind is PhaseKind.TRACK for kind, _ in labels):
            return [Phase(self.name, 0.0, self.duration_s, PhaseKind.TRACK)]
        phases: list[Phase] = []
        ends = self._starts[1:] + [self.duration_s]
        k = 0
        while k < len(labels):
            kind, label = labels[k]
            if kind is PhaseKind.HOLD:
                phases.append(Phase(f"{self.name}:hold-{label}", self._starts[k], ends[k], PhaseKind.HOLD))
                k += 1
                continue
            j = k
            while j + 1 < len(labels) and labels[j + 1][0] is PhaseKind.TRACK:
                j += 1
            names = [lab for _, lab in labels[k : j + 1] if lab is not None]
            suffix = f"to-{names[-1]}" if names else f"turn-{len(phases) + 1}"
            phases.append(Phase(f"{self.name}:{suffix}", self._starts[k], ends[j], PhaseKind.TRACK))
            k = j + 1
        return phases

    # -- evaluation ---------------------------------------------------------------------------

    def phases(self) -> list[Phase]:
        return list(self._phases)

    def _evaluate(self, t_s: float) -> Reference:
        k = bisect_right(self._starts, t_s) - 1
        return self._pieces[k].ref(t_s - self._starts[k])


class VerticalMove(WaypointLegs):
    """Climb or descend straight up or down at a speed limit (take-off, descent, landing).

    A trapezoidal speed profile from rest to rest; the yaw is held.

    Parameters
    ----------
    start_ned_m : array_like, shape (3,)
    to_down_m : float
        Final NED down coordinate (``0`` is the ground at the origin for a landing).
    speed_m_s, accel_m_s2 : float
        Speed and acceleration limits, > 0.
    yaw_rad : float
        Heading at the start.
    name : str
    end_yaw_rad : float or None
        Heading at the end, reached linearly in height (the shorter way round); None holds ``yaw_rad``.
    """

    def __init__(
        self,
        start_ned_m: ArrayLike,
        to_down_m: float,
        speed_m_s: float,
        accel_m_s2: float,
        yaw_rad: float = 0.0,
        name: str = "descent",
        end_yaw_rad: float | None = None,
    ) -> None:
        start = vec3(start_ned_m, "start_ned_m")
        end = (float(start[0]), float(start[1]), finite(to_down_m, "to_down_m"))
        if abs(end[2] - start[2]) < LENGTH_EPS_M:
            raise ValueError(f"{name}: already at down = {end[2]:g} m; nothing to climb or descend")
        yaw_mode = YawMode.FIXED if end_yaw_rad is None else YawMode.WAYPOINT
        super().__init__(
            start, [Waypoint(end, yaw_rad=end_yaw_rad)], speed_m_s, accel_m_s2, CornerMode.STOP, 0.0, yaw_mode, yaw_rad, yaw_rad,
            name=name,
        )
