"""The autopilot's state machine (PX4's commander, in miniature): pure, no sockets, no clock.

It is given the time and events (commands, setpoints, virtual sticks, the vehicle's state) and
answers with results and effects (a ``MAV_RESULT``, STATUSTEXTs); ``task()`` tells the inner loops
what to fly. What PX4 v1.16 SITL does was measured (docs/parity/commander.md) and is followed:

- **Mode changes** (DO_SET_MODE, SET_MODE) are always accepted while **disarmed**; whether arming
  is then possible shows in the heartbeat's system status (UNINIT where it is not: Offboard without
  setpoints, a manual mode without manual control input, Land, Return, Mission without a mission) and arming is
  refused with PX4's "Arming denied: Resolve system health failures first". **Armed**, a mode that
  cannot run is refused with "Switching to <mode> is currently not available" (Offboard without
  setpoints, Position/Altitude/... without MANUAL_CONTROL).
- **Hold** (AUTO_LOITER, the boot mode): hold the position where the mode was entered.
- **Takeoff**: PX4's takeoff handling (``mc_pos_control/Takeoff``): the motors spool up for
  ``COM_SPOOLUP_TIME`` after arming, then the upward velocity limit ramps over ``MPC_TKO_RAMP_T``
  from the value that gives no thrust (``-g / MPC_Z_VEL_P_ACC``) to ``MPC_TKO_SPEED``; the climb
  slows near the takeoff height; within ``NAV_MC_ALT_RAD`` of it, Hold (at the takeoff height).
  The same handling (``_takeoff_climb_limit``) applies to every take-off from the ground: the
  navigated ones (a mission's, a DO_REPOSITION's) and the sticks' in Position/Altitude, as
  mc_pos_control applies it whatever the flight task.
- **Land**: PX4's speed profile (``FlightTaskAuto``): ``MPC_Z_V_AUTO_DN`` above ``MPC_LAND_ALT1``,
  blended down to ``MPC_LAND_SPEED`` at ``MPC_LAND_ALT2``, ``MPC_LAND_CRWL`` below ``MPC_LAND_ALT3``.
  Landing is detected ``LNDMC_TRIG_TIME`` + 2 s after touch-down (PX4's land detector), disarm
  ``COM_DISARM_LAND`` later, and the mode goes back to the last one that allows arming.
- **Return** (AUTO_RTL), **Mission** (AUTO_MISSION) and **Orbit** (POSCTL sub mode 1, entered
  by MAV_CMD_DO_ORBIT) fly what the navigator (sitl_plant/navigator.py) says; so does Hold after
  MAV_CMD_DO_REPOSITION. Return climbs to the return height, comes home, descends and lands.
- **Follow Target** (AUTO_FOLLOW_TARGET, 4/8): follow the target that FOLLOW_TARGET messages
  report, at ``FLW_TGT_DST`` and ``FLW_TGT_FA`` from it and ``FLW_TGT_HT`` high, the nose on it
  (PX4's FlightTaskAutoFollowTarget, sitl_plant/follow.py). As PX4 v1.16: accepted disarmed but
  arming refused in it (system status UNINIT); armed it is accepted with or without a target
  (without one it holds); base_mode 17, armed 145 (measured).
- **Offboard**: fly the latest setpoint. Offboard loss (no setpoint for ``COM_OF_LOSS_T``, armed)
  is PX4's mode fallback (``failsafe.cpp``, ``checkModeFallback``): at once, the action of
  ``COM_OBL_RC_ACT`` (0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold, 6 Terminate,
  7 Disarm), system status CRITICAL, "Failsafe activated"; it ends when setpoints come back (the
  vehicle returns to Offboard) or the client chooses a mode.
- **Position / Altitude** (and Stabilized, Manual, Acro, flown like Altitude): MANUAL_CONTROL as
  virtual sticks (``ManualInput``); without stick input they do what PX4's failsafe flight task
  does: keep the horizontal position and descend at ``MPC_LAND_SPEED``. Sticks that stop for
  ``COM_RC_LOSS_T`` in such a mode: Hold for ``COM_FAIL_ACT_T``, then ``NAV_RCL_ACT``.

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

from offboard.model import px4_modes as M
from offboard.model.state import VehicleState
from sitl_plant.follow import FollowSetpoint, FollowTarget
from sitl_plant.navigator import Frame, NavSetpoint, Navigator, land_speed_m_s
from sitl_plant.params import ParamTable

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

MAV_STATE_UNINIT = 0
MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
MAV_STATE_FLIGHT_TERMINATION = 8

MAV_LANDED_STATE_ON_GROUND = 1
MAV_LANDED_STATE_IN_AIR = 2
MAV_LANDED_STATE_TAKEOFF = 3
MAV_LANDED_STATE_LANDING = 4

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_AUTO_ENABLED = 4
MAV_MODE_FLAG_GUIDED_ENABLED = 8
MAV_MODE_FLAG_STABILIZE_ENABLED = 16
MAV_MODE_FLAG_MANUAL_INPUT_ENABLED = 64
MAV_MODE_FLAG_SAFETY_ARMED = 128

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
    """PX4 modes as (main mode, sub mode) of ``px4_custom_mode.h`` (``offboard.model.px4_modes``)."""

    MANUAL = (M.MAIN_MANUAL, 0)
    ALTCTL = (M.MAIN_ALTCTL, 0)
    POSCTL = (M.MAIN_POSCTL, 0)
    AUTO_READY = (M.MAIN_AUTO, M.SUB_AUTO_READY)
    AUTO_TAKEOFF = (M.MAIN_AUTO, M.SUB_AUTO_TAKEOFF)
    AUTO_LOITER = (M.MAIN_AUTO, M.SUB_AUTO_LOITER)
    AUTO_MISSION = (M.MAIN_AUTO, M.SUB_AUTO_MISSION)
    AUTO_RTL = (M.MAIN_AUTO, M.SUB_AUTO_RTL)
    AUTO_LAND = (M.MAIN_AUTO, M.SUB_AUTO_LAND)
    AUTO_FOLLOW_TARGET = (M.MAIN_AUTO, M.SUB_AUTO_FOLLOW_TARGET)
    ORBIT = (M.MAIN_POSCTL, M.SUB_POSCTL_ORBIT)  # entered by MAV_CMD_DO_ORBIT
    ACRO = (M.MAIN_ACRO, 0)
    OFFBOARD = (M.MAIN_OFFBOARD, 0)
    STABILIZED = (M.MAIN_STABILIZED, 0)
    TERMINATION = (M.MAIN_TERMINATION, 0)  # flight termination (PX4 v1.15+), not a mode to choose

    @property
    def custom_mode(self) -> int:
        """The heartbeat's custom_mode: ``main << 16 | sub << 24``."""
        return M.custom_mode(*self.value)

    @property
    def label(self) -> str:
        """PX4's name of the mode (QGroundControl's words: Hold, Offboard, ...)."""
        return M.mode_name(*self.value)

    @classmethod
    def from_custom(cls, main: int, sub: int) -> Mode | None:
        """The mode for PX4's (main, sub); sub is ignored for main modes other than AUTO and
        POSCTL (whose sub mode 1 is Orbit)."""
        key = (main, sub if main in (M.MAIN_POSCTL, M.MAIN_AUTO) else 0)
        return _BY_VALUE.get(key)

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Mode | None:
        """The mode of a HEARTBEAT's ``custom_mode`` (PX4's main mode in bits 16-23, sub mode in 24-31)."""
        return cls.from_custom(*M.main_sub(custom_mode))


