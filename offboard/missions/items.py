"""MAVLink mission items, as ground-station files store them, and the trajectory they describe.

Both waypoint file kinds (QGC WPL 110 text and QGroundControl ``.plan`` JSON) are lists of
MISSION_ITEM fields: ``command``, ``frame``, ``param1..param4``, ``x`` (latitude), ``y``
(longitude), ``z`` (altitude), ``autocontinue``. ``ItemMission`` holds them with the home
position; ``trajectory_from_items`` turns them into a ``Sequence`` of trajectory segments, and
``items_from_waypoints`` goes the other way for round trips.

Understood commands (anything else is an error naming the command and the item):

======================== ====================================================================
MAV_CMD_NAV_WAYPOINT     fly to x, y, z; param1 hold (s), param2 acceptance radius = corner
                         blend distance (m, 0 = default 2 m), param4 yaw (deg, NaN = along path)
MAV_CMD_NAV_LOITER_TIME  fly to x, y, z (lat = lon = 0: stay here), stop, hold param1 seconds
MAV_CMD_NAV_TAKEOFF      climb vertically to z at the climb speed; param4 yaw (deg) reached at
                         the top; then fly to x, y if given (not 0, 0)
MAV_CMD_NAV_LAND         fly to x, y at the current height if given, stop, descend to z (the
                         ground, normally 0 relative) at the descent speed; param4 yaw (deg)
MAV_CMD_DO_CHANGE_SPEED  param1 speed type (0 air, 1 ground: cruise; 2 climb; 3 descent),
                         param2 speed m/s (-1 no change, -2 back to the default)
======================== ====================================================================

Frames: global ``MAV_FRAME_GLOBAL`` (0, AMSL altitude), ``MAV_FRAME_GLOBAL_RELATIVE_ALT``
(3, above home) and their ``_INT`` twins (5, 6; degrees in files) convert to local NED about
the home position (``geo.LocalProjection``); ``MAV_FRAME_LOCAL_NED`` (1) and
``MAV_FRAME_LOCAL_ENU`` (4, x east, y north, z up) are local metres about the local origin.
Terrain frames are refused (there is no terrain model). One mission uses global or local
frames, not both.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field

import numpy as np
from pymavlink import mavutil

from offboard.errors import MissionFormatError
from offboard.missions.geo import LocalProjection
from offboard.trajectory.segment import YawMode
from offboard.trajectory.sequence import Sequence
from offboard.trajectory.waypoints import DEFAULT_BLEND_RADIUS_M, CornerMode, VerticalMove, Waypoint, WaypointLegs

_MAV = mavutil.mavlink

NAV_WAYPOINT = _MAV.MAV_CMD_NAV_WAYPOINT  # 16
NAV_LOITER_TIME = _MAV.MAV_CMD_NAV_LOITER_TIME  # 19
NAV_LAND = _MAV.MAV_CMD_NAV_LAND  # 21
NAV_TAKEOFF = _MAV.MAV_CMD_NAV_TAKEOFF  # 22
DO_CHANGE_SPEED = _MAV.MAV_CMD_DO_CHANGE_SPEED  # 178
SUPPORTED_COMMANDS = (NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LAND, NAV_TAKEOFF, DO_CHANGE_SPEED)
NAV_COMMANDS = (NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LAND, NAV_TAKEOFF)

FRAME_GLOBAL = _MAV.MAV_FRAME_GLOBAL  # 0, altitude AMSL
FRAME_LOCAL_NED = _MAV.MAV_FRAME_LOCAL_NED  # 1
FRAME_MISSION = _MAV.MAV_FRAME_MISSION  # 2, no coordinates (DO_ commands)
FRAME_GLOBAL_RELATIVE_ALT = _MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT  # 3
FRAME_LOCAL_ENU = _MAV.MAV_FRAME_LOCAL_ENU  # 4
FRAME_GLOBAL_INT = _MAV.MAV_FRAME_GLOBAL_INT  # 5
FRAME_GLOBAL_RELATIVE_ALT_INT = _MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT  # 6
GLOBAL_FRAMES = (FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_INT, FRAME_GLOBAL_RELATIVE_ALT_INT)
AMSL_FRAMES = (FRAME_GLOBAL, FRAME_GLOBAL_INT)
LOCAL_FRAMES = (FRAME_LOCAL_NED, FRAME_LOCAL_ENU)

#: Defaults where a waypoint file says nothing, as PX4's multicopter parameters:
#: MPC_XY_CRUISE, MPC_TKO_SPEED, MPC_LAND_SPEED, MPC_ACC_HOR.
DEFAULT_CRUISE_SPEED_M_S = 5.0
DEFAULT_CLIMB_SPEED_M_S = 1.5
DEFAULT_DESCENT_SPEED_M_S = 0.7
DEFAULT_ACCEL_M_S2 = 3.0
#: Points farther than this from home are refused (swapped latitude/longitude, a 0/0 waypoint).
MAX_DISTANCE_FROM_HOME_M = 50_000.0


def command_name(command: int) -> str:
    """``MAV_CMD_...`` name of a command number (pymavlink's enum), or ``"command <n>"``."""
    entry = _MAV.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"command {command}"


def frame_name(frame: int) -> str:
    """MAVLink's name of a MAV_FRAME value ("frame N" for one it does not know)."""
    entry = _MAV.enums["MAV_FRAME"].get(frame)
    return entry.name if entry is not None else f"frame {frame}"


def _short(command: int) -> str:
    return command_name(command).removeprefix("MAV_CMD_")


@dataclass(frozen=True, eq=False)
class MissionItem:
    """One MISSION_ITEM as stored in a file (degrees for global x/y, metres otherwise).

    ``seq`` is its number in the file (home = 0) and ``where`` locates it for messages
    (``"line 5 (item 4)"``); neither is compared. NaN parameters (MAVLink's "unchanged")
    compare equal to each other, so items read back from a file equal the ones written.
    """

    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float
    autocontinue: bool = True
    seq: int = field(default=0, compare=False)
    where: str = field(default="", compare=False)

    def _key(self) -> tuple:
        numbers = tuple("nan" if math.isnan(v) else v for v in (*self.params, self.x, self.y, self.z))
        return (self.command, self.frame, numbers, self.autocontinue)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MissionItem):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


