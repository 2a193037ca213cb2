"""Parametric missions in TOML: a ``[mission]`` table and its ``[[mission.segment]]`` list.

The format is documented for users in ``docs/missions.md``; in short::

    [mission]
    name = "paper-helix"
    frame = "paper-zup"        # required: "ned" (x north, y east, z down) or "paper-zup" (z up)
    angle_unit = "rad"         # required: "rad" or "deg", for every angle and angular rate
    start = [0, 0, 0]          # where the vehicle starts (default: the origin), in `frame`

    [[mission.segment]]
    type = "helix"             # hold, line, helix, circle, polygon, square, lissajous,
    ...                        # figure-eight, waypoints, takeoff, descent, land

Lengths are metres, times seconds, speeds m/s; key names carry those units (``radius_m``,
``duration_s``), angles are in ``angle_unit`` (with ``angle_unit = "rad"`` also written
``"pi/2"``, ``"-pi"``, ``"3*pi/4"``). Every key is checked: a misspelt or unknown one is an
error, never ignored.

A segment starts where the previous one ended unless its own keys place it (a helix's
centre and phase, a polygon's first vertex, a hold's ``position``, a line's ``from``), in
which case the reference jumps there, as the paper's does.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from offboard.errors import MissionFormatError
from offboard.frames import ned_from_paper_position
from offboard.missions.fields import MissionFields
from offboard.model.tomlfile import near_name
from offboard.trajectory import (
    Helix,
    Hold,
    Line,
    Lissajous,
    Polygon,
    Sequence,
    VerticalMove,
    Waypoint,
    WaypointLegs,
    figure_eight,
    square,
)
from offboard.trajectory.polygon import FirstSide
from offboard.trajectory.sampling import sample
from offboard.trajectory.segment import Segment, YawMode
from offboard.trajectory.waypoints import CORNER_MODES, DEFAULT_BLEND_RADIUS_M, DEFAULT_MAX_YAW_RATE_RAD_S, CornerMode


class MissionFrame(enum.StrEnum):
    """The frame a mission file's positions are in: ``ned`` (x north, y east, z down) or the
    paper's ``paper-zup`` (x north, y east, z up)."""

    NED = "ned"
    PAPER_ZUP = "paper-zup"


class AngleUnit(enum.StrEnum):
    """The unit of a mission file's angles and angular rates."""

    RAD = "rad"
    DEG = "deg"


FRAMES = tuple(f.value for f in MissionFrame)
ANGLE_UNITS = tuple(u.value for u in AngleUnit)
SEGMENT_TYPES = (
    "hold", "line", "helix", "circle", "polygon", "square", "lissajous", "figure-eight",
    "waypoints", "takeoff", "descent", "land",
)
#: Spacing (s) of the samples the ground check looks at.
GROUND_CHECK_DT_S = 0.01

_PI_EXPR = re.compile(r"^\s*([+-])?\s*(\d+(?:\.\d*)?|\.\d+)?\s*\*?\s*pi\s*(?:/\s*(\d+(?:\.\d*)?))?\s*$")


@dataclass(frozen=True)
class ParsedMission:
    """What a ``[mission]`` table says, ready for ``offboard.missions.Mission``."""

    name: str
    description: str
    trajectory: Sequence
    home: tuple[float, float, float] | None
    start_ned_m: tuple[float, float, float]
    start_yaw_rad: float


class _Context:
    """Frame, units and the running state (time, where the last segment ended)."""

    def __init__(self, frame: MissionFrame, angle_unit: AngleUnit) -> None:
        self.frame = frame
        self.angle_unit = angle_unit
        self.t_s = 0.0
        self.pos = np.zeros(3)
        self.yaw = 0.0

    def to_ned(self, xyz: tuple[float, ...]) -> np.ndarray:
        v = np.array(xyz, dtype=float)
        return (ned_from_paper_position(v) if self.frame is MissionFrame.PAPER_ZUP else v) + 0.0  # no -0.0 in reports

    def angle_value(self, f: MissionFields, key: str, value: Any) -> float:
        if isinstance(value, str):
            m = _PI_EXPR.match(value)
            if m is None or self.angle_unit is not AngleUnit.RAD:
                want = "a number of radians or an expression like 'pi/2'" if self.angle_unit is AngleUnit.RAD else "a number of degrees"
                raise f.error(key, f"expected {want}, got {value!r}")
            sign = -1.0 if m.group(1) == "-" else 1.0
            factor = float(m.group(2)) if m.group(2) else 1.0
            divisor = float(m.group(3)) if m.group(3) else 1.0
            if divisor == 0:
                raise f.error(key, f"division by zero in {value!r}")
            return sign * factor * math.pi / divisor
        f._check_number(key, value)
        return math.radians(value) if self.angle_unit is AngleUnit.DEG else float(value)