_BY_VALUE = {m.value: m for m in Mode}
_NEEDS_MANUAL_INPUT = (Mode.MANUAL, Mode.ALTCTL, Mode.POSCTL, Mode.ACRO, Mode.STABILIZED)
#: Modes PX4 arms in (with their requirements met: setpoints for Offboard, sticks for the manual
#: ones, a mission for Mission); Land, Return and Ready are not among them.
_ARMABLE = (Mode.AUTO_LOITER, Mode.AUTO_TAKEOFF, Mode.OFFBOARD, Mode.AUTO_MISSION, *_NEEDS_MANUAL_INPUT)
#: EKF2_NOAID_TOUT's default (PX4 v1.16: 5 000 000 us): how long EKF2 dead-reckons after its last
#: horizontal aiding (the GPS) before it stops vouching for horizontal velocity and position.
#: Measured on PX4 v1.16 SITL with its GPS stopped (docs/plant.md): the flags dropped 5.1-5.2 s
#: after, the predicted-position and height-above-ground flags and the GPS's SYS_STATUS presence
#: about 2 s later (``GPS_DROPPED_S``).
DEAD_RECKONING_S = 5.0
GPS_DROPPED_S = 7.0
#: Modes that need a horizontal position estimate (PX4's mode requirements): without one PX4's
#: failsafe lands blind (measured in Hold: AUTO.LAND 5.2 s after the GPS stopped, system status
#: CRITICAL, "Failsafe activated"). Offboard driven by attitude setpoints needs none and flies on.
_NEEDS_POSITION = (Mode.AUTO_LOITER, Mode.AUTO_TAKEOFF, Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.ORBIT, Mode.AUTO_FOLLOW_TARGET)
#: Modes whose setpoint the navigator gives (sitl_plant/navigator.py).
_NAVIGATED = (Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.ORBIT)
_AUTO = (Mode.AUTO_READY, Mode.AUTO_TAKEOFF, Mode.AUTO_LOITER, Mode.AUTO_MISSION, Mode.AUTO_RTL, Mode.AUTO_LAND)

#: COM_OBL_RC_ACT (PX4's offboard_loss_failsafe_mode) -> the mode the failsafe switches to; 6 is
#: flight termination, 7 disarm (failsafe.cpp, fromOffboardLossActParam). Flown on PX4 v1.16 SITL
#: without manual control input (docs/parity/commander.md): every value ends in the mode named
#: here, none falls back for the missing sticks; Altitude descends at MPC_LAND_SPEED as Position
#: does, Stabilized holds level at the hover thrust (``_manual_task``).
OBL_ACTIONS = {0: Mode.POSCTL, 1: Mode.ALTCTL, 2: Mode.STABILIZED, 3: Mode.AUTO_RTL, 4: Mode.AUTO_LAND, 5: Mode.AUTO_LOITER}
OBL_TERMINATE, OBL_DISARM = 6, 7
#: NAV_RCL_ACT (manual control loss, after COM_FAIL_ACT_T of Hold): 1 Hold, 2 Return, 3 Land,
#: 5 Terminate, 6 Disarm; 0 disabled (PX4's gcs_connection_loss_failsafe_mode numbering).
RCL_ACTIONS = {1: Mode.AUTO_LOITER, 2: Mode.AUTO_RTL, 3: Mode.AUTO_LAND}
RCL_TERMINATE, RCL_DISARM = 5, 6

G_M_S2 = 9.80665  # PX4's CONSTANTS_ONE_G


