"""MAVLink encoding and decoding for the offboard process: pure functions, no sockets.

Incoming: ATTITUDE and LOCAL_POSITION_NED become a ``MeasuredState`` (NED/FRD), the state every
controller reads (the paper's 12-state of it: ``offboard.controller.paper.paper_state_of``); HEARTBEAT,
COMMAND_ACK, PARAM_VALUE and TIMESYNC become small typed values.
Outgoing: a controller's ``Command`` (``offboard.controller.command``) becomes
SET_ATTITUDE_TARGET or SET_ACTUATOR_CONTROL_TARGET fields by ``command_setpoint``, the one
encoding both ``offboard fly`` and ``offboard replay --rerun`` use, so a re-run compares like with
like; commands are built as COMMAND_LONG. Every function is testable with pymavlink's ``pack()`` and ``parse_buffer()``.

Frames and units are MAVLink's: NED metres, FRD body rates in rad/s, the quaternion (w, x, y, z)
rotating body FRD into NED, ZYX Euler angles. The setpoint mapping (docs/offboard.md):

- ``attitude``, thrust ``u / SIM_THR_MAX`` clipped to [0, 1] in both cases:

  - paper model: body rates ``omega = W_eta(eta(n)) @ (x8ref, x10ref, x12ref)`` (eq. 3) with the
    controller's W_eta form at the measured attitude of sample n, marked as a rate setpoint
    (type_mask 128: attitude ignored; q still carries the ZYX quaternion of (x7ez, x9ez,
    x11d(n+1)) for the log). ``sitl-plant --inner-loop paper`` turns the rates of a rate setpoint
    into tau_tilde by inverting exactly that map at the same attitude (an attitude setpoint would
    get its rates from the PX4 attitude P there, docs/plant.md), so the flight reproduces the
    in-process run; ``--inner-loop px4`` flies the same rates with PX4's rate controller.
  - rigid body (PX4): q = the attitude with the law's thrust axis and the heading x11d(n+1)
    (``offboard.frames.setpoint_attitude``); PX4 flies q and reads ``body_yaw_rate`` as the yaw-rate
    feed-forward (``yaw_sp_move_rate``, a world-frame rate, added to its own yaw P), so that field
    carries the reference's yaw rate (``LawOutput.yaw_rate_ff_rad_s``: 0 at a step, where x12ref,
    which holds the law's yaw-error feedback, asked for 63 rad/s at the paper's pi step) and the
    roll and pitch rates, which PX4 ignores beside an attitude, are marked ignored (type_mask 3).
    Sending the body-frame r there instead feeds roll and pitch motion into the yaw loop: on the
    paper helix that turns the yaw step at 12 s into a lasting +-35 deg limit cycle.
- ``actuator``: group 0, controls = (tau_roll / SIM_TQ_RP_MAX, tau_pitch / SIM_TQ_RP_MAX,
  tau_yaw / SIM_TQ_Y_MAX) clipped to [-1, 1] and ``u / SIM_THR_MAX`` clipped to [0, 1], where the
  torque is the body torque ``solve(W_eta^T, tau_gen)`` for a rigid body (virtual work:
  ``tau_gen = W_eta^T tau_body``) and the generalised torque of eq. 16 itself for the paper model.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from offboard.controller.command import Command, require
from offboard.model.euler_lagrange import EulerRateForm
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel
from offboard.model import px4_modes
from offboard.model.messages import MAVLinkMessage
from offboard.model.rotations import quat_from_euler

#: PX4's custom main modes (px4_custom_mode.h) the offboard process cares about (offboard.model.px4_modes).
PX4_MAIN_MODE_OFFBOARD = px4_modes.MAIN_OFFBOARD
PX4_MAIN_MODE_AUTO = px4_modes.MAIN_AUTO
PX4_SUB_MODE_AUTO_LAND = px4_modes.SUB_AUTO_LAND


class SetpointOutput(enum.StrEnum):
    """The setpoint messages the law's output travels in (``--output``; ``command_setpoint``): an
    attitude and thrust, body rates and thrust (both SET_ATTITUDE_TARGET, as PX4 takes them), or
    SET_ACTUATOR_CONTROL_TARGET torques."""

    ATTITUDE = "attitude"
    RATES = "rates"
    ACTUATOR = "actuator"


#: The outputs by name, the default first.
OUTPUTS = tuple(o.value for o in SetpointOutput)

#: How many recent ATTITUDE messages ``offboard fly`` keeps to pair one with a position's instant
#: (``Flight._sample``), and how far back a re-run looks for it.
RECENT_ATTITUDES = 16

FORCE_ARM_MAGIC = 21196  # PX4: param2 of ARM_DISARM that skips the checks (not used by default)


class BadTelemetry(ValueError):
    """A telemetry message with a non-finite field: ignored (counted), never used."""


# --- incoming: the measured state ----------------------------------------------------------------


@dataclass(frozen=True)
class MeasuredState:
    """The vehicle's report of one sample, NED/FRD.

    Attributes
    ----------
    time_boot_ms : int
        The ATTITUDE stamp (the one a lockstep setpoint echoes).
    position_time_boot_ms : int
        The LOCAL_POSITION_NED stamp (equal to ``time_boot_ms`` in lockstep).
    pos_ned_m, vel_ned_m_s : ndarray (3,)
    euler_rad : ndarray (3,)
        (roll, pitch, yaw) as ATTITUDE reports them.
    body_rate_frd_rad_s : ndarray (3,)
        (p, q, r) as ATTITUDE reports them.
    age_s : float or None
        How long before the sample the ATTITUDE arrived (s, our clock), when the sample is taken
        on our own clock; None otherwise (lockstep, the vehicle's clock: sampled as it arrives).
    """

    time_boot_ms: int
    position_time_boot_ms: int
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    euler_rad: np.ndarray
    body_rate_frd_rad_s: np.ndarray
    age_s: float | None = None

    @property
    def quat_wxyz(self) -> np.ndarray:
        """The attitude (body FRD -> NED) of the reported ZYX angles."""
        return quat_from_euler(float(self.euler_rad[0]), float(self.euler_rad[1]), float(self.euler_rad[2]))


def check_attitude(msg: MAVLinkMessage) -> None:
    """Raise ``BadTelemetry`` unless every field of an ATTITUDE message is finite."""
    values = (msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    if not all(math.isfinite(v) for v in values):
        raise BadTelemetry("ATTITUDE with a non-finite field")


def check_local_position(msg: MAVLinkMessage) -> None:
    """Raise ``BadTelemetry`` unless every field of a LOCAL_POSITION_NED message is finite."""
    values = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
    if not all(math.isfinite(v) for v in values):
        raise BadTelemetry("LOCAL_POSITION_NED with a non-finite field")


def measured_state(attitude: MAVLinkMessage, local_position: MAVLinkMessage) -> MeasuredState:
    """The measured state from one ATTITUDE and one LOCAL_POSITION_NED message.

    Raises
    ------
    BadTelemetry
        A field of either message is NaN or infinite.
    """
    check_attitude(attitude)
    check_local_position(local_position)
    return MeasuredState(
        time_boot_ms=int(attitude.time_boot_ms),
        position_time_boot_ms=int(local_position.time_boot_ms),
        pos_ned_m=np.array([local_position.x, local_position.y, local_position.z], dtype=float),
        vel_ned_m_s=np.array([local_position.vx, local_position.vy, local_position.vz], dtype=float),
        euler_rad=np.array([attitude.roll, attitude.pitch, attitude.yaw], dtype=float),
        body_rate_frd_rad_s=np.array([attitude.rollspeed, attitude.pitchspeed, attitude.yawspeed], dtype=float),
    )


def euler_rate_form_for(model: VehicleModel, controller_form: EulerRateForm) -> EulerRateForm:
    """The W_eta that matches what the vehicle reports.

    A rigid body (any real vehicle, PX4, ``sitl-plant --model rigid-body``) reports ZYX Euler
    angles and true body rates, so ``zyx``; the paper's model reports its generalised
    coordinates with its own W_eta, which the controller file names (``castillo``).
    """
    if model not in VEHICLE_MODELS:
        raise ValueError(f"model must be one of {VEHICLE_MODELS}, got {model!r}")
    return EulerRateForm.ZYX if model == VehicleModel.RIGID_BODY else controller_form


# --- outgoing: setpoints -------------------------------------------------------------------------


@dataclass(frozen=True)
class Scaling:
    """The vehicle's published scaling of normalised setpoints.

    Attributes
    ----------
    thrust_max_n : float
        Collective thrust at normalised thrust 1 (``SIM_THR_MAX``).
    torque_roll_pitch_max_nm, torque_yaw_max_nm : float or None
        Torque at normalised torque 1 (``SIM_TQ_RP_MAX``, ``SIM_TQ_Y_MAX``); needed only for the
        actuator output.
    """

    thrust_max_n: float
    torque_roll_pitch_max_nm: float | None = None
    torque_yaw_max_nm: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.thrust_max_n) and self.thrust_max_n > 0):
            raise ValueError(f"thrust_max_n must be > 0, got {self.thrust_max_n}")
        for name in ("torque_roll_pitch_max_nm", "torque_yaw_max_nm"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")


#: SET_ATTITUDE_TARGET type_mask of the rigid-body attitude output: roll and pitch rates ignored.
RIGID_BODY_TYPE_MASK = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                        | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE)  # fmt: skip
#: ... and of the paper model's: a rate setpoint (attitude ignored), flown by the paper inner loop.
PAPER_TYPE_MASK = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE


@dataclass(frozen=True)
class AttitudeSetpoint:
    """SET_ATTITUDE_TARGET fields: q (w, x, y, z) body FRD to NED, rates (rad/s), thrust 0..1.

    ``type_mask`` marks ignored fields (MAVLink's ATTITUDE_TARGET_TYPEMASK bits); an ignored
    rate travels as 0.
    """

    q_wxyz: tuple[float, float, float, float]
    body_rates_frd_rad_s: tuple[float, float, float]
    thrust_norm: float
    type_mask: int = 0


@dataclass(frozen=True)
class ActuatorSetpoint:
    """SET_ACTUATOR_CONTROL_TARGET group 0: normalised roll, pitch, yaw torque and thrust."""

    controls: tuple[float, float, float, float]


def thrust_norm(thrust_n: float, scaling: Scaling) -> float:
    """``u / SIM_THR_MAX`` clipped to [0, 1] (PX4 clips it the same way)."""
    return min(max(thrust_n / scaling.thrust_max_n, 0.0), 1.0)



def command_setpoint(
    command: Command, scaling: Scaling, *, output: SetpointOutput, model: VehicleModel, controller: str = ""
) -> AttitudeSetpoint | ActuatorSetpoint:
    """The setpoint of one mission sample: a controller's command as the message fields that carry it.

    The one encoding of a command: ``offboard.flight`` sends it, ``offboard.replay``'s re-run
    compares it with the log, so both turn the same command into the same fields.

    - ``attitude`` on a rigid body: SET_ATTITUDE_TARGET with the attitude target, the yaw-rate
      feed-forward in the body yaw rate and the roll and pitch rates ignored (PX4's attitude
      controller flies it); on the paper's model (whose plant flies body rates with its paper
      inner loop): the attitude target and the body-rate target, attitude ignored;
    - ``rates``: body rates and thrust, attitude ignored (q carries the asked-for attitude
      ``attitude_ref_euler_rad`` for the log), as PX4 flies it with its rate controller;
    - ``actuator``: SET_ACTUATOR_CONTROL_TARGET group 0, ``torque_nm`` normalised by
      ``SIM_TQ_RP_MAX``/``SIM_TQ_Y_MAX`` and clipped to [-1, 1].

    Thrust is always ``u / SIM_THR_MAX`` clipped to [0, 1].

    Raises
    ------
    ValueError
        An unknown output or model, the actuator output without the torque scaling, or a form
        the controller does not give (``MissingCommand``, naming ``controller``).
    """
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
    if model not in VEHICLE_MODELS:
        raise ValueError(f"model must be one of {VEHICLE_MODELS}, got {model!r}")
    thrust = thrust_norm(command.thrust_n, scaling)
    if output == SetpointOutput.ACTUATOR:
        if scaling.torque_roll_pitch_max_nm is None or scaling.torque_yaw_max_nm is None:
            raise ValueError("the actuator output needs the vehicle's torque scaling (SIM_TQ_RP_MAX, SIM_TQ_Y_MAX)")
        tau = require(command, "torque_nm", controller)
        rp, yw = scaling.torque_roll_pitch_max_nm, scaling.torque_yaw_max_nm
        controls = (tau[0] / rp, tau[1] / rp, tau[2] / yw)
        clipped = tuple(min(max(float(c), -1.0), 1.0) for c in controls)
        return ActuatorSetpoint(controls=(clipped[0], clipped[1], clipped[2], thrust))
    if output == SetpointOutput.ATTITUDE and model == VehicleModel.RIGID_BODY:  # PX4: attitude + yaw-rate feed-forward
        return AttitudeSetpoint(command.attitude_wxyz, (0.0, 0.0, float(command.yaw_rate_ff_rad_s)), thrust, RIGID_BODY_TYPE_MASK)
    rates = require(command, "body_rate_frd_rad_s", controller)
    if output == SetpointOutput.RATES:
        q = quat_from_euler(*command.attitude_ref_euler_rad)
        q_wxyz = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
    else:
        q_wxyz = command.attitude_wxyz
    return AttitudeSetpoint(q_wxyz, rates, thrust, PAPER_TYPE_MASK)


def setpoint_fields(sp: AttitudeSetpoint | ActuatorSetpoint) -> tuple[float, ...]:
    """The numbers a setpoint message carries, in message order (what a re-run compares).

    SET_ATTITUDE_TARGET: q_w, q_x, q_y, q_z, body roll, pitch, yaw rate (rad/s), thrust (0..1);
    SET_ACTUATOR_CONTROL_TARGET group 0: the four controls. The message rounds them to float32.
    """
    if isinstance(sp, ActuatorSetpoint):
        return tuple(sp.controls)
    return (*sp.q_wxyz, *sp.body_rates_frd_rad_s, sp.thrust_norm)


def hold_setpoint(euler_rad: np.ndarray, thrust: float) -> AttitudeSetpoint:
    """A setpoint that asks for the attitude the vehicle has, zero rates and ``thrust`` (0..1).

    Streamed before the mission (thrust 0, disarmed: PX4's proof of offboard life) and while
    the vehicle flies one of its own modes (not flown there; it keeps a lockstep plant going).
    """
    roll, pitch, yaw = (float(v) for v in euler_rad)
    q = quat_from_euler(roll, pitch, yaw)
    return AttitudeSetpoint((float(q[0]), float(q[1]), float(q[2]), float(q[3])), (0.0, 0.0, 0.0), min(max(thrust, 0.0), 1.0))


def set_attitude_target(time_boot_ms: int, sp: AttitudeSetpoint, target_system: int, target_component: int) -> MAVLinkMessage:
    """SET_ATTITUDE_TARGET with ``sp.type_mask`` (ignored fields travel as they are, PX4 skips them)."""
    return mavlink.MAVLink_set_attitude_target_message(
        time_boot_ms & 0xFFFFFFFF, target_system, target_component, sp.type_mask,
        list(sp.q_wxyz), sp.body_rates_frd_rad_s[0], sp.body_rates_frd_rad_s[1], sp.body_rates_frd_rad_s[2],
        sp.thrust_norm,
    )  # fmt: skip


def set_actuator_control_target(time_boot_ms: int, sp: ActuatorSetpoint, target_system: int, target_component: int) -> MAVLinkMessage:
    """SET_ACTUATOR_CONTROL_TARGET, group 0, time_usec = time_boot_ms * 1000 (the lockstep echo)."""
    controls = list(sp.controls) + [0.0] * 4
    return mavlink.MAVLink_set_actuator_control_target_message(time_boot_ms * 1000, 0, target_system, target_component, controls)


# --- commands and other outgoing messages ---------------------------------------------------------


def heartbeat() -> MAVLinkMessage:
    """The offboard process's own HEARTBEAT: an onboard controller, no autopilot."""
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
    )


def command_long(target_system: int, target_component: int, command: int, params: tuple[float, ...], confirmation: int = 0) -> MAVLinkMessage:
    """COMMAND_LONG; unused parameters are 0 (seven parameters in all)."""
    p = list(params) + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(target_system, target_component, command, confirmation, *p[:7])


def set_mode_offboard_params() -> tuple[int, tuple[float, ...]]:
    """MAV_CMD_DO_SET_MODE with PX4's custom main mode OFFBOARD (6)."""
    return mavlink.MAV_CMD_DO_SET_MODE, (float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(PX4_MAIN_MODE_OFFBOARD), 0.0)


def arm_params(arm: bool) -> tuple[int, tuple[float, ...]]:
    """MAV_CMD_COMPONENT_ARM_DISARM (param1 1 arm, 0 disarm; checks not forced)."""
    return mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if arm else 0.0, 0.0)