@dataclass(frozen=True)
class ItemMission:
    """Mission items and their home, as read from (or written to) a waypoint file.

    Attributes
    ----------
    home : MissionItem
        Item 0 of a QGC WPL file / the planned home of a ``.plan``: a NAV_WAYPOINT whose
        position is the origin of the local NED frame (global frame: lat, lon, AMSL altitude).
    items : tuple of MissionItem
        The mission proper, without the home.
    source : str
        File name, for messages.
    cruise_speed_m_s : float or None
        The file's cruise speed (``.plan`` ``hoverSpeed``), if it has one.
    """

    home: MissionItem
    items: tuple[MissionItem, ...]
    source: str = ""
    cruise_speed_m_s: float | None = None

    @property
    def is_global(self) -> bool:
        """Whether the mission's home is geodetic (a global frame)."""
        return self.home.frame in GLOBAL_FRAMES

    @property
    def home_global(self) -> tuple[float, float, float] | None:
        """(lat deg, lon deg, alt m AMSL) of home, or None for a local-frame mission."""
        return (self.home.x, self.home.y, self.home.z) if self.is_global else None


def _err(mission: ItemMission, item: MissionItem, field_name: str, message: str) -> MissionFormatError:
    return MissionFormatError(f"{mission.source}: {item.where}: {field_name}: {message}")


