"""PX4's navigator in miniature: which position setpoint Mission, Return, Reposition and Orbit fly
now. Pure: no sockets, no clock (it is given the time and the vehicle's state).

The autopilot asks ``Navigator.setpoint()`` in those modes and flies it through the plant's
position controller (``PositionTask``, sitl_plant/inner_loops.py). Legs are straight lines flown
by a point that moves along them at the cruise speed (accelerating at ``MPC_ACC_HOR`` reached
at ``MPC_JERK_AUTO``, braking at half of it, climbing at most ``MPC_Z_V_AUTO_UP``, descending at most ``MPC_Z_V_AUTO_DN``)
with its velocity as feed-forward: PX4 flies a jerk-limited trajectory with corner cutting, so
times differ by seconds per leg (docs/parity/mission.md).

Mission items (PX4 ``src/modules/navigator/mission_block.cpp``, ``mission.cpp``):

- NAV_TAKEOFF: climb vertically at ``MPC_TKO_SPEED`` (from the ground after the autopilot's
  spool-up and takeoff ramp) to the item's altitude (at least
  ``MIS_TAKEOFF_ALT``); reached within ``NAV_MC_ALT_RAD`` of it. A mission started on the ground
  whose current item is not a takeoff first climbs to ``MIS_TAKEOFF_ALT``.
- NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LOITER_UNLIM: fly there; reached within the acceptance radius
  (param2 of a waypoint when > 0, else ``NAV_ACC_RAD``) horizontally and ``NAV_MC_ALT_RAD``
  vertically, with a given yaw (param4) within ``MIS_YAW_ERR``; then hold param1 seconds
  (LOITER_UNLIM: for ever). Yaw NaN: face along the leg.
- DO_CHANGE_SPEED: param2 > 0 is the new cruise speed, -2 back to ``MPC_XY_CRUISE``.
- NAV_LAND: fly over the point at the current height, then descend (``MPC_Z_V_AUTO_DN`` above
  ``MPC_LAND_ALT1``, ``MPC_LAND_SPEED`` below ``MPC_LAND_ALT2``, between them interpolated);
  reached on the ground (the autopilot then disarms after ``COM_DISARM_LAND``).
- NAV_RETURN_TO_LAUNCH: the mission hands over to Return.
- Other DO items: taken as done at once. After the last item the vehicle holds where it is
  (PX4 loiters at the last item unless the mission landed).

MISSION_ITEM_REACHED names the item completed last (items completed in the same step: the last
of them, as PX4's mission_result carries one ``seq_reached``: after a takeoff followed by
DO_CHANGE_SPEED, PX4 reports 1 and never 0).

Return (RTL_TYPE 0, ``rtl_direct.cpp``): climb over the current point to the return altitude
(``return_altitude_down_m``: RTL_RETURN_ALT, lowered by the RTL_CONE_ANG cone within
RTL_MIN_DIST of home), fly home, descend to ``RTL_DESCEND_ALT``, wait ``RTL_LAND_DELAY`` (< 0: for ever), land.
Reposition (MAV_CMD_DO_REPOSITION): fly to the point at param1 m/s (else the cruise speed, which
MAV_CMD_DO_CHANGE_SPEED sets) and hold there; from the ground it takes off on the way. Orbit (MAV_CMD_DO_ORBIT): circle the centre at radius |param1| (> 0 clockwise) at
param2 m/s tangential speed (NaN: 1 m/s), the nose to the centre, as PX4's FlightTaskOrbit does:
the radius within [1 m, MC_ORBIT_RAD_MAX], the speed within MPC_XY_VEL_MAX and lowered to
sqrt(a r) when v^2 >= a r (``ORBIT_ACC_MAX_M_S2``, its ``_acceleration_max``: the radius is kept,
the speed given up); it approaches the circle first, then flies a velocity setpoint only (no
horizontal position): tangential v plus (r - distance) towards the circle, with the centripetal
v^2 / r as acceleration feed-forward. A vehicle with drag (PX4's SIH) therefore circles slower
than asked: PX4 v1.16 SIH flew 1.37 m/s when asked 2 m/s on 5 m (docs/parity/mission.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from sitl_plant.mission import (
    DO_CHANGE_SPEED,
    NAV_LAND,
    NAV_LOITER_TIME,
    NAV_LOITER_UNLIM,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    MissionItem,
)
from sitl_plant.params import ParamTable

EARTH_RADIUS_M = 6_371_000.0  # PX4's CONSTANTS_RADIUS_OF_EARTH (the plant's codec uses the same)
_POSITION_COMMANDS = (NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LOITER_UNLIM, NAV_TAKEOFF, NAV_LAND)
DEFAULT_ORBIT_SPEED_M_S = 1.0  # DO_ORBIT param2 NaN or 0 (PX4's orbit default; not measured)
DEFAULT_ORBIT_RADIUS_M = 10.0  # DO_ORBIT param1 NaN or 0 (not measured)
ORBIT_ACC_MAX_M_S2 = 2.0  # FlightTaskOrbit.hpp _acceleration_max: v^2 < a r, else v = sqrt(a r)
ORBIT_RADIUS_MIN_M = 1.0  # FlightTaskOrbit.hpp _radius_min
MIN_STRETCH = 0.2  # the slowest a leg's point moves for a lagging vehicle (``Navigator._stretch``)
ORBIT_ON_CIRCLE_M = 1.0  # the approach ends within this of the circle (FlightTaskOrbit's _horizontal_acceptance_radius)


def orbit_limits(radius_m: float, speed_m_s: float, radius_max_m: float, speed_max_m_s: float) -> tuple[float, float]:
    """PX4's ``FlightTaskOrbit::_sanitizeParams``: |radius| within [1, MC_ORBIT_RAD_MAX], |speed|
    within MPC_XY_VEL_MAX, and where v^2 >= a r the speed lowered to sqrt(a r) (a small radius is
    safer than a high speed). Signs (the direction) are kept."""
    sign = -1.0 if radius_m < 0 else 1.0
    r = min(max(abs(radius_m), ORBIT_RADIUS_MIN_M), radius_max_m)
    v = min(abs(speed_m_s), speed_max_m_s)
    if v * v >= ORBIT_ACC_MAX_M_S2 * r:
        v = math.sqrt(ORBIT_ACC_MAX_M_S2 * r)
    return sign * r, v


def corner_speed_m_s(start: tuple[float, ...], corner: tuple[float, ...], nxt: tuple[float, ...], accel_m_s2: float, radius_m: float) -> float:
    """The speed PX4 passes a waypoint at on its way to the next (v1.16
    ``math::trajectory::computeMaxSpeedInWaypoint``): sqrt(a d tan(alpha / 2)), ``alpha`` the
    angle between the two legs seen from the corner (180 degrees: straight on, 0: back),
    ``a`` MPC_XY_TRAJ_P * MPC_ACC_HOR, ``d`` the waypoint's acceptance radius. A 90-degree corner
    with NAV_ACC_RAD 2 m: 1.7 m/s (PX4 v1.16 SIH flew 1.0-1.5 m/s through the bundled missions'
    corners, docs/parity/mission.md)."""
    un, ue = corner[0] - start[0], corner[1] - start[1]
    wn, we = corner[0] - nxt[0], corner[1] - nxt[1]
    lu, lw = math.hypot(un, ue), math.hypot(wn, we)
    if lu < 1e-6 or lw < 1e-6:
        return 0.0
    alpha = math.acos(min(max((un * wn + ue * we) / (lu * lw), -1.0), 1.0))
    alpha = min(alpha, math.pi - 1e-6)
    return math.sqrt(max(accel_m_s2 * radius_m * math.tan(alpha / 2.0), 0.0))


def geodetic_to_ned(lat_deg: float, lon_deg: float, origin_lat_deg: float, origin_lon_deg: float) -> tuple[float, float]:
    """North, east (m) of a point about the origin: PX4's azimuthal equidistant projection
    (``MapProjection::project``), the inverse of ``codec.ned_to_geodetic``."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    lat0, lon0 = math.radians(origin_lat_deg), math.radians(origin_lon_deg)
    cos_d_lon = math.cos(lon - lon0)
    arg = min(max(math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * cos_d_lon, -1.0), 1.0)
    c = math.acos(arg)
    k = c / math.sin(c) if abs(c) > 1e-12 else 1.0
    north = k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * cos_d_lon) * EARTH_RADIUS_M
    east = k * math.cos(lat) * math.sin(lon - lon0) * EARTH_RADIUS_M
    return north, east