def land_params() -> tuple[int, tuple[float, ...]]:
    """MAV_CMD_NAV_LAND at the current position (PX4: NaN latitude/longitude/yaw = here)."""
    nan = math.nan
    return mavlink.MAV_CMD_NAV_LAND, (0.0, 0.0, 0.0, nan, nan, nan, nan)


#: The streams ``offboard fly`` samples: asked for at its telemetry rate (a multiple of 1/To).
SAMPLED_STREAMS = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
#: Streams it reads and leaves at the vehicle's rate: HEARTBEAT (mode, armed), EXTENDED_SYS_STATE
#: (the landed state that ends the landing), HOME_POSITION (mission alignment, replay),
#: SYS_STATUS (sensor health, reported); and ESTIMATOR_STATUS (what the estimate is good for:
#: ``offboard.flight.guards``), asked for at ``ESTIMATOR_STATUS_RATE_HZ`` with the sampled ones.
KEPT_STREAMS = (mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                mavlink.MAVLINK_MSG_ID_HOME_POSITION, mavlink.MAVLINK_MSG_ID_SYS_STATUS,
                mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS)  # fmt: skip
#: ESTIMATOR_STATUS's rate (Hz): PX4 v1.16 sends it at 1 Hz on an onboard link, which left up to a
#: second between EKF2 giving up on the position and the flight knowing it (measured: 0.9 s).
ESTIMATOR_STATUS_RATE_HZ = 5.0
#: PX4 v1.16's default streams on an onboard link (``configure_streams_to_default``,
#: MAVLINK_MODE_ONBOARD, as measured on its SITL: docs/parity/wire.md) that ``offboard fly`` never
#: reads: switched off with MAV_CMD_SET_MESSAGE_INTERVAL -1, as PX4's clients do. TIMESYNC is
#: PX4's own requests (tc1 = 0); the answers to ours come from its receiver, not this stream.
UNREAD_STREAMS = (
    8,  # LINK_NODE_STATUS (PX4's development dialect)
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
    mavlink.MAVLINK_MSG_ID_PING,
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT,
    mavlink.MAVLINK_MSG_ID_VFR_HUD,
    mavlink.MAVLINK_MSG_ID_TIMESYNC,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU,
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR,
    mavlink.MAVLINK_MSG_ID_ALTITUDE,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
    mavlink.MAVLINK_MSG_ID_VIBRATION,
    mavlink.MAVLINK_MSG_ID_ODOMETRY,
    380,  # TIME_ESTIMATE_TO_TARGET (PX4's development dialect)
    436,  # CURRENT_MODE (development.xml)
    mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_LOCATION,
    mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_SYSTEM,
)
#: MAV_CMD_SET_MESSAGE_INTERVAL's interval that switches a stream off.
INTERVAL_OFF_US = -1