def _angle(ctx: _Context, f: MissionFields, key: str, default: Any = ...) -> Any:
    """An angle in radians; ``default`` (already in radians, or None) when the key is absent."""
    if default is not ... and not f.has(key):
        f.raw(key, None)
        return default
    return ctx.angle_value(f, key, f.raw(key))


def _position(ctx: _Context, f: MissionFields, key: str, default: Any = ...) -> np.ndarray:
    if default is not ... and not f.has(key):
        f.raw(key, None)
        return default
    return ctx.to_ned(f.vector(key, 3))


def _yaw_choice(ctx: _Context, f: MissionFields, modes: tuple[YawMode, ...]) -> tuple[YawMode, float]:
    """``yaw`` key: an angle (fixed) or one of ``modes``; default: the previous yaw, fixed."""
    value = f.raw("yaw", None)
    if value is None:
        return YawMode.FIXED, ctx.yaw
    if isinstance(value, str) and value in modes:
        return YawMode(value), ctx.yaw
    if isinstance(value, str) and _PI_EXPR.match(value) is None:
        unit = "radians" if ctx.angle_unit is AngleUnit.RAD else "degrees"
        raise f.error("yaw", f"expected an angle in {unit} or one of {', '.join(repr(m.value) for m in modes)}, got {value!r}")
    return YawMode.FIXED, ctx.angle_value(f, "yaw", value)


def _duration(ctx: _Context, f: MissionFields, extra: tuple[str, ...] = (), per_unit_s: dict[str, float] | None = None) -> float:
    """Exactly one of ``duration_s``, ``until_s`` (mission time) or the ``extra`` keys."""
    keys = ("duration_s", "until_s", *extra)
    given = [k for k in keys if f.has(k)]
    if len(given) != 1:
        listed = ", ".join(keys)
        got = ", ".join(given) if given else "none"
        raise f.error(given[-1] if len(given) > 1 else keys[0], f"expected exactly one of {listed}, got {got}")
    key = given[0]
    if key == "duration_s":
        return f.number("duration_s", gt=0)
    if key == "until_s":
        until = f.number("until_s")
        if not until > ctx.t_s + 1e-9:
            raise f.error("until_s", f"must be after the segment's start at t = {ctx.t_s:g} s, got {until:g}")
        return until - ctx.t_s
    count = f.number(key, gt=0)
    return count * (per_unit_s or {})[key]


def _optional_number(f: MissionFields, key: str, **bounds: float) -> float | None:
    if not f.has(key):
        f.raw(key, None)
        return None
    return f.number(key, **bounds)


def _points(ctx: _Context, f: MissionFields, key: str, minimum: int) -> list[np.ndarray]:
    value = f.raw(key)
    if not isinstance(value, list) or len(value) < minimum:
        raise f.error(key, f"expected a list of at least {minimum} points [x, y, z]")
    out = []
    for i, p in enumerate(value):
        if not isinstance(p, list) or len(p) != 3:
            raise f.error(f"{key}[{i}]", f"expected 3 numbers [x, y, z], got {p!r}")
        out.append(ctx.to_ned(tuple(f._check_number(f"{key}[{i}][{j}]", v) for j, v in enumerate(p))))
    return out


# --- one builder per segment type: (ctx, fields, name) -> segment --------------------------------


def _hold(ctx: _Context, f: MissionFields, name: str) -> Hold:
    pos = _position(ctx, f, "position", ctx.pos)
    yaw = _angle(ctx, f, "yaw", ctx.yaw)
    return Hold(pos, yaw, _duration(ctx, f), name)


def _line(ctx: _Context, f: MissionFields, name: str) -> Line:
    start = _position(ctx, f, "from", ctx.pos)
    end = _position(ctx, f, "to")
    speed = f.number("speed_m_s", gt=0)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH,))
    if float(np.linalg.norm(end - start)) < 1e-9:
        raise f.error("to", "the line ends where it starts; expected a different point")
    return Line(start, end, speed, yaw, mode, name)


