"""The autopilot's state machine (PX4's commander, in miniature): pure, no sockets, no clock.

It is given the time and events (commands, setpoints, the vehicle's state) and answers with
results and effects (a ``MAV_RESULT``, STATUSTEXTs); ``task()`` tells the inner loops what to fly.

Modes are PX4's (``px4_custom_mode.h``): the heartbeat's ``custom_mode`` is
``main_mode << 16 | sub_mode << 24``. What the plant implements:

- **Hold** (AUTO_LOITER, the boot mode): hold the position where the mode was entered; on the
  ground it stays there (armed on the ground it idles, as PX4 does until a takeoff).
- **Takeoff** (AUTO_TAKEOFF): climb to the takeoff height, then Hold.
- **Land** (AUTO_LAND): descend at ``MPC_LAND_SPEED`` over the current point; once on the
  ground, disarm after ``COM_DISARM_LAND``.
- **Return** (AUTO_RTL), **Mission** (AUTO_MISSION) and **Orbit** (POSCTL sub mode 1, entered
  by MAV_CMD_DO_ORBIT) fly what the navigator (sitl_plant/navigator.py) says; so does Hold after
  MAV_CMD_DO_REPOSITION. Return climbs to the return height, comes home, descends and lands.
- **Offboard**: fly the latest setpoint. Entered only while setpoints arrive (the last one is
  not older than ``COM_OF_LOSS_T``), else ``MAV_RESULT_TEMPORARILY_REJECTED``; setpoints outside
  Offboard are remembered as proof of life but not flown. If they stop for ``COM_OF_LOSS_T``
  while armed, the failsafe switches to Hold (system status CRITICAL) and, with
  ``COM_OBL_RC_ACT = 4``, to Land after ``COM_FAIL_ACT_T``.
- Manual-input modes (Manual, Altitude, Position, Acro, Stabilized) need a remote control the
  simulation does not have: refused, as PX4 refuses them without manual control input.

Arming (MAV_CMD_COMPONENT_ARM_DISARM) runs PX4-like pre-arm checks (simulated sensor failures,
the mode's requirements); a refusal is ``TEMPORARILY_REJECTED`` with a STATUSTEXT, as PX4's
commander answers. ``param2 = 21196`` forces arming or disarming past the checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Union

import numpy as np

from sitl_plant.navigator import Frame, Navigator
from sitl_plant.params import OBL_ACT_LAND, ParamTable
from offboard.model.state import VehicleState

# MAVLink enum values used here (common.xml), spelled out to keep this module free of pymavlink.
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4

MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
MAV_SEVERITY_INFO = 6

MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5

MAV_LANDED_STATE_ON_GROUND = 1
MAV_LANDED_STATE_IN_AIR = 2
MAV_LANDED_STATE_TAKEOFF = 3
MAV_LANDED_STATE_LANDING = 4

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1

MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_MISSION_START = 300
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_RUN_PREARM_CHECKS = 401
MAV_CMD_INJECT_FAILURE = 420

FORCE_MAGIC = 21196  # PX4: arm/disarm forced (checks skipped) when param2 is this number

#: MAV_CMD_INJECT_FAILURE units (FAILURE_UNIT) the plant simulates, by name.
FAILURE_UNITS = {0: "gyro", 1: "accel", 2: "mag", 3: "baro", 4: "gps", 100: "battery", 101: "motor"}
FAILURE_TYPE_OK = 0


class Mode(Enum):
    """PX4 modes as (main mode, sub mode) of ``px4_custom_mode.h``."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    AUTO_READY = (4, 1)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    ORBIT = (3, 1)  # PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT: entered by MAV_CMD_DO_ORBIT
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def custom_mode(self) -> int:
        """The heartbeat's custom_mode: ``main << 16 | sub << 24``."""
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @property
    def label(self) -> str:
        return _LABELS[self]

    @classmethod
    def from_custom(cls, main: int, sub: int) -> Mode | None:
        """The mode for PX4's (main, sub); sub is ignored for main modes other than AUTO and
        POSCTL (whose sub mode 1 is Orbit)."""
        key = (main, sub if main in (3, 4) else 0)
        return _BY_VALUE.get(key)

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Mode | None:
        return cls.from_custom((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


_LABELS = {
    Mode.MANUAL: "Manual",
    Mode.ALTCTL: "Altitude",
    Mode.POSCTL: "Position",
    Mode.AUTO_READY: "Ready",
    Mode.AUTO_TAKEOFF: "Takeoff",
    Mode.AUTO_LOITER: "Hold",
    Mode.AUTO_MISSION: "Mission",
    Mode.AUTO_RTL: "Return",
    Mode.AUTO_LAND: "Land",
    Mode.ACRO: "Acro",
    Mode.ORBIT: "Orbit",
    Mode.OFFBOARD: "Offboard",
    Mode.STABILIZED: "Stabilized",
}
_BY_VALUE = {m.value: m for m in Mode}
_NEEDS_MANUAL_INPUT = (Mode.MANUAL, Mode.ALTCTL, Mode.POSCTL, Mode.ACRO, Mode.STABILIZED)
_ARMABLE = (Mode.AUTO_LOITER, Mode.AUTO_TAKEOFF, Mode.OFFBOARD, Mode.AUTO_MISSION)
#: Modes whose setpoint the navigator gives (sitl_plant/navigator.py).
_NAVIGATED = (Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.ORBIT)


# --- what comes in ------------------------------------------------------------------------------


@dataclass(frozen=True)
class AttitudeSetpoint:
    """SET_ATTITUDE_TARGET as PX4 reads it (validated by the codec).

    Attributes
    ----------
    time_boot_ms : int
        The client's stamp; in lockstep it echoes the telemetry it answers.
    q_wxyz : tuple of 4 floats or None
        Attitude, body FRD to NED, unit norm; None when ignored (type_mask bit 7).
    body_rates_frd_rad_s : tuple of 3 (float or None)
        Body roll, pitch, yaw rate; None for each ignored component (type_mask bits 0-2).
    thrust_norm : float or None
        Collective thrust, normalised (1 = ``SIM_THR_MAX``); None when ignored (bit 6).
    """

    time_boot_ms: int
    q_wxyz: tuple[float, float, float, float] | None
    body_rates_frd_rad_s: tuple[float | None, float | None, float | None]
    thrust_norm: float | None

    @property
    def flies_attitude(self) -> bool:
        return self.q_wxyz is not None

    @property
    def flies_rates(self) -> bool:
        """PX4: rates are used when the attitude is ignored and roll and pitch rates are given."""
        return self.q_wxyz is None and None not in self.body_rates_frd_rad_s[:2]

    @property
    def is_setpoint(self) -> bool:
        """Whether PX4 would take it as a setpoint (proof of life): attitude or rates given."""
        return self.flies_attitude or self.flies_rates


@dataclass(frozen=True)
class ActuatorSetpoint:
    """SET_ACTUATOR_CONTROL_TARGET group 0: normalised roll, pitch, yaw torque and thrust.

    ``controls`` are clipped by the codec to [-1, 1] (torques) and [0, 1] (thrust), as PX4's
    mixer saturates them.
    """

    time_usec: int
    controls: tuple[float, float, float, float]


@dataclass(frozen=True)
class PositionSetpoint:
    """SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED (validated by the codec).

    Per axis a position (m, NED) and/or a velocity (m/s, NED; a feed-forward when the position is
    given); None where ignored. ``yaw_rad`` None: keep the heading.
    """

    time_boot_ms: int
    pos_ned_m: tuple[float | None, float | None, float | None]
    vel_ned_m_s: tuple[float | None, float | None, float | None]
    yaw_rad: float | None


Setpoint = Union[AttitudeSetpoint, ActuatorSetpoint, PositionSetpoint]


@dataclass(frozen=True)
class Command:
    """COMMAND_LONG or COMMAND_INT (params 5, 6 are then the raw x, y integers)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    source_system: int = 0
    source_component: int = 0


@dataclass(frozen=True)
class StatusText:
    """A STATUSTEXT to send (severity is MAV_SEVERITY)."""

    severity: int
    text: str


@dataclass(frozen=True)
class Reply:
    """The autopilot's answer to a command: a MAV_RESULT and the texts that go with it."""

    result: int
    texts: tuple[StatusText, ...] = ()


# --- what goes out: the task for the inner loops ---------------------------------------------


@dataclass(frozen=True)
class IdleTask:
    """Motors at rest (disarmed, or armed on the ground waiting)."""


@dataclass(frozen=True)
class OffboardTask:
    """Fly this setpoint."""

    setpoint: Setpoint


@dataclass(frozen=True)
class PositionTask:
    """Hold ``pos_ned_m`` and ``yaw_rad``; with ``descend_m_s`` the height is not held but the
    vehicle descends at that speed (landing); ``max_climb_m_s`` limits the climb (takeoff).
    ``vel_ned_m_s`` is a velocity feed-forward, or the velocity setpoint of an axis whose
    position is None (offboard position/velocity setpoints)."""

    pos_ned_m: tuple[float | None, float | None, float | None]
    yaw_rad: float
    descend_m_s: float | None = None
    max_climb_m_s: float | None = None
    vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)


Task = Union[IdleTask, OffboardTask, PositionTask]


@dataclass(frozen=True)
class Status:
    """What the heartbeat and the status messages report."""

    armed: bool
    mode: Mode
    system_status: int
    landed_state: int
    failsafe: bool
    failures: frozenset[str]
    prearm_ok: bool


# --- the state machine ------------------------------------------------------------------------


@dataclass
class _Memory:
    last_setpoint: Setpoint | None = None
    last_setpoint_s: float | None = None
    hold_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hold_yaw: float = 0.0
    takeoff_height_m: float = 2.5
    land_at_s: float | None = None  # failsafe: when hold turns into land
    armed_at_s: float = 0.0
    landed_since_s: float | None = None
    has_taken_off: bool = False
    rtl_landing: bool = False


class Autopilot:
    """PX4-like commander for one vehicle.

    Parameters
    ----------
    params : ParamTable
        The plant's parameters (``COM_*``, ``MIS_TAKEOFF_ALT``, ...), read at every use so a
        PARAM_SET takes effect at once.
    home_alt_amsl_m : float
        Home altitude, to turn MAV_CMD_NAV_TAKEOFF's AMSL param7 into a height.
    failures : iterable of str
        Simulated unhealthy units (``FAILURE_UNITS`` names) from the start (``--unhealthy``).
    """

    def __init__(self, params: ParamTable, *, home_alt_amsl_m: float = 0.0, failures: frozenset[str] | set[str] = frozenset()) -> None:
        unknown = set(failures) - set(FAILURE_UNITS.values())
        if unknown:
            raise ValueError(f"unknown failure unit(s) {sorted(unknown)}; expected {sorted(FAILURE_UNITS.values())}")
        self.params = params
        self.home_alt_amsl_m = home_alt_amsl_m
        self.home_ned_m = (0.0, 0.0, 0.0)
        self.failures: set[str] = set(failures)
        self.armed = False
        self.mode = Mode.AUTO_LOITER
        self.failsafe = False
        self._m = _Memory()
        self._pos = np.zeros(3)
        self._yaw = 0.0
        self._landed = True
        self.counters: dict[str, int] = {"setpoints": 0, "ignored_setpoints": 0}
        self.navigator = Navigator(params)
        self.origin = (0.0, 0.0, home_alt_amsl_m)  # lat, lon (deg), alt AMSL (m) of the local frame's origin

    # -- status ----------------------------------------------------------------------------------

    def status(self) -> Status:
        if self.failsafe:
            system_status = MAV_STATE_CRITICAL
        else:
            system_status = MAV_STATE_ACTIVE if self.armed else MAV_STATE_STANDBY
        return Status(
            armed=self.armed,
            mode=self.mode,
            system_status=system_status,
            landed_state=self.landed_state(),
            failsafe=self.failsafe,
            failures=frozenset(self.failures),
            prearm_ok=not self.failures,
        )

    def set_origin(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> None:
        """Where the local NED frame's origin is on the globe (for mission items and commands)."""
        self.origin = (lat_deg, lon_deg, alt_amsl_m)

    def frame(self) -> Frame:
        """The local frame and home, as the navigator converts global positions."""
        return Frame(self.origin[0], self.origin[1], self.origin[2], self.home_ned_m)

    def landed_state(self) -> int:
        if self._landed:
            return MAV_LANDED_STATE_ON_GROUND
        if self.armed and self.mode is Mode.AUTO_TAKEOFF:
            return MAV_LANDED_STATE_TAKEOFF
        if self.armed and (self.mode is Mode.AUTO_LAND or (self.mode in _NAVIGATED and self.navigator.landing)):
            return MAV_LANDED_STATE_LANDING
        return MAV_LANDED_STATE_IN_AIR

    def offboard_signal_ok(self, now_s: float) -> bool:
        """PX4's proof of life: the last setpoint is not older than COM_OF_LOSS_T."""
        last = self._m.last_setpoint_s
        return last is not None and now_s - last <= self.params["COM_OF_LOSS_T"]

    @property
    def last_setpoint(self) -> Setpoint | None:
        return self._m.last_setpoint

    # -- events ----------------------------------------------------------------------------------

    def on_setpoint(self, setpoint: Setpoint, now_s: float) -> bool:
        """Remember a setpoint (proof of life); returns whether it is flown now (Offboard)."""
        if isinstance(setpoint, AttitudeSetpoint) and not setpoint.is_setpoint:
            self.counters["ignored_setpoints"] += 1
            return False
        self.counters["setpoints"] += 1
        self._m.last_setpoint = setpoint
        self._m.last_setpoint_s = now_s
        return self.armed and self.mode is Mode.OFFBOARD

    def observe(self, truth: VehicleState) -> None:
        """Take in the vehicle's state (the autopilot's estimate is the truth here)."""
        self._pos = truth.pos_ned_m
        self._yaw = float(truth.euler_rad[2])
        self._landed = bool(truth.on_ground)

    def on_command(self, cmd: Command, now_s: float) -> Reply | None:
        """Handle a flight command; ``None`` for commands the autopilot does not know."""
        handler = {
            MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm_disarm,
            MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff,
            MAV_CMD_NAV_LAND: self._cmd_land,
            MAV_CMD_NAV_RETURN_TO_LAUNCH: self._cmd_rtl,
            MAV_CMD_INJECT_FAILURE: self._cmd_inject_failure,
            MAV_CMD_RUN_PREARM_CHECKS: self._cmd_prearm,
            MAV_CMD_MISSION_START: self._cmd_mission_start,
            MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
        }.get(cmd.command)
        return None if handler is None else handler(cmd, now_s)

    def set_mode(self, mode: Mode | None, now_s: float) -> Reply:
        """A mode change asked by a client (DO_SET_MODE or the legacy SET_MODE)."""
        if mode is None:
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, "Unknown mode"),))
        if mode is self.mode and not self.failsafe:
            return Reply(MAV_RESULT_ACCEPTED)
        if mode in _NEEDS_MANUAL_INPUT:
            return _refuse(f"Switching to {mode.label} is currently not possible: no manual control input")
        if mode is Mode.AUTO_READY:
            return _refuse(f"Switching to {mode.label} is currently not possible: no mission")
        if mode is Mode.ORBIT:
            return _refuse("Switching to Orbit is currently not possible: send MAV_CMD_DO_ORBIT")
        if mode is Mode.AUTO_MISSION and self.armed and not self.navigator.items:
            return _refuse("Switching to Mission is currently not possible: no valid mission")  # PX4 1.16 in the air
        if mode is Mode.OFFBOARD and not self.offboard_signal_ok(now_s):
            return _refuse("Switching to Offboard is currently not possible: no offboard signal")
        if mode is Mode.AUTO_TAKEOFF:
            self._prepare_takeoff(math.nan)
        self._enter(mode, now_s, by_client=True)
        return Reply(MAV_RESULT_ACCEPTED)

    def update(self, now_s: float) -> list[StatusText]:
        """Time-driven logic: offboard loss, failsafe land, takeoff done, auto-disarm."""
        texts: list[StatusText] = []
        m = self._m
        p = self.params
        if self.mode is Mode.OFFBOARD and not self.offboard_signal_ok(now_s):
            if self.armed:
                self.failsafe = True
                self._enter(Mode.AUTO_LOITER, now_s)
                land = int(p["COM_OBL_RC_ACT"]) == OBL_ACT_LAND
                m.land_at_s = now_s + p["COM_FAIL_ACT_T"] if land else None
                action = f"hold, land in {p['COM_FAIL_ACT_T']:g} s" if land else "hold"
                texts.append(StatusText(MAV_SEVERITY_CRITICAL, f"Failsafe activated: no offboard signal, {action}"))
            else:
                self._enter(Mode.AUTO_LOITER, now_s)
                texts.append(StatusText(MAV_SEVERITY_WARNING, "No offboard signal, switching to Hold"))
        if self.failsafe and m.land_at_s is not None and now_s >= m.land_at_s and self.mode is Mode.AUTO_LOITER:
            self._enter(Mode.AUTO_LAND, now_s)
            m.land_at_s = None
            texts.append(StatusText(MAV_SEVERITY_CRITICAL, "Failsafe: landing"))
        if self.armed and not self._landed:
            m.has_taken_off = True
        if self.armed and self.mode is Mode.AUTO_TAKEOFF and not self._landed:
            target_down = self._takeoff_down_m()
            if self._pos[2] <= target_down + 0.1:
                self._enter(Mode.AUTO_LOITER, now_s)
                m.hold_pos = (m.hold_pos[0], m.hold_pos[1], target_down)
                texts.append(StatusText(MAV_SEVERITY_INFO, "Takeoff complete, holding"))
        texts.extend(self._navigate(now_s))
        texts.extend(self._auto_disarm(now_s))
        return texts

    def task(self) -> Task:
        """What the inner loops fly now."""
        m = self._m
        if not self.armed:
            return IdleTask()
        mode = self.mode
        if mode is Mode.OFFBOARD and m.last_setpoint is not None:
            return OffboardTask(m.last_setpoint)
        if mode is Mode.AUTO_TAKEOFF:
            return PositionTask((m.hold_pos[0], m.hold_pos[1], self._takeoff_down_m()), m.hold_yaw, max_climb_m_s=self.params["MPC_TKO_SPEED"])
        nav = self.navigator.setpoint() if (mode in _NAVIGATED or self.navigator.activity == "reposition") else None
        if nav is not None:
            if self._landed and (nav.landing or (not m.has_taken_off and nav.max_climb_m_s is None)):
                return IdleTask()
            return PositionTask(nav.pos_ned_m, nav.yaw_rad, descend_m_s=nav.descend_m_s, max_climb_m_s=nav.max_climb_m_s, vel_ned_m_s=nav.vel_ned_m_s)
        if self._landed and (not m.has_taken_off or mode in (Mode.AUTO_LAND, Mode.AUTO_LOITER) or m.rtl_landing):
            return IdleTask()
        if mode is Mode.AUTO_LAND:
            return PositionTask(m.hold_pos, m.hold_yaw, descend_m_s=self.params["MPC_LAND_SPEED"])
        return PositionTask(m.hold_pos, m.hold_yaw)

    # -- commands --------------------------------------------------------------------------------

    def _cmd_arm_disarm(self, cmd: Command, now_s: float) -> Reply:
        p1, p2 = cmd.params[0], cmd.params[1]
        if not math.isfinite(p1) or round(p1) not in (0, 1):
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, f"Unsupported ARM_DISARM param: {p1:.3f}"),))
        forced = math.isfinite(p2) and round(p2) == FORCE_MAGIC
        if round(p1) == 1:
            return self.arm(now_s, forced=forced)
        return self.disarm(now_s, forced=forced)

    def arm(self, now_s: float, *, forced: bool = False) -> Reply:
        if self.armed:
            return Reply(MAV_RESULT_ACCEPTED)
        if not forced:
            reason = self.prearm_failure(now_s)
            if reason is not None:
                return _refuse(f"Arming denied: {reason}")
        self.armed = True
        m = self._m
        m.armed_at_s = now_s
        m.has_taken_off = not self._landed
        m.landed_since_s = None
        m.rtl_landing = False
        if self._landed:
            self.home_ned_m = (float(self._pos[0]), float(self._pos[1]), float(self._pos[2]))
        self._set_hold_here()
        if self.mode is Mode.AUTO_MISSION:
            self.navigator.start("mission", now_s)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, "Armed by external command"),))

    def disarm(self, now_s: float, *, forced: bool = False) -> Reply:
        if not self.armed:
            return Reply(MAV_RESULT_ACCEPTED)
        if not forced and not self._landed:
            return _refuse("Disarming denied: not landed")
        self._disarm()
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, "Disarmed by external command"),))

    def prearm_failure(self, now_s: float) -> str | None:
        """Why arming would be refused now, or None (PX4's pre-arm checks, in miniature)."""
        if self.failures:
            return f"{', '.join(sorted(self.failures))} unhealthy (simulated failure)"
        if self.mode not in _ARMABLE:
            return f"not possible in {self.mode.label} mode"
        if self.mode is Mode.OFFBOARD and not self.offboard_signal_ok(now_s):
            return "no offboard signal"
        return None

    def _cmd_set_mode(self, cmd: Command, now_s: float) -> Reply:
        base, main, sub = cmd.params[0], cmd.params[1], cmd.params[2]
        if not (math.isfinite(base) and int(base) & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, "Only PX4 custom modes are supported"),))
        if not math.isfinite(main):
            return self.set_mode(None, now_s)
        sub_mode = int(sub) if math.isfinite(sub) else 0
        return self.set_mode(Mode.from_custom(int(main), sub_mode), now_s)

    def _cmd_takeoff(self, cmd: Command, now_s: float) -> Reply:
        if not (self.armed or self._landed):
            return _refuse("Takeoff denied: already flying")
        self._prepare_takeoff(cmd.params[6])
        self._enter(Mode.AUTO_TAKEOFF, now_s, by_client=True)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, f"Takeoff to {self._m.takeoff_height_m:.1f} m"),))

    def _cmd_land(self, cmd: Command, now_s: float) -> Reply:
        self._enter(Mode.AUTO_LAND, now_s, by_client=True)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, "Landing at current position"),))

    def _cmd_rtl(self, cmd: Command, now_s: float) -> Reply:
        self._enter(Mode.AUTO_RTL, now_s, by_client=True)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, "Returning to launch"),))

    def _cmd_mission_start(self, cmd: Command, now_s: float) -> Reply:
        """MAV_CMD_MISSION_START: Mission mode, from item param1 when it is one (PX4's commander)."""
        first = cmd.params[0]
        if math.isfinite(first) and 0 < first < len(self.navigator.items):
            self.navigator.set_current(int(first))
        return self.set_mode(Mode.AUTO_MISSION, now_s)

    def reposition(self, target_ned_m: tuple[float, float, float], speed_m_s: float, yaw_rad: float | None, now_s: float) -> Reply:
        """MAV_CMD_DO_REPOSITION (the server has turned its global position into local NED):
        Hold mode, flying to the point and holding there (PX4's navigator reposition). As PX4 v1.16
        was measured: disarmed it is ACCEPTED and nothing happens; armed on the ground the vehicle
        takes off towards the point (climbing at most MPC_TKO_SPEED)."""
        if not self.armed:
            return Reply(MAV_RESULT_ACCEPTED)
        self._enter(Mode.AUTO_LOITER, now_s, by_client=True)
        self.navigator.reposition(target_ned_m, speed_m_s, yaw_rad, now_s, from_ground=self._landed)
        return Reply(MAV_RESULT_ACCEPTED)

    def _cmd_change_speed(self, cmd: Command, now_s: float) -> Reply:
        """MAV_CMD_DO_CHANGE_SPEED: param2 m/s (-2: back to MPC_XY_CRUISE) for the legs that follow."""
        self.navigator.change_speed(cmd.params[1])
        return Reply(MAV_RESULT_ACCEPTED)

    def orbit(self, centre_ned_m: tuple[float, float, float], radius_m: float, speed_m_s: float, now_s: float) -> Reply:
        """MAV_CMD_DO_ORBIT: Orbit mode (POSCTL sub mode 1) around the centre. Disarmed, PX4 v1.16
        takes the command and the mode (it was measured); armed on the ground it is refused."""
        if self.armed and self._landed:
            return _refuse("Orbit denied: not flying")  # (not measured on PX4)
        self._enter(Mode.ORBIT, now_s, by_client=True)
        self.navigator.orbit(centre_ned_m, radius_m, speed_m_s, now_s)
        return Reply(MAV_RESULT_ACCEPTED)

    def _navigate(self, now_s: float) -> list[StatusText]:
        nav = self.navigator
        nav.frame = self.frame()
        nav.observe((float(self._pos[0]), float(self._pos[1]), float(self._pos[2])), self._yaw, self._landed)
        if not self.armed:
            return []
        nav.update(now_s)
        if nav.wants_rtl and self.mode is Mode.AUTO_MISSION:
            self._enter(Mode.AUTO_RTL, now_s)
            return [StatusText(MAV_SEVERITY_INFO, "Mission: returning to launch")]
        return []

    def _cmd_inject_failure(self, cmd: Command, now_s: float) -> Reply:
        if int(self.params["SYS_FAILURE_EN"]) != 1:
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, "Failure injection disabled (SYS_FAILURE_EN)"),))
        unit_code, kind = cmd.params[0], cmd.params[1]
        unit = FAILURE_UNITS.get(int(unit_code)) if math.isfinite(unit_code) else None
        if unit is None or not math.isfinite(kind):
            return Reply(MAV_RESULT_UNSUPPORTED)
        if int(kind) == FAILURE_TYPE_OK:
            self.failures.discard(unit)
            return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, f"Failure cleared: {unit}"),))
        self.failures.add(unit)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_WARNING, f"Failure injected: {unit}"),))

    def _cmd_prearm(self, cmd: Command, now_s: float) -> Reply:
        if self.armed:
            return Reply(MAV_RESULT_TEMPORARILY_REJECTED)
        reason = self.prearm_failure(now_s)
        text = "Preflight checks passed" if reason is None else f"Preflight Fail: {reason}"
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO if reason is None else MAV_SEVERITY_CRITICAL, text),))

    # -- internals -------------------------------------------------------------------------------

    def _prepare_takeoff(self, param7_amsl_m: float) -> None:
        height = self.params["MIS_TAKEOFF_ALT"]
        if math.isfinite(param7_amsl_m) and param7_amsl_m - self.home_alt_amsl_m > 0.5:
            height = param7_amsl_m - self.home_alt_amsl_m
        self._m.takeoff_height_m = height

    def _takeoff_down_m(self) -> float:
        return self.home_ned_m[2] - self._m.takeoff_height_m

    def _set_hold_here(self) -> None:
        self._m.hold_pos = (float(self._pos[0]), float(self._pos[1]), float(self._pos[2]))
        self._m.hold_yaw = self._yaw

    def _enter(self, mode: Mode, now_s: float, *, by_client: bool = False) -> None:
        """Switch mode; a mode the client chooses ends a failsafe (PX4: the user takes over)."""
        if by_client:
            self.failsafe = False
            self._m.land_at_s = None
        self._set_hold_here()
        self._m.rtl_landing = False
        self.mode = mode
        nav = self.navigator
        nav.stop()
        nav.observe((float(self._pos[0]), float(self._pos[1]), float(self._pos[2])), self._yaw, self._landed)
        if self.armed and mode is Mode.AUTO_MISSION:
            nav.frame = self.frame()
            nav.start("mission", now_s)
        elif mode is Mode.AUTO_RTL:
            nav.frame = self.frame()
            nav.start("rtl", now_s)

    def _auto_disarm(self, now_s: float) -> list[StatusText]:
        if not self.armed:
            return []
        m, p = self._m, self.params
        if not self._landed:
            m.landed_since_s = None
            return []
        if m.has_taken_off:
            if m.landed_since_s is None:
                m.landed_since_s = now_s
                return [StatusText(MAV_SEVERITY_INFO, "Landing detected")]
            delay = p["COM_DISARM_LAND"]
            if delay > 0 and now_s - m.landed_since_s >= delay:
                self._disarm()
                return [StatusText(MAV_SEVERITY_INFO, "Disarmed by landing")]
            return []
        delay = p["COM_DISARM_PRFLT"]
        if delay > 0 and now_s - m.armed_at_s >= delay and self.mode is not Mode.AUTO_TAKEOFF:
            self._disarm()
            return [StatusText(MAV_SEVERITY_INFO, "Disarmed by auto preflight disarming")]
        return []

    def _disarm(self) -> None:
        self.armed = False
        self.failsafe = False
        self._m.land_at_s = None
        self._m.has_taken_off = False
        self._m.landed_since_s = None
        if self.mode in (Mode.AUTO_LAND, Mode.AUTO_RTL, Mode.AUTO_TAKEOFF):
            self._enter(Mode.AUTO_LOITER, 0.0)


def _refuse(text: str) -> Reply:
    return Reply(MAV_RESULT_TEMPORARILY_REJECTED, (StatusText(MAV_SEVERITY_CRITICAL, text),))


__all__ = [
    "Autopilot",
    "Mode",
    "AttitudeSetpoint",
    "ActuatorSetpoint",
    "PositionSetpoint",
    "Setpoint",
    "Command",
    "StatusText",
    "Reply",
    "Status",
    "IdleTask",
    "OffboardTask",
    "PositionTask",
    "Task",
    "FAILURE_UNITS",
    "FORCE_MAGIC",
]