def message_interval_params(message_id: int, rate_hz: float | None) -> tuple[int, tuple[float, ...]]:
    """MAV_CMD_SET_MESSAGE_INTERVAL for one stream: at ``rate_hz``, or off (interval -1) for None."""
    interval_us = INTERVAL_OFF_US if rate_hz is None else round(1e6 / rate_hz)
    return mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(message_id), float(interval_us))


def param_request_read(target_system: int, target_component: int, name: str) -> MAVLinkMessage:
    """PARAM_REQUEST_READ by name (index -1)."""
    return mavlink.MAVLink_param_request_read_message(target_system, target_component, name.encode("ascii"), -1)


def timesync_request(ts1_ns: int) -> MAVLinkMessage:
    """TIMESYNC request: tc1 = 0, ts1 = our time in nanoseconds."""
    return mavlink.MAVLink_timesync_message(0, ts1_ns)


# --- incoming: status, acks, parameters ----------------------------------------------------------


@dataclass(frozen=True)
class VehicleStatus:
    """What a vehicle's HEARTBEAT says."""

    armed: bool
    main_mode: int
    sub_mode: int
    system_status: int
    custom_mode_enabled: bool

    @property
    def offboard(self) -> bool:
        """Whether the vehicle is in PX4's Offboard mode."""
        return self.custom_mode_enabled and self.main_mode == PX4_MAIN_MODE_OFFBOARD

    @property
    def landing(self) -> bool:
        """Whether the vehicle is in PX4's Land mode (AUTO.LAND)."""
        return self.custom_mode_enabled and self.main_mode == PX4_MAIN_MODE_AUTO and self.sub_mode == PX4_SUB_MODE_AUTO_LAND

    @property
    def critical(self) -> bool:
        """System status CRITICAL or EMERGENCY: PX4 reports a failsafe this way."""
        return self.system_status in (mavlink.MAV_STATE_CRITICAL, mavlink.MAV_STATE_EMERGENCY)

    @property
    def mode_name(self) -> str:
        """PX4's name of the mode, for messages ("non-PX4 mode" without PX4's custom mode)."""
        return px4_mode_name(self.main_mode, self.sub_mode) if self.custom_mode_enabled else "non-PX4 mode"