def _helix(ctx: _Context, f: MissionFields, name: str, climbs: bool = True) -> Helix:
    center = _position(ctx, f, "center")
    radius = f.number("radius_m", gt=0)
    rate = _angle(ctx, f, "angular_rate")
    if rate == 0:
        raise f.error("angular_rate", "must be nonzero (the sign sets the direction)")
    climb = f.number("climb_rate_m_s") if climbs else 0.0
    phase = _angle(ctx, f, "phase", 0.0)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH, YawMode.CENTER))
    duration = _duration(ctx, f, ("turns",), {"turns": 2.0 * math.pi / abs(rate)})
    return Helix(center, radius, rate, climb, duration, phase, yaw, mode, name)


def _circle(ctx: _Context, f: MissionFields, name: str) -> Helix:
    return _helix(ctx, f, name, climbs=False)


def _polygon(ctx: _Context, f: MissionFields, name: str) -> Polygon:
    verts = _points(ctx, f, "vertices", 2)
    for k in range(1, len(verts)):
        if float(np.linalg.norm(verts[k] - verts[k - 1])) < 1e-9:
            raise f.error(f"vertices[{k}]", "repeats the previous vertex; expected distinct consecutive vertices")
    speed = f.number("speed_m_s", gt=0)
    closed = f.boolean("closed", True)
    laps = _laps(f, closed)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH,))
    return Polygon(verts, speed, closed, laps, yaw, mode, name)


def _laps(f: MissionFields, closed: bool = True) -> int:
    laps = f.raw("laps", 1)
    if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
        raise f.error("laps", f"expected a whole number >= 1, got {laps!r}")
    if laps > 1 and not closed:
        raise f.error("laps", "more than one lap needs closed = true")
    return laps


def _square(ctx: _Context, f: MissionFields, name: str) -> Polygon:
    corner = _position(ctx, f, "corner")
    side = f.number("side_m", gt=0)
    speed = f.number("speed_m_s", gt=0)
    first = f.string("first_side", "x", choices=("x", "y"))
    laps = _laps(f)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH,))
    return square(corner, side, speed, FirstSide.NORTH if first == "x" else FirstSide.EAST, laps, yaw, mode, name)


def _lissajous(ctx: _Context, f: MissionFields, name: str) -> Lissajous:
    center = _position(ctx, f, "center")
    amplitude = np.array(f.vector("amplitude_m", 3, ge=0))
    raw_rates = f.raw("angular_rate")
    if not isinstance(raw_rates, list) or len(raw_rates) != 3:
        raise f.error("angular_rate", f"expected 3 angular rates, got {raw_rates!r}")
    rates = np.array([ctx.angle_value(f, f"angular_rate[{k}]", v) for k, v in enumerate(raw_rates)])
    raw_phase = f.raw("phase", [0, 0, 0])
    if not isinstance(raw_phase, list) or len(raw_phase) != 3:
        raise f.error("phase", f"expected 3 angles, got {raw_phase!r}")
    phase = np.array([ctx.angle_value(f, f"phase[{k}]", v) for k, v in enumerate(raw_phase)])
    if not np.any(amplitude * np.abs(rates) > 0):
        raise f.error("amplitude_m", "no axis moves; expected an amplitude > 0 on an axis with a nonzero angular rate")
    if ctx.frame is MissionFrame.PAPER_ZUP:
        phase[2] += math.pi  # up = a sin(.) is down = a sin(. + pi)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH,))
    return Lissajous(center, amplitude, rates, phase, _duration(ctx, f), yaw, mode, name)


def _figure_eight(ctx: _Context, f: MissionFields, name: str) -> Lissajous:
    center = _position(ctx, f, "center")
    length = f.number("length_m", gt=0)
    width = f.number("width_m", gt=0)
    period = f.number("period_s", gt=0)
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH,))
    duration = _duration(ctx, f, ("laps",), {"laps": period})
    return figure_eight(center, length, width, period, duration, yaw, mode, name)