@dataclass(frozen=True)
class Frame:
    """Where the local NED frame is: its origin on the globe and the home position in it."""

    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_amsl_m: float
    home_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_ned(self, lat_deg: float, lon_deg: float, alt_m: float, relative: bool) -> tuple[float, float, float]:
        """A global point (altitude AMSL, or above home when ``relative``) in local NED (m)."""
        n, e = geodetic_to_ned(lat_deg, lon_deg, self.origin_lat_deg, self.origin_lon_deg)
        down = self.home_ned_m[2] - alt_m if relative else self.origin_alt_amsl_m - alt_m
        return n, e, down


@dataclass(frozen=True)
class NavSetpoint:
    """What to fly: a position (None: that axis is not held) with a velocity feed-forward and a
    yaw; ``descend_m_s`` descends at that speed instead of holding the height (landing);
    ``max_climb_m_s`` is the take-off's climb speed (from the ground the autopilot ramps up to it
    after spool-up: PX4's takeoff handling, ``Autopilot._takeoff_climb_limit``); ``takeoff``: a
    vertical take-off to ``pos_ned_m``'s height (the climb slows near it). ``landing``: idle once
    on the ground."""

    pos_ned_m: tuple[float, float, float]
    yaw_rad: float
    vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    descend_m_s: float | None = None
    max_climb_m_s: float | None = None
    takeoff: bool = False
    landing: bool = False
    #: False: the horizontal position is not held, ``vel_ned_m_s`` is the horizontal velocity
    #: setpoint (Orbit, as PX4's); ``pos_ned_m`` then says where a vehicle keeping the speed is
    hold_xy: bool = True
    acc_ff_ne_m_s2: tuple[float, float] = (0.0, 0.0)  # acceleration feed-forward (Orbit's centripetal)