#: PX4's name of a (main, sub) mode, for messages.
px4_mode_name = px4_modes.mode_name


def is_autopilot_heartbeat(msg: MAVLinkMessage) -> bool:
    """A heartbeat from a flight controller (not a ground station, camera or companion)."""
    return msg.get_type() == "HEARTBEAT" and int(msg.autopilot) != mavlink.MAV_AUTOPILOT_INVALID and int(msg.type) not in (
        mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
    )  # fmt: skip


def vehicle_status(msg: MAVLinkMessage) -> VehicleStatus:
    """Decode PX4's HEARTBEAT: custom_mode = main << 16 | sub << 24."""
    main_mode, sub_mode = px4_modes.main_sub(int(msg.custom_mode))
    base = int(msg.base_mode)
    return VehicleStatus(
        armed=bool(base & mavlink.MAV_MODE_FLAG_SAFETY_ARMED),
        main_mode=main_mode,
        sub_mode=sub_mode,
        system_status=int(msg.system_status),
        custom_mode_enabled=bool(base & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
    )


def mav_result_name(result: int) -> str:
    """``MAV_RESULT_TEMPORARILY_REJECTED`` -> ``TEMPORARILY_REJECTED``."""
    entry = mavlink.enums["MAV_RESULT"].get(int(result))
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"MAV_RESULT {result}"


def mav_cmd_name(command: int) -> str:
    """``MAV_CMD_COMPONENT_ARM_DISARM`` (the full enum name, as users search for it)."""
    entry = mavlink.enums["MAV_CMD"].get(int(command))
    return entry.name if entry is not None else f"MAV_CMD {command}"


def param_value(msg: MAVLinkMessage) -> tuple[str, float]:
    """(name, value) of a PARAM_VALUE; integer types travel as their bytes in the float (PX4)."""
    raw = msg.param_id
    name = (raw.split(b"\x00", 1)[0].decode("ascii", "replace") if isinstance(raw, bytes) else raw.split("\x00", 1)[0])[:16]
    if int(msg.param_type) in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                               mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):  # fmt: skip
        return name, float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return name, float(msg.param_value)


def timesync_offset_ns(ts1_ns: int, tc1_ns: int, now_ns: int) -> tuple[int, int]:
    """(offset, round trip) of a TIMESYNC reply, ns: remote time = our time + offset.

    The remote stamped ``tc1`` half a round trip after we stamped ``ts1`` (PX4's estimate).
    """
    rtt = now_ns - ts1_ns
    return tc1_ns - (ts1_ns + now_ns) // 2, rtt


def frame_header(msg: mavlink.MAVLink_message) -> tuple[int, int, int]:
    """(sequence, system id, component id) read from a message's own frame bytes (MAVLink 1 or
    2); pymavlink leaves them 0 in a ``MAVLink_unknown``. (0, 0, 0) for a frame too short."""
    buf = msg.get_msgbuf()
    if len(buf) >= 7 and buf[0] == mavlink.PROTOCOL_MARKER_V2:
        return buf[4], buf[5], buf[6]
    if len(buf) >= 5 and buf[0] == mavlink.PROTOCOL_MARKER_V1:
        return buf[2], buf[3], buf[4]
    return 0, 0, 0