class _Converter:
    """Item positions in local NED, with the checks that need the home."""

    def __init__(self, mission: ItemMission) -> None:
        self.m = mission
        home = mission.home
        if home.command != NAV_WAYPOINT:
            raise _err(mission, home, "command", f"the home item must be MAV_CMD_NAV_WAYPOINT, got {command_name(home.command)}")
        self._check_finite(home)
        if home.frame in GLOBAL_FRAMES:
            if home.frame not in AMSL_FRAMES:
                raise _err(
                    mission, home, "frame",
                    f"the home item must have an AMSL altitude (MAV_FRAME_GLOBAL), got {frame_name(home.frame)}",
                )
            self._check_latlon(home)
            self.proj: LocalProjection | None = LocalProjection(home.x, home.y, home.z)
            self.home_ned = np.zeros(3)
        elif home.frame in LOCAL_FRAMES:
            self.proj = None
            self.home_ned = self._local(home)
        else:
            raise _err(mission, home, "frame", f"expected a global or local frame for the home item, got {frame_name(home.frame)}")

    def _check_finite(self, item: MissionItem) -> None:
        global_item = item.frame in GLOBAL_FRAMES
        for name, label, value in (("x", "latitude", item.x), ("y", "longitude", item.y), ("z", "altitude", item.z)):
            if not math.isfinite(value):
                field_name = f"{name} ({label})" if global_item else name
                raise _err(self.m, item, field_name, f"expected a number, got {value}")

    def _check_latlon(self, item: MissionItem) -> None:
        if not -90.0 <= item.x <= 90.0:
            raise _err(self.m, item, "x (latitude)", f"expected degrees in [-90, 90], got {item.x:g}")
        if not -180.0 <= item.y <= 180.0:
            raise _err(self.m, item, "y (longitude)", f"expected degrees in [-180, 180], got {item.y:g}")

    @staticmethod
    def _local(item: MissionItem) -> np.ndarray:
        if item.frame == FRAME_LOCAL_ENU:
            return np.array([item.y, item.x, -item.z])
        return np.array([item.x, item.y, item.z])

    def position(self, item: MissionItem, here_ned: np.ndarray, zero_means_here: bool) -> np.ndarray:
        """NED position of a navigation item; lat = lon = 0 (or x = y = 0 locally) keeps ``here``."""
        global_item = item.frame in GLOBAL_FRAMES
        if item.frame not in GLOBAL_FRAMES + LOCAL_FRAMES:
            raise _err(
                self.m, item, "frame",
                f"{frame_name(item.frame)} ({item.frame}) is not supported; expected a global (0, 3, 5, 6) or local (1, 4) frame",
            )
        if global_item != (self.proj is not None):
            want = "a global frame, like the home item" if self.proj is not None else "a local frame, like the home item"
            raise _err(self.m, item, "frame", f"expected {want}, got {frame_name(item.frame)}")
        self._check_finite(item)
        if global_item:
            assert self.proj is not None
            if zero_means_here and item.x == 0.0 and item.y == 0.0:
                north, east = float(here_ned[0]), float(here_ned[1])
            else:
                self._check_latlon(item)
                north, east = self.proj.north_east(item.x, item.y)
                distance = math.hypot(north, east)
                if distance > MAX_DISTANCE_FROM_HOME_M:
                    raise _err(
                        self.m, item, "x, y (latitude, longitude)",
                        f"point is {distance / 1000:.0f} km from home; expected a local mission "
                        f"(< {MAX_DISTANCE_FROM_HOME_M / 1000:.0f} km; latitude and longitude swapped?)",
                    )
            down = -(item.z - self.proj.alt_m) if item.frame in AMSL_FRAMES else -item.z
            pos = np.array([north, east, down])
        else:
            pos = self._local(item)
            if zero_means_here and item.x == 0.0 and item.y == 0.0:
                pos[:2] = here_ned[:2]
        if pos[2] > self.home_ned[2] + 1e-6:
            below = pos[2] - self.home_ned[2]
            raise _err(
                self.m, item, "z (altitude)",
                f"point is {below:.3g} m below home, underground; expected an altitude at or above home",
            )
        return pos


def _param(mission: ItemMission, item: MissionItem, k: int, meaning: str, *, nan_ok: bool = False) -> float:
    value = item.params[k - 1]
    if math.isnan(value) and not nan_ok:
        raise _err(mission, item, f"param{k} ({meaning})", "expected a number, got NaN")
    if math.isinf(value):
        raise _err(mission, item, f"param{k} ({meaning})", f"expected a finite number, got {value}")
    return value