@dataclass
class _Leg:
    """A point moving from ``start`` to ``end`` at up to ``speed`` (m/s), braking to stop there."""

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    speed: float
    up_max: float
    down_max: float
    accel: float
    jerk: float = math.inf
    s: float = 0.0
    v: float = 0.0
    a: float = 0.0
    v_end: float = 0.0  # the speed to pass the end at (a waypoint flown through), 0: stop there

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def _direction(self) -> tuple[float, float, float]:
        n = self.length
        if n < 1e-9:
            return (0.0, 0.0, 0.0)
        (n0, e0, d0), (n1, e1, d1) = self.start, self.end
        return ((n1 - n0) / n, (e1 - e0) / n, (d1 - d0) / n)

    def step(self, dt: float) -> None:
        d = self._direction()
        v_max = self.speed
        if d[2] < -1e-6:
            v_max = min(v_max, self.up_max / -d[2])
        elif d[2] > 1e-6:
            v_max = min(v_max, self.down_max / d[2])
        remaining = self.length - self.s
        # PX4's trajectories are jerk-limited (MPC_JERK_AUTO): the acceleration ramps up, and
        # braking is planned at half MPC_ACC_HOR, which an S-curve averages over its stop
        v_brake = math.sqrt(self.v_end * self.v_end + self.accel * max(remaining, 0.0))
        self.a = min(self.a + self.jerk * dt, self.accel)
        v = min(self.v + self.a * dt, v_max, v_brake)
        if v >= v_max - 1e-9:
            self.a = 0.0
        self.v = max(0.0, v)
        self.s = min(self.s + self.v * dt, self.length)
        if self.s >= self.length:
            self.v = 0.0  # at the end: it waits there (a waypoint flown through has been left by now)

    def point(self) -> tuple[float, float, float]:
        d = self._direction()
        return (self.start[0] + self.s * d[0], self.start[1] + self.s * d[1], self.start[2] + self.s * d[2])

    def velocity(self) -> tuple[float, float, float]:
        d = self._direction()
        return (self.v * d[0], self.v * d[1], self.v * d[2])


@dataclass
class _Run:
    """The state of the item (or the Return phase) being flown."""

    phase: str = ""
    leg: _Leg | None = None
    hold_until_s: float | None = None
    target: tuple[float, float, float] | None = None
    yaw: float | None = None
    started: bool = False