def _waypoints(ctx: _Context, f: MissionFields, name: str) -> WaypointLegs:
    has_points, has_point = f.has("points"), f.has("point")
    if has_points == has_point:
        raise f.error("points", "expected exactly one of points = [[x, y, z], ...] or [[mission.segment.point]] tables")
    waypoints: list[Waypoint] = []
    if has_points:
        waypoints = [Waypoint(tuple(p)) for p in _points(ctx, f, "points", 1)]
    else:
        tables = f.table_list("point")
        for i, table in enumerate(tables):
            pf = MissionFields(table, f.source, f"{f.prefix}point[{i}].")
            pos = ctx.to_ned(pf.vector("position", 3))
            wp_yaw = _angle(ctx, pf, "yaw", None)
            hold = pf.number("hold_s", 0.0, ge=0)
            speed = _optional_number(pf, "speed_m_s", gt=0)
            blend = _optional_number(pf, "blend_radius_m", ge=0)
            stop = pf.boolean("stop", False)
            label = pf.string("label", "")
            pf.reject_unknown()
            waypoints.append(Waypoint(tuple(pos), wp_yaw, hold, speed, blend, stop, label))
    cruise = f.number("cruise_speed_m_s", gt=0)
    accel = f.number("accel_m_s2", gt=0)
    corners = CornerMode(f.string("corners", CornerMode.STOP, choices=CORNER_MODES))
    blend_radius = f.number("blend_radius_m", DEFAULT_BLEND_RADIUS_M, ge=0)
    max_rate = _angle(ctx, f, "max_yaw_rate", DEFAULT_MAX_YAW_RATE_RAD_S)
    if not max_rate > 0:
        raise f.error("max_yaw_rate", "must be > 0")
    mode, yaw = _yaw_choice(ctx, f, (YawMode.ALONG_PATH, YawMode.WAYPOINT))
    if mode is not YawMode.WAYPOINT and any(w.yaw_rad is not None for w in waypoints):
        raise f.error("yaw", "points give their own yaw; expected yaw = \"waypoint\"")
    return WaypointLegs(ctx.pos, waypoints, cruise, accel, corners, blend_radius, mode, ctx.yaw, yaw, max_rate, name)


def _vertical(ctx: _Context, f: MissionFields, name: str, climb: bool, ground_down_m: float | None = None) -> VerticalMove:
    """Take-off (climb), descent, or landing (to ``ground_down_m``), straight up or down from here.

    ``altitude_m`` is the height above the origin, positive up, whatever the frame.
    """
    if ground_down_m is None:
        to_down = -f.number("altitude_m")
        key = "altitude_m"
    else:
        to_down = ground_down_m
        key = "type"
    speed = f.number("speed_m_s", gt=0)
    accel = f.number("accel_m_s2", gt=0)
    end_yaw = _angle(ctx, f, "yaw", None)
    here_up = 0.0 - float(ctx.pos[2]) + 0.0  # no "-0 m" in messages
    if climb and not to_down < ctx.pos[2] - 1e-9:
        raise f.error(key, f"a take-off must climb; expected an altitude above the segment's start ({here_up:g} m), got {-to_down:g}")
    if not climb and not to_down > ctx.pos[2] + 1e-9:
        word, what = ("landing", "the ground") if ground_down_m is not None else ("descent", f"{-to_down:g} m")
        raise f.error(key, f"a {word} must go down; the segment starts at {here_up:g} m and {what} is not below it")
    return VerticalMove(ctx.pos, to_down, speed, accel, ctx.yaw, name, end_yaw)


def _takeoff(ctx: _Context, f: MissionFields, name: str) -> VerticalMove:
    return _vertical(ctx, f, name, climb=True)


def _descent(ctx: _Context, f: MissionFields, name: str) -> VerticalMove:
    return _vertical(ctx, f, name, climb=False)


_BUILDERS = {
    "hold": _hold,
    "line": _line,
    "helix": _helix,
    "circle": _circle,
    "polygon": _polygon,
    "square": _square,
    "lissajous": _lissajous,
    "figure-eight": _figure_eight,
    "waypoints": _waypoints,
    "takeoff": _takeoff,
    "descent": _descent,
}