def trajectory_from_items(
    mission: ItemMission,
    cruise_speed_m_s: float | None = None,
    accel_m_s2: float = DEFAULT_ACCEL_M_S2,
    climb_speed_m_s: float = DEFAULT_CLIMB_SPEED_M_S,
    descent_speed_m_s: float = DEFAULT_DESCENT_SPEED_M_S,
    blend_radius_m: float = DEFAULT_BLEND_RADIUS_M,
) -> Sequence:
    """The trajectory a multicopter flies for these items, from rest at home (NED, module doc).

    Consecutive NAV_WAYPOINT/NAV_LOITER_TIME items make one ``WaypointLegs`` segment (corners
    blended by each waypoint's acceptance radius, yaw per waypoint if any waypoint gives one,
    else along the path); NAV_TAKEOFF and NAV_LAND make ``VerticalMove`` segments.

    Parameters
    ----------
    mission : ItemMission
    cruise_speed_m_s : float or None
        Initial cruise speed; None: the file's, else ``DEFAULT_CRUISE_SPEED_M_S``.
    accel_m_s2, climb_speed_m_s, descent_speed_m_s, blend_radius_m : float
        Limits and the default corner blend distance.

    Raises
    ------
    MissionFormatError
        Unsupported command or frame, bad parameter, point underground, nothing to fly.
    """
    conv = _Converter(mission)
    default_cruise = cruise_speed_m_s or mission.cruise_speed_m_s or DEFAULT_CRUISE_SPEED_M_S
    cruise = default_cruise
    climb, descent = climb_speed_m_s, descent_speed_m_s
    pos = conv.home_ned.copy()
    yaw = 0.0
    segments: list = []
    pending: list[Waypoint] = []
    pending_names: list[str] = []

    def flush() -> None:
        nonlocal pos, yaw
        if not pending:
            return
        yaw_mode = YawMode.WAYPOINT if any(w.yaw_rad is not None for w in pending) else YawMode.ALONG_PATH
        name = f"waypoints {pending_names[0]}" if len(pending) == 1 else f"waypoints {pending_names[0]}..{pending_names[-1]}"
        try:
            legs = WaypointLegs(
                pos, pending, pending[0].speed_m_s or cruise, accel_m_s2, CornerMode.BLEND, blend_radius_m, yaw_mode, yaw,
                name=name,
            )
        except ValueError:  # only holds at the start point with no time: nothing to fly
            pending.clear()
            pending_names.clear()
            return
        segments.append(legs)
        end = legs.end_reference
        pos, yaw = end.pos_ned_m.copy(), end.yaw_rad
        pending.clear()
        pending_names.clear()

    def vertical(to_down: float, speed: float, end_yaw: float | None, name: str) -> None:
        nonlocal pos, yaw
        flush()
        if abs(to_down - pos[2]) < 1e-9:
            return
        move = VerticalMove(pos, to_down, speed, accel_m_s2, yaw, name=name, end_yaw_rad=end_yaw)
        segments.append(move)
        end = move.end_reference
        pos, yaw = end.pos_ned_m.copy(), end.yaw_rad

    def here() -> np.ndarray:
        return np.array(pending[-1].pos_ned_m) if pending else pos

    for item in mission.items:
        cmd = item.command
        if cmd not in SUPPORTED_COMMANDS:
            hint = ""
            if cmd == _MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                hint = " (its path depends on the autopilot's return altitude: use NAV_WAYPOINT to home, then NAV_LAND)"
            raise _err(
                mission, item, "command",
                f"{command_name(cmd)} ({cmd}) is not supported; expected one of "
                + ", ".join(f"{_short(c)} ({c})" for c in SUPPORTED_COMMANDS)
                + hint,
            )
        if cmd == DO_CHANGE_SPEED:
            kind = _param(mission, item, 1, "speed type")
            speed = _param(mission, item, 2, "speed")
            if speed == -1.0:
                continue
            if speed == -2.0:
                speed = {0: default_cruise, 1: default_cruise, 2: climb_speed_m_s, 3: descent_speed_m_s}.get(int(kind), default_cruise)
            elif not speed > 0.0:
                raise _err(mission, item, "param2 (speed)", f"expected a speed > 0 m/s (or -1: no change, -2: default), got {speed:g}")
            if kind in (0.0, 1.0):
                cruise = speed
            elif kind == 2.0:
                climb = speed
            elif kind == 3.0:
                descent = speed
            else:
                raise _err(mission, item, "param1 (speed type)", f"expected 0 (air), 1 (ground), 2 (climb) or 3 (descent), got {kind:g}")
            continue

        label = f"item{item.seq}"
        if cmd == NAV_TAKEOFF:
            yaw_deg = _param(mission, item, 4, "yaw", nan_ok=True)
            target = conv.position(item, here(), zero_means_here=True)
            start = here()
            if target[2] > start[2] + 1e-9:
                raise _err(mission, item, "z (altitude)", f"take-off altitude is {target[2] - start[2]:.3g} m below the current position; expected a climb")
            vertical(target[2], climb, None if math.isnan(yaw_deg) else math.radians(yaw_deg), "takeoff")
            if math.hypot(*(target[:2] - pos[:2])) > 1e-6:
                pending.append(Waypoint(tuple(target), speed_m_s=cruise, stop=True, label=label))
                pending_names.append(str(item.seq))
            continue
        if cmd == NAV_LAND:
            yaw_deg = _param(mission, item, 4, "yaw", nan_ok=True)
            start = here()
            target = conv.position(item, start, zero_means_here=True)
            if target[2] < start[2] - 1e-9:
                raise _err(mission, item, "z (altitude)", f"landing altitude is {start[2] - target[2]:.3g} m above the current position; expected the ground")
            if math.hypot(*(target[:2] - start[:2])) > 1e-6:
                pending.append(Waypoint((target[0], target[1], start[2]), speed_m_s=cruise, stop=True, label=label))
                pending_names.append(str(item.seq))
            vertical(target[2], descent, None if math.isnan(yaw_deg) else math.radians(yaw_deg), "land")
            continue
        # NAV_WAYPOINT, NAV_LOITER_TIME
        if cmd == NAV_WAYPOINT:
            hold = _param(mission, item, 1, "hold time")
            accept = _param(mission, item, 2, "acceptance radius")
            yaw_deg = _param(mission, item, 4, "yaw", nan_ok=True)
            if hold < 0:
                raise _err(mission, item, "param1 (hold time)", f"expected seconds >= 0, got {hold:g}")
            if accept < 0:
                raise _err(mission, item, "param2 (acceptance radius)", f"expected metres >= 0, got {accept:g}")
            target = conv.position(item, here(), zero_means_here=False)
            wp = Waypoint(
                tuple(target),
                yaw_rad=None if math.isnan(yaw_deg) else math.radians(yaw_deg),
                hold_s=hold,
                speed_m_s=cruise,
                blend_radius_m=accept if accept > 0 else None,
                label=label,
            )
        else:
            hold = _param(mission, item, 1, "loiter time")
            if hold < 0:
                raise _err(mission, item, "param1 (loiter time)", f"expected seconds >= 0, got {hold:g}")
            target = conv.position(item, here(), zero_means_here=True)
            wp = Waypoint(tuple(target), hold_s=hold, speed_m_s=cruise, stop=True, label=label)
        pending.append(wp)
        pending_names.append(str(item.seq))
    flush()
    if not segments:
        raise MissionFormatError(f"{mission.source}: no navigation item moves the vehicle; expected at least one waypoint, take-off or landing")
    return Sequence(segments)