def base_mode_flags(mode: Mode, armed: bool, offboard_signal: bool) -> int:
    """The heartbeat's ``base_mode`` as PX4 v1.16 sends it (measured): CUSTOM_MODE_ENABLED, plus
    STABILIZE|GUIDED|AUTO in the auto modes (29, armed 157) but Follow Target (STABILIZE: 17, 145), MANUAL_INPUT|STABILIZE in Position,
    Altitude, Stabilized and Manual (81 / 209), MANUAL_INPUT in Acro, and in Offboard STABILIZE
    once setpoints have come (1 before, 17 / 145 after: PX4 keeps the last offboard control mode,
    so a vehicle disarmed by the offboard-loss failsafe reports 17); SAFETY_ARMED when armed.
    Flight termination: CUSTOM_MODE_ENABLED and SAFETY_ARMED only (129). ``offboard_signal``:
    whether setpoints have ever come."""
    flags = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        flags |= MAV_MODE_FLAG_SAFETY_ARMED
    if mode is Mode.TERMINATION:
        return flags
    if mode in _AUTO:
        flags |= MAV_MODE_FLAG_STABILIZE_ENABLED | MAV_MODE_FLAG_GUIDED_ENABLED | MAV_MODE_FLAG_AUTO_ENABLED
    elif mode is Mode.ACRO:
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    elif mode in _NEEDS_MANUAL_INPUT or mode is Mode.ORBIT:  # Orbit as Position (not measured)
        flags |= MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | MAV_MODE_FLAG_STABILIZE_ENABLED
    elif (mode is Mode.OFFBOARD and offboard_signal) or mode is Mode.AUTO_FOLLOW_TARGET:
        flags |= MAV_MODE_FLAG_STABILIZE_ENABLED  # Follow Target: 17 / 145 (PX4 v1.16, measured)
    return flags


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
        """Whether the setpoint gives an attitude (PX4 then flies it and ignores the rates)."""
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
class ManualInput:
    """MANUAL_CONTROL as PX4 reads it (``x`` pitch stick, forward +; ``y`` roll stick, right +;
    ``r`` yaw stick, clockwise +; each -1..1; ``z`` throttle 0..1, 0.5 the centre): the raw
    -1000..1000 and 0..1000 divided by 1000."""

    x: float
    y: float
    z: float
    r: float


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
    vehicle descends at that speed (landing); ``max_climb_m_s`` limits the climb (takeoff: below
    zero it asks for a descent of at least that speed, PX4's ramp start that gives no thrust).
    ``vel_ned_m_s`` is a velocity feed-forward, or the velocity setpoint of an axis whose
    position is None (offboard position/velocity setpoints, the sticks of Position mode).
    ``acc_ne_m_s2``: the horizontal acceleration wanted instead of any horizontal control
    (Altitude mode's tilt sticks). ``acc_ff_ne_m_s2``: a horizontal acceleration feed-forward
    added to the velocity loop's output, as PX4's PositionControl adds the flight task's
    acceleration setpoint (Orbit's centripetal acceleration)."""

    pos_ned_m: tuple[float | None, float | None, float | None]
    yaw_rad: float
    descend_m_s: float | None = None
    max_climb_m_s: float | None = None
    vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acc_ne_m_s2: tuple[float, float] | None = None
    acc_ff_ne_m_s2: tuple[float, float] = (0.0, 0.0)


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
    base_mode: int | None = None
    gps_lost_s: float | None = None  # how long the GPS has been failed (None: it is not)


# --- the state machine ------------------------------------------------------------------------


@dataclass
class _Memory:
    last_setpoint: Setpoint | None = None
    last_setpoint_s: float | None = None
    sticks: ManualInput | None = None
    sticks_s: float | None = None
    had_sticks: bool = False  # in this flight (manual control loss is judged against it)
    hold_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hold_yaw: float = 0.0
    takeoff_height_m: float = 2.5
    takeoff_wanted_s: float | None = None  # Takeoff: when the climb was asked for (the ramp starts then, after spool-up)
    armed_at_s: float = 0.0
    contact_since_s: float | None = None  # ground contact, before the land detector says landed
    landed_since_s: float | None = None
    has_taken_off: bool = False
    rtl_landing: bool = False
    last_armable: Mode = Mode.AUTO_LOITER  # the last mode chosen that allows arming
    fallback_of_offboard: bool = False  # the failsafe is the offboard-loss fallback (ends when setpoints return)
    rc_lost_act_at_s: float | None = None  # manual control loss: when the Hold turns into NAV_RCL_ACT
    terminated: bool = False
    vel_sp_ne: tuple[float, float] = (0.0, 0.0)  # Position mode: the stick velocity, shaped
    manual_vz: float | None = None  # the throttle stick's climb (-) / descent (+) rate, m/s NED
    last_update_s: float | None = None


class Autopilot:
    """PX4-like commander for one vehicle.

    Parameters
    ----------
    params : ParamTable
        The plant's parameters (``COM_*``, ``MPC_*``, ``MIS_TAKEOFF_ALT``, ...), read at every use
        so a PARAM_SET takes effect at once.
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
        self._gps_failed_s: float | None = 0.0 if "gps" in self.failures else None  # when the GPS failed
        self.armed = False
        self.mode = Mode.AUTO_LOITER
        self.failsafe = False
        self._m = _Memory()
        self._pos = np.zeros(3)
        self._vel = np.zeros(3)
        self._yaw = 0.0
        self._contact = True  # the simulation's ground contact
        self._landed = True  # the land detector's verdict (PX4: LNDMC_TRIG_TIME after contact)
        self._now = 0.0
        self.counters: dict[str, int] = {"setpoints": 0, "ignored_setpoints": 0, "manual_inputs": 0}
        self.navigator = Navigator(params)
        self.follow = FollowTarget(params)
        self._follow_sp: FollowSetpoint | None = None  # the Follow Target flight task's latest setpoint (None: hold)
        self.origin = (0.0, 0.0, home_alt_amsl_m)  # lat, lon (deg), alt AMSL (m) of the local frame's origin

    # -- status ----------------------------------------------------------------------------------

    def status(self) -> Status:
        """The status the heartbeat and the status streams report now (mode, arming, system status,
        failures, sensor health, landed state, a lost GPS's age).
        """
        now = self._now
        if self._m.terminated:
            system_status = MAV_STATE_FLIGHT_TERMINATION
        elif self.failsafe:
            system_status = MAV_STATE_CRITICAL
        elif self.armed:
            system_status = MAV_STATE_ACTIVE
        else:
            # PX4: UNINIT while arming would be refused, STANDBY when it would be accepted
            system_status = MAV_STATE_STANDBY if self.prearm_failure(now) is None else MAV_STATE_UNINIT
        return Status(
            armed=self.armed,
            mode=self.mode,
            system_status=system_status,
            landed_state=self.landed_state(),
            failsafe=self.failsafe,
            failures=frozenset(self.failures),
            prearm_ok=not self.failures,
            base_mode=base_mode_flags(self.mode, self.armed, self._m.last_setpoint_s is not None),
            gps_lost_s=self.gps_lost_s(now),
        )

    def gps_lost_s(self, now_s: float) -> float | None:
        """How long the GPS has been failed at ``now_s`` (None: it is not)."""
        return None if self._gps_failed_s is None else max(0.0, now_s - self._gps_failed_s)

    def position_valid(self, now_s: float) -> bool:
        """Whether the estimator still vouches for the horizontal position (``DEAD_RECKONING_S``)."""
        lost = self.gps_lost_s(now_s)
        return lost is None or lost < DEAD_RECKONING_S

    def set_origin(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> None:
        """Where the local NED frame's origin is on the globe (for mission items and commands)."""
        self.origin = (lat_deg, lon_deg, alt_amsl_m)

    def frame(self) -> Frame:
        """The local frame and home, as the navigator converts global positions."""
        return Frame(self.origin[0], self.origin[1], self.origin[2], self.home_ned_m)

    def landed_state(self) -> int:
        """EXTENDED_SYS_STATE's landed state: on the ground, taking off, landing or in the air."""
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

    def manual_input_ok(self, now_s: float) -> bool:
        """Manual control present: the last MANUAL_CONTROL is not older than COM_RC_LOSS_T."""
        last = self._m.sticks_s
        return last is not None and now_s - last <= self.params["COM_RC_LOSS_T"]

    @property
    def last_setpoint(self) -> Setpoint | None:
        """The offboard setpoint heard last (None: none yet)."""
        return self._m.last_setpoint

    # -- events ----------------------------------------------------------------------------------

    @property
    def setpoint_time_s(self) -> float | None:
        """When the latest offboard setpoint was taken (s of the vehicle's time; None: none yet)."""
        return self._m.last_setpoint_s

    def on_setpoint(self, setpoint: Setpoint, now_s: float) -> bool:
        """Remember a setpoint (proof of life); returns whether it is flown now (Offboard)."""
        if isinstance(setpoint, AttitudeSetpoint) and not setpoint.is_setpoint:
            self.counters["ignored_setpoints"] += 1
            return False
        self.counters["setpoints"] += 1
        self._m.last_setpoint = setpoint
        self._m.last_setpoint_s = now_s
        return self.armed and self.mode is Mode.OFFBOARD

    def on_manual_input(self, sticks: ManualInput, now_s: float) -> None:
        """MANUAL_CONTROL (virtual sticks), flown in the manual modes."""
        self.counters["manual_inputs"] += 1
        m = self._m
        m.sticks, m.sticks_s = sticks, now_s
        m.had_sticks = True
        if m.rc_lost_act_at_s is not None:  # manual control regained: the failsafe ends
            m.rc_lost_act_at_s = None
            self.failsafe = False

    def on_follow_target(self, pos_ned_m: tuple[float, float, float], vel_ned_m_s: tuple[float, float, float], now_s: float) -> None:
        """A FOLLOW_TARGET report (the server has turned its global position into local NED): the
        target estimator of Follow Target takes it while that mode is on (PX4 builds the estimator
        with the flight task)."""
        if self.mode is Mode.AUTO_FOLLOW_TARGET:
            self.follow.report(now_s, pos_ned_m, vel_ned_m_s)

    def observe(self, truth: VehicleState) -> None:
        """Take in the vehicle's state (the autopilot's estimate is the truth here)."""
        self._pos = truth.pos_ned_m
        self._vel = truth.vel_ned_m_s
        self._yaw = float(truth.euler_rad[2])
        self._contact = bool(truth.on_ground)
        if not self._contact:
            self._landed = False

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

    def mode_can_run(self, mode: Mode, now_s: float) -> bool:
        """Whether ``mode`` has what it needs (setpoints, sticks, a mission)."""
        if mode is Mode.OFFBOARD:
            return self.offboard_signal_ok(now_s)
        if mode in _NEEDS_MANUAL_INPUT:
            return self.manual_input_ok(now_s)
        if mode in _NEEDS_POSITION and not self.position_valid(now_s):
            return False  # PX4 v1.16 after its GPS stopped: Hold refused, Land kept (measured)
        if mode is Mode.AUTO_MISSION:
            return bool(self.navigator.items)  # PX4 1.16 in the air: refused without a valid mission
        return mode not in (Mode.AUTO_READY, Mode.ORBIT)  # Orbit is entered by MAV_CMD_DO_ORBIT

    def set_mode(self, mode: Mode | None, now_s: float) -> Reply:
        """A mode change asked by a client (DO_SET_MODE or the legacy SET_MODE).

        PX4 accepts every mode while disarmed (arming then says whether it can fly it); armed, a
        mode that cannot run is refused."""
        self._now = max(self._now, now_s)
        if mode is None or mode is Mode.TERMINATION:
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, "Unknown mode"),))
        if self._m.terminated:
            return _refuse("Flight termination active")
        if mode is self.mode and not self.failsafe:
            return Reply(MAV_RESULT_ACCEPTED)
        if self.armed and not self.mode_can_run(mode, now_s):
            return _refuse(f"Switching to {mode.label} is currently not available")
        if mode is Mode.AUTO_TAKEOFF:
            self._prepare_takeoff(math.nan, now_s)
        self._enter(mode, now_s, by_client=True)
        return Reply(MAV_RESULT_ACCEPTED)

    def update(self, now_s: float) -> list[StatusText]:
        """Time-driven logic: land detector, offboard and manual control loss, takeoff done, Return
        at home, auto-disarm, the sticks' integration."""
        texts: list[StatusText] = []
        m = self._m
        p = self.params
        dt = 0.0 if m.last_update_s is None else max(0.0, now_s - m.last_update_s)
        m.last_update_s = now_s
        self._now = now_s
        texts.extend(self._land_detector(now_s))
        if self.armed and not self._landed:
            m.has_taken_off = True
        texts.extend(self._offboard_loss(now_s))
        texts.extend(self._manual_control_loss(now_s))
        texts.extend(self._position_loss(now_s))
        if self.armed and self.mode is Mode.AUTO_TAKEOFF and m.has_taken_off:
            target_down = self._takeoff_down_m()
            if self._pos[2] <= target_down + p["NAV_MC_ALT_RAD"]:  # PX4's navigator: within the altitude acceptance
                self._enter(Mode.AUTO_LOITER, now_s)
                m.hold_pos = (m.hold_pos[0], m.hold_pos[1], target_down)
                texts.append(StatusText(MAV_SEVERITY_INFO, "Takeoff complete, holding"))
        texts.extend(self._navigate(now_s))
        if self.mode is Mode.AUTO_FOLLOW_TARGET:
            here = (float(self._pos[0]), float(self._pos[1]), float(self._pos[2]))
            self._follow_sp = self.follow.step(now_s, here)
        if self.armed and self.mode in _NEEDS_MANUAL_INPUT:
            self._integrate_sticks(now_s, dt)
        texts.extend(self._auto_disarm(now_s))
        return texts

    def task(self) -> Task:
        """What the inner loops fly now."""
        m = self._m
        if not self.armed or m.terminated:
            return IdleTask()
        mode = self.mode
        now = self._now
        if mode is Mode.OFFBOARD and m.last_setpoint is not None:
            return OffboardTask(m.last_setpoint)
        if mode is Mode.AUTO_TAKEOFF:
            limit = self._takeoff_climb_limit(now, approach_down_m=self._takeoff_down_m())
            if limit is None:
                return IdleTask()  # spooling up
            return PositionTask((m.hold_pos[0], m.hold_pos[1], self._takeoff_down_m()), m.hold_yaw, max_climb_m_s=limit)
        if mode in _NEEDS_MANUAL_INPUT:
            return self._manual_task(now)
        if mode is Mode.AUTO_FOLLOW_TARGET and self._follow_sp is not None and not self._landed:
            f = self._follow_sp
            return PositionTask(f.pos_ned_m, f.yaw_rad, vel_ned_m_s=f.vel_ned_m_s, acc_ff_ne_m_s2=f.acc_ff_ne_m_s2)
        nav = self._nav_setpoint()
        if nav is not None:
            if self._landed and (nav.landing or (not m.has_taken_off and nav.max_climb_m_s is None)):
                return IdleTask()
            climb = nav.max_climb_m_s
            if climb is not None:  # the navigator's take-off speed, through PX4's takeoff handling
                climb = self._takeoff_climb_limit(now, speed_m_s=climb, approach_down_m=nav.pos_ned_m[2] if nav.takeoff else None)
                if climb is None:
                    return IdleTask()  # spooling up
            pos = nav.pos_ned_m if nav.hold_xy else (None, None, nav.pos_ned_m[2])
            return PositionTask(pos, nav.yaw_rad, descend_m_s=nav.descend_m_s, max_climb_m_s=climb, vel_ned_m_s=nav.vel_ned_m_s,
                                acc_ff_ne_m_s2=nav.acc_ff_ne_m_s2)  # fmt: skip
        if self._landed and (not m.has_taken_off or mode in (Mode.AUTO_LAND, Mode.AUTO_LOITER, Mode.AUTO_FOLLOW_TARGET) or m.rtl_landing):
            return IdleTask()
        if mode is Mode.AUTO_LAND:
            if not self.position_valid(now):
                # blind: with the horizontal velocity estimate gone PX4's position control takes no
                # horizontal acceleration (level) and only descends; the vehicle coasts on its drag
                return PositionTask((None, None, m.hold_pos[2]), m.hold_yaw, descend_m_s=self.land_speed_m_s(), acc_ne_m_s2=(0.0, 0.0))
            return PositionTask(m.hold_pos, m.hold_yaw, descend_m_s=self.land_speed_m_s())
        return PositionTask(m.hold_pos, m.hold_yaw)

    # -- PX4's speed profiles ----------------------------------------------------------------------

    def land_speed_m_s(self) -> float:
        """PX4's landing speed at the current height (``navigator.land_speed_m_s``)."""
        return land_speed_m_s(self.params.__getitem__, self.home_ned_m[2] - float(self._pos[2]))

    def _takeoff_climb_limit(self, now_s: float, *, speed_m_s: float | None = None, approach_down_m: float | None = None) -> float | None:
        """PX4's takeoff handling (mc_pos_control/Takeoff, ``updateRamp``), for every take-off from
        the ground (Takeoff mode, a mission's or a DO_REPOSITION's, the sticks'): None while the
        motors spool up (COM_SPOOLUP_TIME after arming); then the upward velocity limit goes
        linearly over MPC_TKO_RAMP_T, from when the climb was asked for, from -g / MPC_Z_VEL_P_ACC
        (no thrust) to ``speed_m_s`` (the flight task's take-off speed, default MPC_TKO_SPEED).
        With ``approach_down_m`` (the take-off height, NED down) the climb slows near it. A climb
        asked for in the air (no take-off from the ground in this flight) is not ramped."""
        m, p = self._m, self.params
        speed = p["MPC_TKO_SPEED"] if speed_m_s is None else speed_m_s
        target = speed
        if approach_down_m is not None:
            # the climb PX4's takeoff trajectory asks for slows near the height (fitted, docs/parity)
            remaining = max(float(self._pos[2]) - approach_down_m, 0.0)
            target = min(speed, TAKEOFF_APPROACH_GAIN * math.sqrt(remaining))
        if m.takeoff_wanted_s is None and m.has_taken_off:
            return target
        spooled = m.armed_at_s + p["COM_SPOOLUP_TIME"]
        if now_s < spooled:
            return None
        wanted = m.takeoff_wanted_s if m.takeoff_wanted_s is not None else now_s
        start = max(spooled, wanted)
        ramp_t = p["MPC_TKO_RAMP_T"]
        if not self._landed and m.has_taken_off and ramp_t <= 0:
            return speed
        init = -G_M_S2 / max(p["MPC_Z_VEL_P_ACC"], 0.01)
        progress = 1.0 if ramp_t <= 0 else min(max((now_s - start) / ramp_t, 0.0), 1.0)
        return init + progress * (target - init)

    # -- the manual modes --------------------------------------------------------------------------

    def _sticks_now(self, now_s: float) -> ManualInput | None:
        return self._m.sticks if self.manual_input_ok(now_s) else None

    def _integrate_sticks(self, now_s: float, dt: float) -> None:
        """What the sticks ask for, with PX4's shaping (expo curves MPC_*_EXPO, the MPC_HOLD_DZ dead
        zone): the yaw rate (MPC_MAN_Y_MAX), the climb rate (MPC_Z_VEL_MAX_UP / _DN, the height
        held when the throttle is centred) and, in Position, the horizontal velocity: acceleration
        MPC_ACC_HOR with the drag that gives MPC_VEL_MANUAL at full stick (StickAccelerationXY),
        braking at MPC_ACC_HOR when released, then the position held where it stopped."""
        m, p = self._m, self.params
        sticks = self._sticks_now(now_s)
        if sticks is None:
            m.vel_sp_ne, m.manual_vz = (0.0, 0.0), None
            return
        rate = _expo(_deadzone(sticks.r, p["MPC_HOLD_DZ"]), p["MPC_YAW_EXPO"]) * math.radians(p["MPC_MAN_Y_MAX"])
        m.hold_yaw = _wrap(m.hold_yaw + rate * dt)
        throttle = _expo(_deadzone(2.0 * sticks.z - 1.0, p["MPC_HOLD_DZ"]), p["MPC_Z_MAN_EXPO"])
        if throttle != 0.0:
            m.manual_vz = -throttle * (p["MPC_Z_VEL_MAX_UP"] if throttle > 0 else p["MPC_Z_VEL_MAX_DN"])
            m.hold_pos = (m.hold_pos[0], m.hold_pos[1], float(self._pos[2]))
            if throttle > 0 and self._landed and m.takeoff_wanted_s is None:
                m.takeoff_wanted_s = now_s  # PX4's takeoff ramp starts with the climb asked for
        else:
            if m.manual_vz is not None and m.manual_vz != 0.0:
                m.hold_pos = (m.hold_pos[0], m.hold_pos[1], float(self._pos[2]))
            m.manual_vz = 0.0
        if self.mode is not Mode.POSCTL:
            return
        fwd = _expo(_deadzone(sticks.x, p["MPC_HOLD_DZ"]), p["MPC_XY_MAN_EXPO"])
        right = _expo(_deadzone(sticks.y, p["MPC_HOLD_DZ"]), p["MPC_XY_MAN_EXPO"])
        c, s = math.cos(m.hold_yaw), math.sin(m.hold_yaw)
        stick_ne = (c * fwd - s * right, s * fwd + c * right)
        acc_max, v_max = p["MPC_ACC_HOR"], p["MPC_VEL_MANUAL"]
        drag = acc_max / v_max if v_max > 0 else 0.0
        vn, ve = m.vel_sp_ne
        if fwd == 0.0 and right == 0.0:
            speed = math.hypot(vn, ve)
            if speed > 0.0:
                scale = max(speed - acc_max * dt, 0.0) / speed
                vn, ve = vn * scale, ve * scale
        else:
            vn += (acc_max * stick_ne[0] - drag * vn) * dt
            ve += (acc_max * stick_ne[1] - drag * ve) * dt
        m.vel_sp_ne = (vn, ve)
        if vn != 0.0 or ve != 0.0:
            m.hold_pos = (float(self._pos[0]), float(self._pos[1]), m.hold_pos[2])

    def _manual_task(self, now_s: float) -> Task:
        """Position / Altitude (and the other manual modes, flown as Altitude) from the sticks
        (``_integrate_sticks``); without stick input PX4's failsafe flight task: hold the
        horizontal position, descend at MPC_LAND_SPEED. Stabilized without stick input (the
        offboard-loss fallback COM_OBL_RC_ACT 2) is PX4's attitude control of a manual control
        setpoint of zeros: level, the yaw held, thrust MPC_THR_HOVER (the throttle curve's centre);
        PX4 SIH sank 0.07 m/s so (measured, docs/parity/commander.md)."""
        m, p = self._m, self.params
        sticks = self._sticks_now(now_s)
        vz = m.manual_vz
        if sticks is None or vz is None:
            if self._landed:
                return IdleTask()
            if self.mode is Mode.STABILIZED:
                half = 0.5 * m.hold_yaw
                level = (math.cos(half), 0.0, 0.0, math.sin(half))
                return OffboardTask(AttitudeSetpoint(0, level, (None, None, 0.0), p["MPC_THR_HOVER"]))
            return PositionTask((m.hold_pos[0], m.hold_pos[1], None), m.hold_yaw, descend_m_s=p["MPC_LAND_SPEED"])
        if self._landed and vz >= 0.0:
            return IdleTask()
        limit = None if m.has_taken_off else self._takeoff_climb_limit(now_s)
        if limit is None and not m.has_taken_off:
            return IdleTask()  # spooling up
        down = m.hold_pos[2] if vz == 0.0 else None
        if self.mode is Mode.POSCTL:
            vn, ve = m.vel_sp_ne
            moving = vn != 0.0 or ve != 0.0
            pos = (None if moving else m.hold_pos[0], None if moving else m.hold_pos[1], down)
            return PositionTask(pos, m.hold_yaw, max_climb_m_s=limit, vel_ned_m_s=(vn, ve, vz))
        tilt = math.radians(p["MPC_MAN_TILT_MAX"])
        c, s = math.cos(m.hold_yaw), math.sin(m.hold_yaw)
        a_fwd, a_right = G_M_S2 * math.tan(tilt * sticks.x), G_M_S2 * math.tan(tilt * sticks.y)
        acc = (c * a_fwd - s * a_right, s * a_fwd + c * a_right)
        return PositionTask((None, None, down), m.hold_yaw, max_climb_m_s=limit, vel_ned_m_s=(0.0, 0.0, vz), acc_ne_m_s2=acc)

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
        """Arm, unless a pre-arm check fails (``forced``: without them, as MAV_CMD_COMPONENT_ARM_DISARM's
        magic number 21196).
        """
        self._now = max(self._now, now_s)
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
        m.terminated = False
        m.takeoff_wanted_s = now_s if self.mode is Mode.AUTO_TAKEOFF else None
        m.had_sticks = self.manual_input_ok(now_s)
        m.vel_sp_ne = (0.0, 0.0)
        if self._landed:
            self.home_ned_m = (float(self._pos[0]), float(self._pos[1]), float(self._pos[2]))
        self._set_hold_here()
        if self.mode is Mode.AUTO_MISSION:
            self.navigator.start("mission", now_s)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, "Armed by external command"),))

    def disarm(self, now_s: float, *, forced: bool = False) -> Reply:
        """Disarm, on the ground only unless ``forced`` (then in the air too: the motors stop)."""
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
        if self.mode is Mode.AUTO_FOLLOW_TARGET:
            return "Resolve system health failures first"  # PX4 v1.16's words (measured): mode_req_prevent_arming
        if self.mode not in _ARMABLE:
            return f"not possible in {self.mode.label} mode"
        if not self.mode_can_run(self.mode, now_s):
            return "Resolve system health failures first"  # PX4's words for a mode that cannot run
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
        self._prepare_takeoff(cmd.params[6], now_s)
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
        takes off towards the point (climbing at most MPC_TKO_SPEED, after the spool-up and the
        takeoff ramp of ``_takeoff_climb_limit``)."""
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

    def _nav_setpoint(self) -> NavSetpoint | None:
        """The navigator's setpoint when it is the one flown (its modes, and Hold after DO_REPOSITION)."""
        if self.mode in _NAVIGATED or self.navigator.activity == "reposition":
            return self.navigator.setpoint()
        return None

    def _navigate(self, now_s: float) -> list[StatusText]:
        nav = self.navigator
        nav.frame = self.frame()
        nav.observe((float(self._pos[0]), float(self._pos[1]), float(self._pos[2])), self._yaw, self._landed)
        if not self.armed:
            return []
        nav.update(now_s)
        sp = self._nav_setpoint()
        if sp is not None and sp.max_climb_m_s is not None and self._landed and self._m.takeoff_wanted_s is None:
            self._m.takeoff_wanted_s = now_s  # PX4's takeoff ramp starts with the climb asked for
        if nav.wants_rtl and self.mode is Mode.AUTO_MISSION:
            self._enter(Mode.AUTO_RTL, now_s)
            return [StatusText(MAV_SEVERITY_INFO, "Mission: returning to launch")]
        return []

    def inject_failure(self, unit: str, now_s: float) -> None:
        """Fail ``unit`` (a ``FAILURE_UNITS`` name) at ``now_s``; a GPS lost starts EKF2's dead reckoning."""
        if unit == "gps" and unit not in self.failures:
            self._gps_failed_s = now_s
        self.failures.add(unit)

    def clear_failure(self, unit: str) -> None:
        """Make ``unit`` (a ``FAILURE_UNITS`` name) work again; a GPS back ends the dead reckoning."""
        self.failures.discard(unit)
        if unit == "gps":
            self._gps_failed_s = None

    def _cmd_inject_failure(self, cmd: Command, now_s: float) -> Reply:
        if int(self.params["SYS_FAILURE_EN"]) != 1:
            return Reply(MAV_RESULT_DENIED, (StatusText(MAV_SEVERITY_CRITICAL, "Failure injection disabled (SYS_FAILURE_EN)"),))
        unit_code, kind = cmd.params[0], cmd.params[1]
        unit = FAILURE_UNITS.get(int(unit_code)) if math.isfinite(unit_code) else None
        if unit is None or not math.isfinite(kind):
            return Reply(MAV_RESULT_UNSUPPORTED)
        if int(kind) == FAILURE_TYPE_OK:
            self.clear_failure(unit)
            return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO, f"Failure cleared: {unit}"),))
        self.inject_failure(unit, now_s)
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_WARNING, f"Failure injected: {unit}"),))

    def _cmd_prearm(self, cmd: Command, now_s: float) -> Reply:
        if self.armed:
            return Reply(MAV_RESULT_TEMPORARILY_REJECTED)
        reason = self.prearm_failure(now_s)
        text = "Preflight checks passed" if reason is None else f"Preflight Fail: {reason}"
        return Reply(MAV_RESULT_ACCEPTED, (StatusText(MAV_SEVERITY_INFO if reason is None else MAV_SEVERITY_CRITICAL, text),))

    # -- failsafes -------------------------------------------------------------------------------

    def _offboard_loss(self, now_s: float) -> list[StatusText]:
        """PX4's mode fallback for offboard loss (failsafe.cpp): at once, not deferred by
        COM_FAIL_ACT_T; it clears when the setpoints come back (back to Offboard)."""
        m = self._m
        if m.fallback_of_offboard and self.failsafe and self.armed and self.offboard_signal_ok(now_s):
            m.fallback_of_offboard = False
            self.failsafe = False
            self._enter(Mode.OFFBOARD, now_s)
            return [StatusText(MAV_SEVERITY_INFO, "Failsafe deactivated: offboard signal back")]
        if not (self.armed and self.mode is Mode.OFFBOARD and not self.offboard_signal_ok(now_s)):
            return []
        action = int(self.params["COM_OBL_RC_ACT"])
        texts = [StatusText(MAV_SEVERITY_CRITICAL, "Failsafe activated")]
        if action == OBL_DISARM:
            self._disarm()
            return [*texts, StatusText(MAV_SEVERITY_INFO, "Disarmed by failsafe")]
        self.failsafe = True
        if action == OBL_TERMINATE:
            self._terminate()
        else:
            m.fallback_of_offboard = True
            self._enter(OBL_ACTIONS.get(action, Mode.POSCTL), now_s)
        return texts

    def _position_loss(self, now_s: float) -> list[StatusText]:
        """PX4's mode fallback for a lost position estimate: a mode that needs one lands blind, at
        once (``_NEEDS_POSITION``); the failsafe stays until a client picks a mode."""
        if not (self.armed and not self._landed and self.mode in _NEEDS_POSITION and not self.position_valid(now_s)):
            return []
        self.failsafe = True
        self._set_hold_here()
        self._enter(Mode.AUTO_LAND, now_s)
        return [StatusText(MAV_SEVERITY_CRITICAL, "Failsafe activated")]

    def _manual_control_loss(self, now_s: float) -> list[StatusText]:
        """Sticks gone for COM_RC_LOSS_T in a manual mode: Hold for COM_FAIL_ACT_T, then
        NAV_RCL_ACT (PX4's manual-control-loss failsafe, deferred by its hold delay)."""
        m, p = self._m, self.params
        if m.rc_lost_act_at_s is not None:
            if self.failsafe and self.mode is Mode.AUTO_LOITER and now_s >= m.rc_lost_act_at_s:
                m.rc_lost_act_at_s = None
                action = int(p["NAV_RCL_ACT"])
                if action == RCL_DISARM:
                    self._disarm()
                elif action == RCL_TERMINATE:
                    self._terminate()
                elif action in RCL_ACTIONS and RCL_ACTIONS[action] is not Mode.AUTO_LOITER:
                    self._enter(RCL_ACTIONS[action], now_s)
                return [StatusText(MAV_SEVERITY_CRITICAL, "Failsafe activated")]
            return []
        if not (self.armed and m.had_sticks and self.mode in _NEEDS_MANUAL_INPUT and not self.manual_input_ok(now_s)):
            return []
        if int(p["NAV_RCL_ACT"]) == 0 or self._landed:
            return []
        self.failsafe = True
        self._enter(Mode.AUTO_LOITER, now_s)
        m.rc_lost_act_at_s = now_s + p["COM_FAIL_ACT_T"]
        return [StatusText(MAV_SEVERITY_CRITICAL, f"Failsafe activated: entering Hold for {p['COM_FAIL_ACT_T']:g} seconds")]

    def _terminate(self) -> None:
        """Flight termination: the motors stop (the vehicle falls). PX4 v1.16 (measured) reports
        custom main mode 10 (TERMINATION), base_mode 129, system status FLIGHT_TERMINATION, and
        stays so, armed, on the ground: only a reboot ends it."""
        self._m.terminated = True
        self.mode = Mode.TERMINATION

    # -- internals -------------------------------------------------------------------------------

    def _prepare_takeoff(self, param7_amsl_m: float, now_s: float) -> None:
        height = self.params["MIS_TAKEOFF_ALT"]
        if math.isfinite(param7_amsl_m) and param7_amsl_m - self.home_alt_amsl_m > 0.5:
            height = param7_amsl_m - self.home_alt_amsl_m
        self._m.takeoff_height_m = height
        self._m.takeoff_wanted_s = now_s

    def _takeoff_down_m(self) -> float:
        return self.home_ned_m[2] - self._m.takeoff_height_m

    def _set_hold_here(self) -> None:
        self._m.hold_pos = (float(self._pos[0]), float(self._pos[1]), float(self._pos[2]))
        self._m.hold_yaw = self._yaw

    def _enter(self, mode: Mode, now_s: float, *, by_client: bool = False) -> None:
        """Switch mode; a mode the client chooses ends a failsafe (PX4: the user takes over)."""
        m = self._m
        if by_client:
            self.failsafe = False
            m.fallback_of_offboard = False
            m.rc_lost_act_at_s = None
            if mode in _ARMABLE:
                m.last_armable = mode
        self._set_hold_here()
        m.rtl_landing = False
        m.vel_sp_ne = (0.0, 0.0)
        m.manual_vz = 0.0
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
        self._follow_sp = None
        if mode is Mode.AUTO_FOLLOW_TARGET:
            self.follow.activate(self._yaw, self.home_ned_m[2], now_s)

    def _land_detector(self, now_s: float) -> list[StatusText]:
        """PX4's land detector in miniature: landed LNDMC_TRIG_TIME + LAND_DETECT_WINDDOWN_S after
        the ground contact began (at once while disarmed or before the takeoff)."""
        m = self._m
        if not self._contact or not self._thrust_low_enough_to_land():
            m.contact_since_s = None
            return []
        if self._landed:
            return []
        if m.contact_since_s is None:
            m.contact_since_s = now_s
        delay = self.params["LNDMC_TRIG_TIME"] + LAND_DETECT_WINDDOWN_S
        if not (self.armed and m.has_taken_off) or now_s - m.contact_since_s >= delay - EPS_S:
            self._landed = True
            if self.armed and m.has_taken_off:
                m.landed_since_s = now_s
                return [StatusText(MAV_SEVERITY_INFO, "Landing detected")]
        return []

    def _thrust_low_enough_to_land(self) -> bool:
        """PX4's land detector needs the thrust at its floor: where no climb rate is controlled
        (Offboard with attitude, rate or actuator setpoints) "maybe landed" takes a collective
        thrust of at most MPC_MANTHR_MIN + 0.01 (MulticopterLandDetector::_get_maybe_landed_state),
        so a client holding about hover thrust on the ground is not landed, nor disarmed. In the
        plant's own modes its controller winds the thrust down on contact (the fitted delay)."""
        if self.mode is not Mode.OFFBOARD or not self.armed:
            return True
        sp = self._m.last_setpoint
        if isinstance(sp, AttitudeSetpoint) and sp.thrust_norm is not None:
            thrust = sp.thrust_norm
        elif isinstance(sp, ActuatorSetpoint):
            thrust = sp.controls[3]
        else:
            return True
        return thrust <= self.params["MPC_MANTHR_MIN"] + 0.01

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
            delay = p["COM_DISARM_LAND"]
            if m.terminated:
                return []  # PX4: flight termination is not ended by landing
            if delay > 0 and now_s - m.landed_since_s >= delay - EPS_S:
                self._disarm()
                return [StatusText(MAV_SEVERITY_INFO, "Disarmed by landing")]
            return []
        delay = p["COM_DISARM_PRFLT"]
        if delay > 0 and now_s - m.armed_at_s >= delay and self.mode is not Mode.AUTO_TAKEOFF:
            self._disarm()
            return [StatusText(MAV_SEVERITY_INFO, "Disarmed by auto preflight disarming")]
        return []

    def _disarm(self) -> None:
        m = self._m
        self.armed = False
        self.failsafe = False
        m.fallback_of_offboard = False
        m.rc_lost_act_at_s = None
        m.has_taken_off = False
        m.landed_since_s = None
        m.terminated = False
        m.takeoff_wanted_s = None
        if self.mode not in _ARMABLE:
            # PX4: after a disarm the commander goes back to the last mode that allows arming
            self._enter(m.last_armable, 0.0)