def parse_mission_table(table: Any, source: str, prefix: str = "mission.", default_name: str = "mission") -> ParsedMission:
    """Build the trajectory a ``[mission]`` table describes (NED), checking every field.

    Parameters
    ----------
    table : mapping
        The ``[mission]`` table as ``tomllib`` parsed it.
    source : str
        File name for messages.
    prefix : str
        Dotted path of the table in its file, for messages.
    default_name : str
        Name when the table has no ``name``.

    Raises
    ------
    MissionFormatError
        One line naming the file, the segment and the field, and what was expected.
    """
    f = MissionFields(table, source, prefix)
    name = f.string("name", default_name)
    description = f.string("description", "")
    frame = MissionFrame(f.string("frame", choices=FRAMES))
    angle_unit = AngleUnit(f.string("angle_unit", choices=ANGLE_UNITS))
    ctx = _Context(frame, angle_unit)
    start = _position(ctx, f, "start", np.zeros(3))
    start_yaw = _angle(ctx, f, "start_yaw", 0.0)
    ground_z = f.number("ground_z_m", 0.0)
    ground_down = -ground_z if frame is MissionFrame.PAPER_ZUP else ground_z
    home = None
    if f.has("home"):
        lat, lon, alt = f.vector("home", 3)
        if not -90 <= lat <= 90:
            raise f.error("home", f"latitude must be in [-90, 90] degrees, got {lat:g}")
        if not -180 <= lon <= 180:
            raise f.error("home", f"longitude must be in [-180, 180] degrees, got {lon:g}")
        home = (lat, lon, alt)
    ctx.pos, ctx.yaw = start.copy(), start_yaw
    if start[2] > ground_down + 1e-9:
        raise f.error("start", f"is {start[2] - ground_down:.3g} m below the ground (ground_z_m = {ground_z:g})")

    segments = []
    names: set[str] = set()
    for i, raw in enumerate(f.table_list("segment"), start=1):
        head = MissionFields(raw, source, f"{prefix}segment #{i}: ")
        kind = head.string("type", choices=SEGMENT_TYPES)
        seg_name = head.string("name", kind)
        if seg_name in names:
            if head.has("name"):
                raise head.error("name", f"{seg_name!r} is already the name of an earlier segment; expected unique names")
            k = 2
            while f"{kind}-{k}" in names:
                k += 1
            seg_name = f"{kind}-{k}"
        names.add(seg_name)
        sf = MissionFields(raw, source, f"{prefix}segment #{i} ({seg_name}): ")
        sf.raw("type"), sf.raw("name", None)
        segment: Segment
        try:
            if kind == "land":
                segment = _vertical(ctx, sf, seg_name, climb=False, ground_down_m=ground_down)
            else:
                segment = _BUILDERS[kind](ctx, sf, seg_name)
        except ValueError as exc:
            if isinstance(exc, MissionFormatError):
                raise
            raise MissionFormatError(f"{source}: {prefix}segment #{i} ({seg_name}): {exc}") from None
        sf.reject_unknown()
        _check_above_ground(segment, ground_down, f"{source}: {prefix}segment #{i} ({seg_name})", ctx.t_s)
        segments.append(segment)
        ctx.t_s += segment.duration_s
        end = segment.end_reference
        ctx.pos, ctx.yaw = end.pos_ned_m.copy(), end.yaw_rad
    f.reject_unknown()
    return ParsedMission(name, description, Sequence(segments), home, tuple(start.tolist()), start_yaw)


def _lowest_down_m(segment: Any) -> float | None:
    """The segment's largest NED down coordinate where it follows from the geometry, else None.

    Straight pieces and blending arcs stay within their corner points; a helix is monotone in
    height.
    """
    if isinstance(segment, Hold):
        return float(segment.pos_ned_m[2])
    if isinstance(segment, (Line, Helix)):
        return max(float(segment.start_reference.pos_ned_m[2]), float(segment.end_reference.pos_ned_m[2]))
    if isinstance(segment, Polygon):
        return float(segment.vertices_ned_m[:, 2].max())
    if isinstance(segment, WaypointLegs):
        return max([float(segment.start_ned_m[2])] + [w.pos_ned_m[2] for w in segment.waypoints])
    return None


def _check_above_ground(segment: Any, ground_down_m: float, where: str, t0_s: float) -> None:
    lowest = _lowest_down_m(segment)
    if lowest is not None and lowest <= ground_down_m + 1e-6:
        return
    s = sample(segment, GROUND_CHECK_DT_S)
    depth = s.pos_ned_m[:, 2] - ground_down_m
    k = int(np.argmax(depth))
    if depth[k] > 1e-6:
        raise MissionFormatError(
            f"{where}: goes {depth[k]:.3g} m below the ground at t = {t0_s + s.t_s[k]:.3g} s; "
            f"expected the path to stay at or above the ground (ground_z_m)"
        )


def read_parametric(path: Path, table: dict[str, Any]) -> ParsedMission:
    """A standalone mission file: only a ``[mission]`` table at the top level."""
    f = MissionFields(table, path.name)
    if not f.has("mission"):
        scenario = table.get("scenario")
        hint = ""
        if isinstance(scenario, dict) and isinstance(scenario.get("mission"), str):
            hint = f" (this looks like a scenario file: its mission is {scenario['mission']!r})"
        else:
            near = near_name("mission", table)
            hint = f" (is [{near}] meant to be [mission]?)" if near else ""
        raise f.error("mission", f"missing; expected a [mission] table{hint}")
    mission_table = f.raw("mission")
    f.reject_unknown()  # first: a misspelt top-level table is named as such, not as missing fields
    return parse_mission_table(mission_table, path.name, "mission.", path.stem)