def items_from_waypoints(
    waypoints: SequenceABC[Waypoint],
    home: tuple[float, float, float] | None,
    cruise_speed_m_s: float,
    source: str = "",
) -> ItemMission:
    """NAV_WAYPOINT items (with DO_CHANGE_SPEED where the speed changes) for waypoints from home.

    Parameters
    ----------
    waypoints : sequence of Waypoint
        NED positions about home; yaw, hold, speed and blend radius are kept.
    home : (lat deg, lon deg, alt m AMSL) or None
        Global home: items in MAV_FRAME_GLOBAL_RELATIVE_ALT. None: MAV_FRAME_LOCAL_NED items
        about a local home at the origin.
    cruise_speed_m_s : float
        The speed in force at the start (stored as the mission's cruise speed).
    """
    proj = LocalProjection(*home) if home is not None else None
    if home is not None:
        home_item = MissionItem(NAV_WAYPOINT, FRAME_GLOBAL, (0.0, 0.0, 0.0, 0.0), home[0], home[1], home[2])
    else:
        home_item = MissionItem(NAV_WAYPOINT, FRAME_LOCAL_NED, (0.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0)
    items: list[MissionItem] = []
    speed = cruise_speed_m_s
    for w in waypoints:
        if w.speed_m_s is not None and w.speed_m_s != speed:
            speed = w.speed_m_s
            items.append(MissionItem(DO_CHANGE_SPEED, FRAME_MISSION, (1.0, speed, -1.0, 0.0), 0.0, 0.0, 0.0, seq=len(items) + 1))
        north, east, down = w.pos_ned_m
        params = (w.hold_s, w.blend_radius_m or 0.0, 0.0, math.nan if w.yaw_rad is None else math.degrees(w.yaw_rad))
        if proj is not None:
            lat, lon, _ = proj.global_from_ned(north, east, down)
            items.append(MissionItem(NAV_WAYPOINT, FRAME_GLOBAL_RELATIVE_ALT, params, lat, lon, -down, seq=len(items) + 1))
        else:
            items.append(MissionItem(NAV_WAYPOINT, FRAME_LOCAL_NED, params, north, east, down, seq=len(items) + 1))
    return ItemMission(home_item, tuple(items), source, cruise_speed_m_s)