EPS_S = 1e-9  # time comparisons: sums of ticks are not exact
#: Touch-down to "Landing detected" took PX4 v1.16 SIH about 3 s (measured, docs/parity/commander.md):
#: LNDMC_TRIG_TIME for its three detector stages, the rest (fitted) for the thrust to wind down to
#: the landed threshold while the landing setpoint still pushes down.
LAND_DETECT_WINDDOWN_S = 2.0
#: The takeoff climb PX4's trajectory asks for, v = min(MPC_TKO_SPEED, K sqrt(remaining m)), K in
#: m^0.5/s, the end of the ramp: fitted to PX4 v1.16 SITL's takeoffs to 2.5 m (climbing at up to
#: 0.86-0.98 m/s, lift-off 2.7-4.2 s and 90 % of the height about 7 s after the command).
TAKEOFF_APPROACH_GAIN = 0.6


def _expo(value: float, e: float) -> float:
    """PX4's math::expo: (1 - e) v + e v^3, v clipped to [-1, 1]."""
    v = min(max(value, -1.0), 1.0)
    e = min(max(e, 0.0), 1.0)
    return (1.0 - e) * v + e * v * v * v


def _deadzone(value: float, dz: float) -> float:
    """PX4's math::deadzone: 0 within +-dz, rescaled to reach +-1 at the ends."""
    v = min(max(value, -1.0), 1.0)
    if abs(v) <= dz or dz >= 1.0:
        return 0.0
    return (v - math.copysign(dz, v)) / (1.0 - dz)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


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
    "ManualInput",
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