@dataclass
class Navigator:
    """Mission, Return, Reposition and Orbit for one vehicle.

    Parameters
    ----------
    params : mapping of parameter names to values (the plant's ParamTable), read at every use.
    """

    params: ParamTable
    items: list[MissionItem] = field(default_factory=list)
    current_seq: int = 0
    reached_seq: int = -1
    reached_count: int = 0  # grows with every MISSION_ITEM_REACHED to send
    finished: bool = False
    frame: Frame = field(default_factory=lambda: Frame(0.0, 0.0, 0.0))
    _run: _Run = field(default_factory=_Run)
    _activity: str = ""  # "mission" | "rtl" | "reposition" | "orbit" | ""
    _last_s: float | None = None
    _pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _yaw: float = 0.0
    _yaw_sp: float = 0.0
    _landed: bool = True
    _cruise: float | None = None
    _orbit: tuple[float, float, float, float, float] | None = None  # centre n, e, down, radius (signed), speed
    _goto: tuple[tuple[float, float, float], float, float | None] | None = None
    _orbit_vel: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _orbit_acc: tuple[float, float] = (0.0, 0.0)
    _from_ground: bool = False
    _carry_m_s: float = 0.0  # the speed the last mission leg ended with: the next starts with it
    wants_rtl: bool = False

    def _p(self, name: str) -> float:
        return float(self.params[name])

    # -- what the autopilot tells it --------------------------------------------------------------

    def load(self, items: list[MissionItem], current_seq: int = 0) -> None:
        """A new mission (after an upload or a clear): it starts from ``current_seq``."""
        self.items = list(items)
        self.current_seq = current_seq if 0 <= current_seq < len(items) else 0
        self.reached_seq = -1
        self.finished = False
        self._run = _Run()

    def set_current(self, seq: int) -> None:
        """Go on from mission item ``seq`` (MISSION_SET_CURRENT; out of range: ignored), from its start."""
        if 0 <= seq < len(self.items):
            self.current_seq = seq
            self.finished = False
            self._run = _Run()

    def observe(self, pos_ned_m: tuple[float, float, float], yaw_rad: float, landed: bool) -> None:
        """Where the vehicle is now (NED, m), its heading and whether it has landed."""
        self._pos = (float(pos_ned_m[0]), float(pos_ned_m[1]), float(pos_ned_m[2]))
        self._yaw = yaw_rad
        self._landed = landed

    def start(self, activity: str, now_s: float) -> None:
        """Begin flying ``activity`` ("mission", "rtl") from where the vehicle is."""
        self._activity = activity
        self._last_s = now_s
        self._yaw_sp = self._yaw
        self._run = _Run()
        self._carry_m_s = 0.0
        self.wants_rtl = False
        if activity == "mission":
            if self.finished:  # PX4 restarts a finished mission from its first item
                self.current_seq, self.finished, self.reached_seq = 0, False, -1
            self._cruise = None

    def stop(self) -> None:
        """End the activity (mission, return, reposition, orbit): nothing is navigated."""
        self._activity = ""
        self._orbit = None
        self._goto = None

    def reposition(self, target: tuple[float, float, float], speed_m_s: float, yaw_rad: float | None, now_s: float, *, from_ground: bool = False) -> None:
        """Fly to ``target`` (NED, m) at ``speed_m_s`` and hold there, at heading ``yaw_rad`` when one is
        given (MAV_CMD_DO_REPOSITION; ``from_ground``: climbing from the ground at the take-off speed).
        """
        cruise = self._cruise
        self.start("reposition", now_s)
        self._cruise = cruise  # a DO_CHANGE_SPEED before it holds
        self._goto = (target, speed_m_s, yaw_rad)
        self._from_ground = from_ground
        self.update(now_s)  # the leg exists at once: the setpoint is there before the next step

    def change_speed(self, speed_m_s: float) -> None:
        """DO_CHANGE_SPEED: the cruise speed of the legs to come (> 0), or MPC_XY_CRUISE (-2)."""
        if math.isfinite(speed_m_s) and speed_m_s > 0:
            self._cruise = speed_m_s
        elif speed_m_s == -2:
            self._cruise = None

    def orbit(self, centre: tuple[float, float, float], radius_m: float, speed_m_s: float, now_s: float) -> None:
        """Circle ``centre`` at ``radius_m`` (> 0 clockwise) and ``speed_m_s``, after PX4's limits
        (``orbit_limits``)."""
        self.start("orbit", now_s)
        radius_m, speed_m_s = orbit_limits(radius_m, speed_m_s, self._p("MC_ORBIT_RAD_MAX"), self._p("MPC_XY_VEL_MAX"))
        self._orbit = (centre[0], centre[1], centre[2], radius_m, speed_m_s)
        self.update(now_s)

    @property
    def activity(self) -> str:
        """What is navigated: "mission", "rtl", "reposition", "orbit", ... or "" (nothing)."""
        return self._activity

    # -- time ------------------------------------------------------------------------------------

    def update(self, now_s: float) -> None:
        """Advance the active leg and the item logic to ``now_s``."""
        if not self._activity:
            return
        dt = 0.0 if self._last_s is None else max(0.0, now_s - self._last_s)
        self._last_s = now_s
        if self._activity == "mission":
            self._mission_step(now_s, dt)
        elif self._activity == "rtl":
            self._rtl_step(now_s, dt)
        elif self._activity == "reposition":
            self._goto_step(dt)
        elif self._activity == "orbit":
            self._orbit_step(dt)
        self._turn(dt)

    def setpoint(self) -> NavSetpoint | None:
        """What to fly now; None when nothing is active (the autopilot holds)."""
        r = self._run
        if not self._activity:
            return None
        if self._activity == "orbit" and self._orbit is not None and r.target is not None:
            if r.phase == "approach":
                return NavSetpoint(r.target, self._yaw_sp)
            return NavSetpoint(r.target, self._yaw_sp, self._orbit_vel, hold_xy=False, acc_ff_ne_m_s2=self._orbit_acc)
        if r.phase == "land":
            assert r.target is not None, "a landing has its target"
            return NavSetpoint((r.target[0], r.target[1], self._pos[2]), self._yaw_sp, descend_m_s=self._land_speed(), landing=True)
        if r.phase == "takeoff":
            assert r.target is not None, "a take-off has its target"
            return NavSetpoint(r.target, self._yaw_sp, max_climb_m_s=self._p("MPC_TKO_SPEED"), takeoff=True)
        if r.leg is not None:
            climb = self._p("MPC_TKO_SPEED") if self._activity == "reposition" and self._from_ground else None
            return NavSetpoint(r.leg.point(), self._yaw_sp, r.leg.velocity(), max_climb_m_s=climb)
        if r.target is not None:
            return NavSetpoint(r.target, self._yaw_sp)
        return None

    # -- mission ---------------------------------------------------------------------------------

    def _mission_step(self, now_s: float, dt: float) -> None:
        r = self._run
        done: list[int] = []
        for _ in range(len(self.items) + 1):  # DO items complete at once: several in one step
            if self.finished or not self.items:
                if r.target is None:
                    self._hold_here()
                break
            item = self.items[self.current_seq]
            if not r.started:
                self._begin(item, now_s)
                r = self._run
            if r.leg is not None:
                r.leg.step(dt * self._stretch(r.leg))
                dt = 0.0
            if not self._item_complete(item, now_s):
                break
            done.append(item.seq)
            # PX4's trajectory keeps its speed from one leg to the next (a waypoint flown through)
            self._carry_m_s = r.leg.v if r.leg is not None else 0.0
            if item.command == NAV_RETURN_TO_LAUNCH:
                self.wants_rtl = True
            if self.current_seq + 1 < len(self.items):
                self.current_seq += 1
                self._run = r = _Run()
            else:
                self.finished = True
                if item.command != NAV_LAND:
                    self._hold_here()
                break
        if done:
            self.reached_seq = done[-1]
            self.reached_count += 1

    def _hold_here(self) -> None:
        self._run = _Run(phase="hold", target=self._pos, started=True)

    def _begin(self, item: MissionItem, now_s: float) -> None:
        r = _Run(started=True)
        self._run = r
        carry, self._carry_m_s = self._carry_m_s, 0.0
        c = item.command
        if c == DO_CHANGE_SPEED:
            self.change_speed(item.params[1])
            return
        if c not in _POSITION_COMMANDS:
            return
        lat, lon = item.lat_lon_deg()
        n, e, d = self.frame.to_ned(lat, lon, item.z if math.isfinite(item.z) else 0.0, item.relative_alt)
        if not math.isfinite(item.z):
            d = self._pos[2]  # no altitude given: the current one
        if c == NAV_TAKEOFF or (self._landed and c != NAV_LAND):
            # a take-off item, or a mission started on the ground: climb first (MIS_TAKEOFF_ALT)
            height = self._p("MIS_TAKEOFF_ALT")
            if c == NAV_TAKEOFF:
                height = max(self.frame.home_ned_m[2] - d, height)
            r.phase = "takeoff"
            r.target = (self._pos[0], self._pos[1], self.frame.home_ned_m[2] - height)
            return
        if c == NAV_LAND:
            r.phase = "to-land"
            r.target = (n, e, self._pos[2])
        else:
            r.phase = "goto"
            r.target = (n, e, d)
        r.yaw = math.radians(item.params[3]) if c == NAV_WAYPOINT and math.isfinite(item.params[3]) else None
        r.leg = self._leg(r.target)
        r.leg.v = min(carry, r.leg.speed)
        r.leg.v_end = self._fly_through_m_s(item, r.leg)

    def _fly_through_m_s(self, item: MissionItem, leg: _Leg) -> float:
        """The speed to pass ``item`` at (0: stop there), as PX4 v1.16 plans it (FlightTaskAuto's
        PositionSmoothing, ``corner_speed_m_s``): a waypoint without a hold time, followed (after
        DO items) by another waypoint or loiter more than its acceptance radius away, is flown
        through at the corner speed, at most the leg's speed."""
        hold = item.params[0] if math.isfinite(item.params[0]) else 0.0
        if item.command != NAV_WAYPOINT or hold > 0 or not item.autocontinue:
            return 0.0
        nxt = next((it for it in self.items[self.current_seq + 1:] if it.command in _POSITION_COMMANDS), None)
        if nxt is None or nxt.command not in (NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LOITER_UNLIM):
            return 0.0
        lat, lon = nxt.lat_lon_deg()
        after = self.frame.to_ned(lat, lon, nxt.z if math.isfinite(nxt.z) else 0.0, nxt.relative_alt)
        radius = item.params[1] if item.params[1] > 0 else self._p("NAV_ACC_RAD")
        if math.hypot(after[0] - leg.end[0], after[1] - leg.end[1]) <= radius:
            return 0.0
        accel = self._p("MPC_XY_TRAJ_P") * self._p("MPC_ACC_HOR")
        return min(corner_speed_m_s(leg.start, leg.end, after, accel, radius), leg.speed)

    def _leg(self, target: tuple[float, float, float], speed: float | None = None) -> _Leg:
        cruise = speed if speed is not None and speed > 0 else (self._cruise or self._p("MPC_XY_CRUISE"))
        return _Leg(self._pos, target, min(cruise, self._p("MPC_XY_VEL_MAX")), self._p("MPC_Z_V_AUTO_UP"),
                    self._p("MPC_Z_V_AUTO_DN"), self._p("MPC_ACC_HOR"), self._p("MPC_JERK_AUTO"))  # fmt: skip

    def _stretch(self, leg: _Leg) -> float:
        """How much of the time step the leg's point moves: PX4's PositionSmoothing slows its
        trajectory by 1 - e / MPC_XY_ERR_MAX while the vehicle is a horizontal distance e behind
        it (so the vehicle is never left to catch up above the cruise speed). Never below
        ``MIN_STRETCH``: twice in nine side-by-side runs with PX4 a survey leg's point stood still
        for minutes with the vehicle 2 m from it (cause not found), which PX4's vehicle, always
        closing in, never shows."""
        p, (vn, ve, _) = leg.point(), leg.velocity()
        en, ee = p[0] - self._pos[0], p[1] - self._pos[1]
        if en * vn + ee * ve <= 0.0:
            return 1.0
        return max(1.0 - math.hypot(en, ee) / max(self._p("MPC_XY_ERR_MAX"), 1e-3), MIN_STRETCH)

    def _item_complete(self, item: MissionItem, now_s: float) -> bool:
        r = self._run
        c = item.command
        if r.phase == "":
            return True  # a DO item (or one the plant does not fly)
        t = r.target
        if r.phase == "takeoff":
            assert t is not None
            if self._pos[2] <= t[2] + self._p("NAV_MC_ALT_RAD"):
                if c == NAV_TAKEOFF:
                    return True
                self._landed = False  # the take-off done, now fly the item itself
                self._begin(item, now_s)
            return False
        if r.phase == "to-land":
            assert t is not None
            if math.hypot(self._pos[0] - t[0], self._pos[1] - t[1]) <= self._p("NAV_ACC_RAD"):
                r.phase, r.leg = "land", None
            return False
        if r.phase == "land":
            return self._landed
        # goto: position, then yaw, then the hold time
        if r.hold_until_s is None:
            radius = item.params[1] if c == NAV_WAYPOINT and item.params[1] > 0 else self._p("NAV_ACC_RAD")
            assert t is not None
            if math.hypot(self._pos[0] - t[0], self._pos[1] - t[1]) > radius or abs(self._pos[2] - t[2]) > self._p("NAV_MC_ALT_RAD"):
                return False
            if r.yaw is not None and abs(_wrap(self._yaw - r.yaw)) > math.radians(self._p("MIS_YAW_ERR")):
                return False
            if c == NAV_LOITER_UNLIM:
                return False
            hold = item.params[0] if c in (NAV_WAYPOINT, NAV_LOITER_TIME) and math.isfinite(item.params[0]) else 0.0
            r.hold_until_s = now_s + max(hold, 0.0)
        return now_s >= r.hold_until_s

    # -- return ----------------------------------------------------------------------------------

    def return_altitude_down_m(self) -> float:
        """Down coordinate of the return altitude (PX4 v1.16 ``rtl.cpp``,
        ``calculate_return_alt_from_cone_half_angle``): RTL_RETURN_ALT above home; nearer than
        RTL_MIN_DIST no higher than the cone of half angle RTL_CONE_ANG over home allows, but at
        least 2 NAV_ACC_RAD; within NAV_ACC_RAD twice the distance; never below the current one.
        Measured on PX4 v1.16 SITL: from 25 m and 36 m away it climbed to 30 m."""
        home = self.frame.home_ned_m
        dist = math.hypot(self._pos[0] - home[0], self._pos[1] - home[1])
        acc = self._p("NAV_ACC_RAD")
        height = self._p("RTL_RETURN_ALT")
        if dist <= acc:
            height = 2.0 * dist
        else:
            cone = self._p("RTL_CONE_ANG")
            if dist <= self._p("RTL_MIN_DIST") and 0 < cone < 90:
                height = min(height, dist / math.tan(math.radians(cone)))
            height = max(height, 2.0 * acc)
        return min(home[2] - height, self._pos[2])

    def _rtl_step(self, now_s: float, dt: float) -> None:
        r = self._run
        home = self.frame.home_ned_m
        tol = self._p("NAV_MC_ALT_RAD")
        if not r.started:
            r.started = True
            r.phase = "climb"
            r.target = (self._pos[0], self._pos[1], self.return_altitude_down_m())
            r.leg = self._leg(r.target)
        if r.leg is not None:
            r.leg.step(dt * self._stretch(r.leg))
        t = r.target
        assert t is not None
        if r.phase == "climb" and abs(self._pos[2] - t[2]) <= tol:
            r.phase, r.target = "return", (home[0], home[1], t[2])
            r.leg = self._leg(r.target)
        elif r.phase == "return" and math.hypot(self._pos[0] - home[0], self._pos[1] - home[1]) <= self._p("NAV_ACC_RAD"):
            down = max(t[2], home[2] - self._p("RTL_DESCEND_ALT"))
            r.phase, r.target = "descend", (home[0], home[1], down)
            r.leg = self._leg(r.target)
        elif r.phase == "descend" and abs(self._pos[2] - t[2]) <= tol:
            delay = self._p("RTL_LAND_DELAY")
            r.phase, r.leg = "loiter", None
            r.hold_until_s = None if delay < 0 else now_s + delay
        elif r.phase == "loiter" and r.hold_until_s is not None and now_s >= r.hold_until_s:
            r.phase = "land"
        if r.phase in ("return",) and math.hypot(t[0] - self._pos[0], t[1] - self._pos[1]) > 1.0:
            r.yaw = math.atan2(t[1] - self._pos[1], t[0] - self._pos[0])

    @property
    def landing(self) -> bool:
        """Whether a mission or a return is in its landing."""
        return self._activity in ("mission", "rtl") and self._run.phase == "land"

    # -- reposition, orbit -----------------------------------------------------------------------

    def _goto_step(self, dt: float) -> None:
        r = self._run
        assert self._goto is not None
        target, speed, yaw = self._goto
        if not r.started:
            r.started, r.phase, r.target = True, "goto", target
            r.leg = self._leg(target, speed)
            r.yaw = yaw
        if r.leg is not None:
            r.leg.step(dt * self._stretch(r.leg))

    def _orbit_step(self, dt: float) -> None:
        r = self._run
        assert self._orbit is not None
        cn, ce, cd, radius, speed = self._orbit
        rad = max(abs(radius), 1.0)
        direction = 1.0 if radius >= 0 else -1.0  # > 0: clockwise seen from above (north to east)
        dn, de = self._pos[0] - cn, self._pos[1] - ce
        dist = math.hypot(dn, de)
        here = math.atan2(de, dn) if dist > 1e-9 else 0.0
        if not r.started:
            r.started, r.phase = True, "approach"
            r.hold_until_s = here  # the angle (rad) of a vehicle keeping the speed, kept here
        if r.phase == "approach":
            # PX4 flies to the nearest point of the circle first (a line at MPC_XY_CRUISE)
            r.target = (cn + rad * math.cos(here), ce + rad * math.sin(here), cd)
            r.yaw = math.atan2(-de, -dn)
            if abs(dist - rad) >= ORBIT_ON_CIRCLE_M or abs(self._pos[2] - cd) >= self._p("NAV_MC_ALT_RAD"):
                return
            r.phase, r.hold_until_s = "orbit", here
        theta = (r.hold_until_s or 0.0) + direction * speed / rad * dt
        r.hold_until_s = theta
        r.target = (cn + rad * math.cos(theta), ce + rad * math.sin(theta), cd)
        # FlightTaskOrbit's circle setpoints, from where the vehicle is: the tangent at its angle,
        # the radial error closed at 1/s, and the centripetal acceleration as feed-forward
        un, ue = (math.cos(here), math.sin(here))
        self._orbit_vel = (-ue * direction * speed + (rad - dist) * un, un * direction * speed + (rad - dist) * ue, 0.0)
        self._orbit_acc = (-un * speed * speed / rad, -ue * speed * speed / rad)
        r.yaw = math.atan2(-de, -dn)

    # -- yaw, landing speed ----------------------------------------------------------------------

    def _turn(self, dt: float) -> None:
        """The yaw setpoint turns towards the wanted yaw at MPC_YAWRAUTO_MAX."""
        r = self._run
        want = r.yaw
        if want is None and r.leg is not None and r.phase == "goto":
            t = r.leg.end
            if math.hypot(t[0] - self._pos[0], t[1] - self._pos[1]) > 2.0:
                want = math.atan2(t[1] - self._pos[1], t[0] - self._pos[0])
        if want is None:
            return
        step = math.radians(self._p("MPC_YAWRAUTO_MAX")) * dt
        err = _wrap(want - self._yaw_sp)
        self._yaw_sp = _wrap(self._yaw_sp + max(-step, min(step, err)))

    def _land_speed(self) -> float:
        return land_speed_m_s(self._p, self.frame.home_ned_m[2] - self._pos[2])


def land_speed_m_s(param: Callable[[str], float], height_m: float) -> float:
    """PX4's landing speed at ``height_m`` above home (FlightTaskAuto, ``math::gradual``):
    MPC_Z_V_AUTO_DN above MPC_LAND_ALT1, linear down to MPC_LAND_SPEED at MPC_LAND_ALT2,
    MPC_LAND_CRWL below MPC_LAND_ALT3 (SIH's distance sensor sees the ground; so does the plant).
    The one profile of Land, and of the landings of Mission and Return."""
    alt1, alt2 = param("MPC_LAND_ALT1"), param("MPC_LAND_ALT2")
    fast, slow = param("MPC_Z_V_AUTO_DN"), param("MPC_LAND_SPEED")
    if height_m <= param("MPC_LAND_ALT3"):
        return param("MPC_LAND_CRWL")
    if height_m >= alt1:
        return fast
    if height_m <= alt2 or alt1 <= alt2:
        return slow
    return slow + (fast - slow) * (height_m - alt2) / (alt1 - alt2)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


__all__ = ["Navigator", "NavSetpoint", "Frame", "geodetic_to_ned", "DEFAULT_ORBIT_RADIUS_M", "DEFAULT_ORBIT_SPEED_M_S"]
