"""MAVLink encoding and decoding for the plant: pure functions, no sockets.

Outgoing: ``VehicleState`` and the autopilot's ``Status`` become pymavlink message objects
(``heartbeat``, ``attitude``, ``local_position_ned`` ...), to be packed by the link.
Incoming: pymavlink messages become validated ``AttitudeSetpoint``, ``ActuatorSetpoint`` and
``Command`` objects; a field the plant cannot use raises ``Refused`` (counted by the caller, never
flown). Everything is testable with pymavlink's ``pack()`` and ``parse_buffer()``.

Frames and units follow MAVLink: positions NED in metres, attitude as ZYX Euler angles and the
quaternion (w, x, y, z) of body FRD to NED, body rates FRD in rad/s, ``time_boot_ms`` = simulation
time. Latitude/longitude come from the local NED position by PX4's azimuthal equidistant
projection about ``Home``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from offboard.model.messages import MAVLinkMessage
from offboard.model.rotations import rotation_matrix
from offboard.model.state import VehicleState
from sitl_plant.autopilot import (
    DEAD_RECKONING_S,
    GPS_DROPPED_S,
    ActuatorSetpoint,
    AttitudeSetpoint,
    Command,
    Mode,
    PositionSetpoint,
    Status,
)
from sitl_plant.mission import Out
from sitl_plant.navigator import Frame

MAVLink: TypeAlias = mavlink.MAVLink

EARTH_RADIUS_M = 6371000.0  # PX4 CONSTANTS_RADIUS_OF_EARTH
# Earth's magnetic field near PX4 SITL's default home (Zurich), gauss, NED
MAG_FIELD_NED_GAUSS = (0.21, 0.0, 0.43)

#: AUTOPILOT_VERSION as PX4 v1.16.0 SITL answers it (measured, tests/e2e/test_px4_parity_wire.py):
#: version words major << 24 | minor << 16 | patch << 8 | FIRMWARE_VERSION_TYPE_OFFICIAL (255),
#: the same word for the middleware, board_version 1, the first bytes of the release's git hash
#: (6ea3539157...) in flight/middleware_custom_version, last byte first (PX4's version.c).
PX4_FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255  # "v1.16.0", official release
PX4_GIT_HASH_BYTES = (0, 0, 0, 0x57, 0x91, 0x53, 0xA3, 0x6E)
PX4_BOARD_VERSION = 1
#: PX4's capabilities (mavlink_main.cpp, get_capabilities; measured 0xE8FF).
PX4_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_FTP
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)

#: Sensors the plant reports in SYS_STATUS, and the failure unit that makes each unhealthy.
SENSOR_BITS = {
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO: "gyro",
    mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL: "accel",
    mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG: "mag",
    mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE: "baro",
    mavlink.MAV_SYS_STATUS_SENSOR_GPS: "gps",
    mavlink.MAV_SYS_STATUS_SENSOR_BATTERY: "battery",
    mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS: "motor",
    mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL: None,
    mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION: None,
    mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION: None,
    mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL: None,
    mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL: None,
    mavlink.MAV_SYS_STATUS_AHRS: None,
    mavlink.MAV_SYS_STATUS_PREARM_CHECK: None,
}

ATTITUDE_IGNORE = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE  # 128
THROTTLE_IGNORE = mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE  # 64
THRUST_BODY_SET = 32  # ATTITUDE_TARGET_TYPEMASK_THRUST_BODY_SET (newer common.xml than pymavlink's)
RATE_IGNORE = (
    mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
    mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
    mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
)
_SET_ATTITUDE_TARGET_BASE_LEN = 39  # payload bytes before the thrust_body extension
MAX_BODY_RATE_RAD_S = 100.0  # beyond this a rate setpoint is refused as nonsense (PX4 limits far lower)
QUAT_NORM_TOLERANCE = 0.1


class Refused(ValueError):
    """An incoming message the plant refuses (NaN, out of range, wrong group): not flown."""


# --- where the vehicle is --------------------------------------------------------------------


@dataclass(frozen=True)
class Home:
    """The origin of the local NED frame: latitude, longitude (deg WGS84), altitude AMSL (m)."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg <= 90.0 or not -180.0 <= self.lon_deg <= 180.0 or not math.isfinite(self.alt_m):
            raise ValueError(f"home must be LAT,LON,ALT with |lat| <= 90, |lon| <= 180, got {self}")

    @classmethod
    def parse(cls, text: str) -> Home:
        """``"LAT,LON,ALT"`` (degrees, degrees, metres AMSL)."""
        parts = text.split(",")
        if len(parts) != 3:
            raise ValueError(f"expected LAT,LON,ALT, got {text!r}")
        try:
            lat, lon, alt = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"expected three numbers LAT,LON,ALT, got {text!r}") from None
        return cls(lat, lon, alt)


def ned_to_geodetic(pos_ned_m: np.ndarray, home: Home) -> tuple[float, float, float]:
    """(lat deg, lon deg, alt m AMSL) of a local NED point (PX4's azimuthal equidistant map)."""
    lat0, lon0 = math.radians(home.lat_deg), math.radians(home.lon_deg)
    x_rad = float(pos_ned_m[0]) / EARTH_RADIUS_M
    y_rad = float(pos_ned_m[1]) / EARTH_RADIUS_M
    c = math.hypot(x_rad, y_rad)
    if c > 0.0:
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(cos_c * math.sin(lat0) + x_rad * sin_c * math.cos(lat0) / c)
        lon = lon0 + math.atan2(y_rad * sin_c, c * math.cos(lat0) * cos_c - x_rad * math.sin(lat0) * sin_c)
    else:
        lat, lon = lat0, lon0
    return math.degrees(lat), math.degrees(lon), home.alt_m - float(pos_ned_m[2])


def pressure_hpa(alt_amsl_m: float) -> float:
    """ISA static pressure at an altitude (troposphere)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


# --- outgoing ---------------------------------------------------------------------------------


def heartbeat(status: Status) -> MAVLinkMessage:
    """HEARTBEAT of a PX4 quadrotor: the autopilot's base mode flags (or ones built from the mode and
    arming), PX4's custom mode, the system status.
    """
    base = status.base_mode  # the autopilot's, as PX4 sends it (autopilot.base_mode_flags)
    if base is None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if status.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if status.mode in (Mode.OFFBOARD,) or status.mode.value[0] == 4:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, status.mode.custom_mode, status.system_status, 3
    )


def attitude(t_ms: int, st: VehicleState) -> MAVLinkMessage:
    """ATTITUDE: ZYX roll, pitch, yaw (rad) and body rates (FRD, rad/s) of ``st``, stamped ``t_ms``."""
    e, w = st.euler_rad, st.body_rate_frd_rad_s
    return mavlink.MAVLink_attitude_message(t_ms, e[0], e[1], e[2], w[0], w[1], w[2])


def attitude_quaternion(t_ms: int, st: VehicleState) -> MAVLinkMessage:
    """ATTITUDE_QUATERNION: q (w, x, y, z) body FRD to NED and body rates of ``st``; no repr_offset_q."""
    q, w = st.quat_wxyz, st.body_rate_frd_rad_s
    return mavlink.MAVLink_attitude_quaternion_message(t_ms, q[0], q[1], q[2], q[3], w[0], w[1], w[2], (0.0, 0.0, 0.0, 0.0))


def local_position_ned(t_ms: int, st: VehicleState) -> MAVLinkMessage:
    """LOCAL_POSITION_NED: position (m) and velocity (m/s) of ``st``, NED from home."""
    p, v = st.pos_ned_m, st.vel_ned_m_s
    return mavlink.MAVLink_local_position_ned_message(t_ms, p[0], p[1], p[2], v[0], v[1], v[2])


def global_position_int(t_ms: int, st: VehicleState, home: Home) -> MAVLinkMessage:
    """GLOBAL_POSITION_INT: ``st``'s position about ``home`` (degE7, alt AMSL and relative in mm), its
    velocity (cm/s) and heading (cdeg).
    """
    lat, lon, alt = ned_to_geodetic(st.pos_ned_m, home)
    v = st.vel_ned_m_s
    hdg = _clip32(math.degrees(st.euler_rad[2]) * 100.0) % 36000
    return mavlink.MAVLink_global_position_int_message(
        t_ms,
        _clip32(lat * 1e7),
        _clip32(lon * 1e7),
        _clip32(alt * 1000.0),
        _clip32(-float(st.pos_ned_m[2]) * 1000.0),
        _clip16(v[0] * 100.0),
        _clip16(v[1] * 100.0),
        _clip16(v[2] * 100.0),
        hdg,
    )


def hil_state_quaternion(truth: VehicleState, home: Home) -> MAVLinkMessage:
    """The simulator's ground truth, as PX4 SITL sends it on request (its
    ``vehicle_*_groundtruth`` topics, HIL_STATE_QUATERNION.hpp): time_usec 0, airspeeds 0, and the
    acceleration in whole m/s^2 where MAVLink says mG (PX4 copies the float into the int16)."""
    lat, lon, alt = ned_to_geodetic(truth.pos_ned_m, home)
    q, w, v, a = truth.quat_wxyz, truth.body_rate_frd_rad_s, truth.vel_ned_m_s, truth.acc_ned_m_s2
    return mavlink.MAVLink_hil_state_quaternion_message(
        0,
        [float(q[0]), float(q[1]), float(q[2]), float(q[3])],
        float(w[0]),
        float(w[1]),
        float(w[2]),
        _clip32(lat * 1e7),
        _clip32(lon * 1e7),
        _clip32(alt * 1000.0),
        _clip16(v[0] * 100.0),
        _clip16(v[1] * 100.0),
        _clip16(v[2] * 100.0),
        0,
        0,
        _clip16(math.trunc(float(a[0]))),
        _clip16(math.trunc(float(a[1]))),
        _clip16(math.trunc(float(a[2]))),
    )


def ground_course(st: VehicleState, *, unknown_cdeg: int) -> tuple[float, int]:
    """(ground speed m/s, course over ground in cdeg 0..35999); ``unknown_cdeg`` below 0.1 m/s."""
    v = st.vel_ned_m_s
    ground = math.hypot(float(v[0]), float(v[1]))
    if ground <= 0.1:
        return ground, unknown_cdeg
    return ground, _clip32(math.degrees(math.atan2(float(v[1]), float(v[0]))) * 100.0) % 36000


def gps_raw_int(t_us: int, st: VehicleState, home: Home, healthy: bool = True) -> MAVLinkMessage:
    """A 3D fix with 10 satellites (no fix when the GPS failure is injected)."""
    lat, lon, alt = ned_to_geodetic(st.pos_ned_m, home)
    ground, cog = ground_course(st, unknown_cdeg=65535)
    fix = mavlink.GPS_FIX_TYPE_3D_FIX if healthy else mavlink.GPS_FIX_TYPE_NO_FIX
    return mavlink.MAVLink_gps_raw_int_message(
        t_us, fix, _clip32(lat * 1e7), _clip32(lon * 1e7), _clip32(alt * 1000.0), 70, 100,
        min(_clip32(ground * 100.0), 65534), cog, 10 if healthy else 0,
    )  # fmt: skip


def vfr_hud(st: VehicleState, home: Home, throttle_norm: float) -> MAVLinkMessage:
    """Speeds (m/s; airspeed = ground speed, the plant has no airspeed sensor), heading, throttle %."""
    v = st.vel_ned_m_s
    ground = math.hypot(float(v[0]), float(v[1]))
    heading = _clip32(math.degrees(float(st.euler_rad[2]))) % 360
    throttle = int(round(min(max(throttle_norm, 0.0), 1.0) * 100.0)) if math.isfinite(throttle_norm) else 0
    return mavlink.MAVLink_vfr_hud_message(ground, ground, heading, throttle, home.alt_m - float(st.pos_ned_m[2]), -float(v[2]))


def highres_imu(t_us: int, st: VehicleState, home: Home, gravity_m_s2: float = 9.81) -> MAVLinkMessage:
    """Body FRD specific force (accelerometer), rates (gyro), magnetic field, pressure."""
    r_t = rotation_matrix(st.quat_wxyz).T
    acc = r_t @ (np.asarray(st.acc_ned_m_s2) - np.array([0.0, 0.0, gravity_m_s2]))
    mag = r_t @ np.array(MAG_FIELD_NED_GAUSS)
    w = st.body_rate_frd_rad_s
    alt = home.alt_m - float(st.pos_ned_m[2])
    return mavlink.MAVLink_highres_imu_message(
        t_us, acc[0], acc[1], acc[2], w[0], w[1], w[2], mag[0], mag[1], mag[2], pressure_hpa(alt), 0.0, alt, 25.0, 0x1FFF
    )


def sys_status(status: Status, *, bad_packets: int = 0) -> MAVLinkMessage:
    """SYS_STATUS: a failed unit's health bit cleared; a lost GPS also dropped from the present
    bits ``GPS_DROPPED_S`` after it failed, and the horizontal position control unhealthy once the
    estimate is gone, as PX4 v1.16 (which leaves the GPS's health bit set: docs/plant.md)."""
    present = 0
    health = 0
    for bit, unit in SENSOR_BITS.items():
        present |= bit
        if unit is None or unit not in status.failures:
            health |= bit
    lost = status.gps_lost_s
    if lost is not None and lost >= DEAD_RECKONING_S:
        health &= ~mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    if lost is not None and lost >= GPS_DROPPED_S:
        present &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
    if not status.prearm_ok:
        health &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
    battery_ok = "battery" not in status.failures
    return mavlink.MAVLink_sys_status_message(
        present, present, health, 0, 16200 if battery_ok else 13200, -1, 100 if battery_ok else 5, 0, min(bad_packets, 65535), 0, 0, 0, 0
    )


def extended_sys_state(status: Status) -> MAVLinkMessage:
    """EXTENDED_SYS_STATE: the landed state (no VTOL state)."""
    return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, status.landed_state)


def home_position(t_us: int, home: Home, home_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> MAVLinkMessage:
    """HOME_POSITION: home at ``home_ned_m`` from the local origin ``home``, geodetic and local."""
    lat, lon, alt = ned_to_geodetic(np.asarray(home_ned_m), home)
    return mavlink.MAVLink_home_position_message(
        _clip32(lat * 1e7), _clip32(lon * 1e7), _clip32(alt * 1000.0),
        home_ned_m[0], home_ned_m[1], home_ned_m[2], (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, t_us,
    )  # fmt: skip


def battery_status(status: Status) -> MAVLinkMessage:
    """BATTERY_STATUS of a 4S pack: 4.05 V a cell and 100 %, or flat with the ``battery`` failure."""
    ok = "battery" not in status.failures
    cell_mv = 4050 if ok else 3300
    voltages = [cell_mv] * 4 + [65535] * 6
    return mavlink.MAVLink_battery_status_message(
        0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, voltages, -1, -1, -1, 100 if ok else 5
    )


def attitude_target(t_ms: int, q_wxyz: tuple[float, float, float, float], rates: tuple[float, float, float], thrust_norm: float) -> MAVLinkMessage:
    """ATTITUDE_TARGET: the attitude, body rates and normalised thrust being flown."""
    return mavlink.MAVLink_attitude_target_message(t_ms, 0, q_wxyz, rates[0], rates[1], rates[2], thrust_norm)


def servo_output_raw(t_us: int, motor_speeds_rad_s: np.ndarray, max_speed_rad_s: float, armed: bool) -> MAVLinkMessage:
    """Motor outputs as PWM: 1000 us (stopped) to 2000 us (top speed), 900 us disarmed."""
    if armed:
        pwm = [int(round(1000.0 + 1000.0 * min(max(float(w) / max_speed_rad_s, 0.0), 1.0))) if math.isfinite(w) else 1000
               for w in motor_speeds_rad_s[:4]]
    else:
        pwm = [900] * 4
    return mavlink.MAVLink_servo_output_raw_message(t_us & 0xFFFFFFFF, 0, *pwm, 0, 0, 0, 0)


# --- the streams PX4 v1.16 adds on its links (mavlink_main.cpp, configure_streams_to_default) ---

_NAN = float("nan")
_UNKNOWN_COVARIANCE = [_NAN] * 21  # MAVLink: NaN in the first element = unknown


def odometry(t_us: int, st: VehicleState) -> MAVLinkMessage:
    """ODOMETRY as PX4's ODOMETRY.hpp sends its estimate: MAV_FRAME_LOCAL_NED pose, body-FRD
    velocity frame id MAV_FRAME_BODY_FRD... PX4 sends child_frame_id LOCAL_NED (1) with the
    velocity in NED; the plant does the same (measured: frame_id 1, child_frame_id 1)."""
    p, v, q, w = st.pos_ned_m, st.vel_ned_m_s, st.quat_wxyz, st.body_rate_frd_rad_s
    return mavlink.MAVLink_odometry_message(
        t_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, p[0], p[1], p[2], [float(c) for c in q],
        v[0], v[1], v[2], w[0], w[1], w[2], _UNKNOWN_COVARIANCE, _UNKNOWN_COVARIANCE, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
    )  # fmt: skip


def altitude(t_us: int, st: VehicleState, home: Home, home_alt_m: float) -> MAVLinkMessage:
    """ALTITUDE (m): AMSL as monotonic and AMSL, local = -down, relative to home, terrain and
    bottom clearance from the flat ground at the home's altitude."""
    amsl = home.alt_m - float(st.pos_ned_m[2])
    height = -float(st.pos_ned_m[2])
    return mavlink.MAVLink_altitude_message(t_us, amsl, amsl, height, amsl - home_alt_m, home.alt_m, height)


def distance_sensor(t_ms: int) -> MAVLinkMessage:
    """DISTANCE_SENSOR as PX4 SIH sends it without a range finder (measured): 0 .. 10000 cm,
    current 0, MAV_DISTANCE_SENSOR_LASER, facing down (MAV_SENSOR_ROTATION_PITCH_270)."""
    return mavlink.MAVLink_distance_sensor_message(t_ms, 0, 10000, 0, mavlink.MAV_DISTANCE_SENSOR_LASER, 0,
                                                   mavlink.MAV_SENSOR_ROTATION_PITCH_270, 0)  # fmt: skip


def position_target_local_ned(t_ms: int, pos_ned_m: tuple, vel_ned_m_s: tuple, acc_ned_m_s2: tuple, yaw_rad: float) -> MAVLinkMessage:
    """POSITION_TARGET_LOCAL_NED: what the position controller flies; None entries are NaN
    (PX4 sends NaN position/velocity and type_mask 63 when only thrust/attitude is set)."""
    vals = [_NAN if v is None else float(v) for v in (*pos_ned_m, *vel_ned_m_s)]
    mask = 0
    for i, v in enumerate(vals):
        if math.isnan(v):
            mask |= 1 << i
    acc = [0.0 if a is None else float(a) for a in acc_ned_m_s2]
    return mavlink.MAVLink_position_target_local_ned_message(t_ms, mavlink.MAV_FRAME_LOCAL_NED, mask, *vals, *acc, yaw_rad, 0.0)


def timesync_request(now_ns: int) -> MAVLinkMessage:
    """PX4's own TIMESYNC request (10 Hz on the API link): tc1 = 0, ts1 = its time in ns."""
    return mavlink.MAVLink_timesync_message(0, now_ns)


def ping_request(t_us: int, seq: int) -> MAVLinkMessage:
    """PX4's PING request to everyone (target 0/0): time and a counter."""
    return mavlink.MAVLink_ping_message(t_us, seq & 0xFFFFFFFF, 0, 0)


#: ESTIMATOR_STATUS flags PX4 v1.16's EKF2 sends on its SITL, converged on GPS (measured): on the
#: ground 0x3ff, in the air 0x37f (no constant-position mode).
ESTIMATOR_FLAGS_GROUND = 0x3FF
ESTIMATOR_FLAGS_AIR = 0x37F
#: What EKF2 stops vouching for ``DEAD_RECKONING_S`` after its GPS stopped, and ``GPS_DROPPED_S``
#: after (in the air: 0x365, then 0x025; on the ground then 0x0e5).
_DEAD_RECKONING_LOST = mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_HORIZ_ABS
_GPS_DROPPED_LOST = mavlink.ESTIMATOR_PRED_POS_HORIZ_REL | mavlink.ESTIMATOR_PRED_POS_HORIZ_ABS


def estimator_flags(on_ground: bool, gps_lost_s: float | None) -> int:
    """PX4's EKF2 flags (``ESTIMATOR_FLAGS_*``), with what a GPS lost ``gps_lost_s`` ago costs."""
    flags = ESTIMATOR_FLAGS_GROUND if on_ground else ESTIMATOR_FLAGS_AIR
    if gps_lost_s is not None and gps_lost_s >= DEAD_RECKONING_S:
        flags &= ~_DEAD_RECKONING_LOST
    if gps_lost_s is not None and gps_lost_s >= GPS_DROPPED_S:
        flags &= ~(_GPS_DROPPED_LOST | (0 if on_ground else mavlink.ESTIMATOR_POS_VERT_AGL))
    return flags


def estimator_status(t_us: int, status: Status) -> MAVLinkMessage:
    """ESTIMATOR_STATUS as PX4's EKF2 sends it (``estimator_flags``; the plant has no estimator:
    the test ratios are 0, accuracies those of its noise-free GPS)."""
    flags = estimator_flags(status.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND, status.gps_lost_s)
    return mavlink.MAVLink_estimator_status_message(t_us, flags, 0.0, 0.0, 0.0, 0.0, 0.0, _NAN, 0.3, 0.3)


def scaled_pressure(t_ms: int, st: VehicleState, home: Home) -> MAVLinkMessage:
    """SCALED_PRESSURE: ISA static pressure (hPa) at the altitude, 25 C."""
    return mavlink.MAVLink_scaled_pressure_message(t_ms, pressure_hpa(home.alt_m - float(st.pos_ned_m[2])), 0.0, 2500, 0)


def vibration(t_us: int) -> MAVLinkMessage:
    """VIBRATION of a simulation: no vibration, no clipping."""
    return mavlink.MAVLink_vibration_message(t_us, 0.0, 0.0, 0.0, 0, 0, 0)


def open_drone_id_location(st: VehicleState, home: Home, airborne: bool) -> MAVLinkMessage:
    """OPEN_DRONE_ID_LOCATION as PX4 sends it (its open_drone_id streams, common.xml): position,
    heading (cdeg), speeds (cm/s), heights; unknown timestamp 0xFFFF, no id_or_mac."""
    lat, lon, alt = ned_to_geodetic(st.pos_ned_m, home)
    v = st.vel_ned_m_s
    ground, direction = ground_course(st, unknown_cdeg=36100)
    status = mavlink.MAV_ODID_STATUS_AIRBORNE if airborne else mavlink.MAV_ODID_STATUS_GROUND
    return mavlink.MAVLink_open_drone_id_location_message(
        0, 0, [0] * 20, status, direction, min(_clip32(ground * 100.0), 25425), _clip16(-float(v[2]) * 100.0),
        _clip32(lat * 1e7), _clip32(lon * 1e7), alt, alt, mavlink.MAV_ODID_HEIGHT_REF_OVER_TAKEOFF, -float(st.pos_ned_m[2]),
        mavlink.MAV_ODID_HOR_ACC_1_METER, mavlink.MAV_ODID_VER_ACC_1_METER, 0, mavlink.MAV_ODID_SPEED_ACC_0_3_METERS_PER_SECOND,
        65535.0, 0,
    )  # fmt: skip


def open_drone_id_system(home: Home, unix_s: float) -> MAVLinkMessage:
    """OPEN_DRONE_ID_SYSTEM: the operator at home (take-off location), one area, EU class unknown."""
    odid_epoch = 1_546_300_800  # 2019-01-01T00:00:00Z, Open Drone ID's time origin
    stamp = int(max(unix_s - odid_epoch, 0)) & 0xFFFFFFFF
    return mavlink.MAVLink_open_drone_id_system_message(
        0, 0, [0] * 20, mavlink.MAV_ODID_OPERATOR_LOCATION_TYPE_TAKEOFF, mavlink.MAV_ODID_CLASSIFICATION_TYPE_UNDECLARED,
        _clip32(home.lat_deg * 1e7), _clip32(home.lon_deg * 1e7), 1, 0, -1000.0, -1000.0, 0, 0, home.alt_m, stamp,
    )  # fmt: skip


class DialectMessage(MAVLinkMessage):
    """A message of PX4's dialect that pymavlink's common.xml (and development.xml) lack: its id,
    CRC extra and little-endian payload layout (fields in wire order), packed like pymavlink's.

    The CRC extras were checked against PX4 v1.16's own frames."""

    def __init__(self, msg_id: int, name: str, crc_extra: int, layout: str, fields: tuple[str, ...], values: tuple) -> None:
        super().__init__(msg_id, name)
        self.id, self.msgname, self.crc_extra = msg_id, name, crc_extra
        self._layout = struct.Struct("<" + layout)
        self._fieldnames = list(fields)
        for name_, value in zip(fields, values):
            setattr(self, name_, value)

    def pack(self, mav: MAVLink, force_mavlink1: bool = False) -> bytes:
        """The frame, as pymavlink packs its own messages (sequence, ids and signing from ``mav``)."""
        payload = self._layout.pack(*(getattr(self, f) for f in self._fieldnames))
        return self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1)


def link_node_status(t_ms: int, sent: int, received: int) -> MAVLinkMessage:
    """LINK_NODE_STATUS (id 8, PX4's development dialect): the link's own counters."""
    fields = ("timestamp", "tx_rate", "rx_rate", "messages_sent", "messages_received", "messages_lost",
              "rx_parse_err", "tx_overflows", "rx_overflows", "tx_buf", "rx_buf")  # fmt: skip
    values = (t_ms, 0, 0, sent & 0xFFFFFFFF, received & 0xFFFFFFFF, 0, 0, 0, 0, 0, 0)
    return DialectMessage(8, "LINK_NODE_STATUS", 117, "QIIIIIHHHBB", fields, values)


def time_estimate_to_target(seconds: tuple[int, int, int, int, int] = (-1, -1, -1, -1, -1)) -> MAVLinkMessage:
    """TIME_ESTIMATE_TO_TARGET (id 380, development dialect): safe return, land, next item,
    mission end, commanded action, in s; -1 = unknown. PX4 SIH on the ground sends 0 for safe
    return and -1 for the rest (measured)."""
    fields = ("safe_return", "land", "mission_next_item", "mission_end", "commanded_action")
    return DialectMessage(380, "TIME_ESTIMATE_TO_TARGET", 232, "iiiii", fields, seconds)


def current_mode(custom_mode: int, intended_custom_mode: int) -> MAVLinkMessage:
    """CURRENT_MODE (id 436, development dialect; pymavlink's development.py has it)."""
    from pymavlink.dialects.v20 import development

    return development.MAVLink_current_mode_message(0, custom_mode, intended_custom_mode)


def system_time(unix_us: int, t_ms: int) -> MAVLinkMessage:
    """SYSTEM_TIME: Unix time (us) and time since boot (ms, wrapped to 32 bits)."""
    return mavlink.MAVLink_system_time_message(unix_us, t_ms & 0xFFFFFFFF)


def statustext(severity: int, text: str, chunk_id: int = 0) -> list[MAVLinkMessage]:
    """STATUSTEXT, split into 50-byte chunks sharing ``chunk_id`` when longer (MAVLink 2). A
    chunk shorter than 50 bytes (its text NUL-terminated) is the last, as the spec says; a text
    of a whole number of chunks ends with an empty one, so a reader knows it is complete."""
    data = text.encode("utf-8", "replace")
    if len(data) <= 50:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    chunks = [data[i : i + 50] for i in range(0, len(data), 50)]
    if len(data) % 50 == 0:
        chunks.append(b"")
    return [mavlink.MAVLink_statustext_message(severity, c, chunk_id, n) for n, c in enumerate(chunks)]


def command_ack(command: int, result: int, target_system: int, target_component: int) -> MAVLinkMessage:
    """COMMAND_ACK of ``command`` with ``result`` (a MAV_RESULT), to the sender."""
    return mavlink.MAVLink_command_ack_message(command, result, 0, 0, target_system, target_component)


def param_value(name: str, value: float, is_int: bool, count: int, index: int) -> MAVLinkMessage:
    """PARAM_VALUE; an INT32 parameter travels as its bytes in the float field (PX4's encoding)."""
    if is_int:
        wire = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        kind = mavlink.MAV_PARAM_TYPE_INT32
    else:
        wire = value
        kind = mavlink.MAV_PARAM_TYPE_REAL32
    return mavlink.MAVLink_param_value_message(name.encode("ascii"), wire, kind, count, index)


def param_set_value(msg: MAVLinkMessage) -> float:
    """The value a PARAM_SET carries, decoding INT32 from the float's bytes (PX4's encoding)."""
    if msg.param_type in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                          mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):  # fmt: skip
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return float(msg.param_value)


def param_name(raw: bytes | str) -> str:
    """A param_id field as text (NUL-terminated, at most 16 characters)."""
    if isinstance(raw, bytes):
        raw = raw.split(b"\x00", 1)[0].decode("ascii", "replace")
    return raw.split("\x00", 1)[0][:16]


def autopilot_version(sysid: int) -> MAVLinkMessage:
    """AUTOPILOT_VERSION with PX4 v1.16.0's version words and capabilities (``PX4_*`` above).

    os_sw_version stays 0 (PX4 reports its host's kernel) and the uid is the plant's own
    (``0x5171_0000 + sysid``: one per vehicle, never 0, uid2 zero as in PX4 SITL)."""
    return mavlink.MAVLink_autopilot_version_message(
        PX4_CAPABILITIES, PX4_FLIGHT_SW_VERSION, PX4_FLIGHT_SW_VERSION, 0, PX4_BOARD_VERSION,
        list(PX4_GIT_HASH_BYTES), list(PX4_GIT_HASH_BYTES), [0] * 8, 0, 0, 0x5171_0000 + sysid,
    )  # fmt: skip


def timesync_reply(now_ns: int, ts1: int) -> MAVLinkMessage:
    """TIMESYNC answering a request: tc1 = our time now (ns), ts1 = the request's."""
    return mavlink.MAVLink_timesync_message(now_ns, ts1)


def message_interval(message_id: int, interval_us: int) -> MAVLinkMessage:
    """MESSAGE_INTERVAL: a stream's interval (us; -1 off)."""
    return mavlink.MAVLink_message_interval_message(message_id, interval_us)


def _clip16(value: float) -> int:
    return int(max(-32768, min(32767, round(value)))) if math.isfinite(value) else 0


def _clip32(value: float) -> int:
    return int(max(-(2**31), min(2**31 - 1, round(value)))) if math.isfinite(value) else 0


# --- incoming ---------------------------------------------------------------------------------


def _payload(msg: MAVLinkMessage) -> bytes:
    """The raw payload bytes of a received message (MAVLink 1 or 2)."""
    buf = msg.get_msgbuf()
    header = 10 if buf[0] == mavlink.PROTOCOL_MARKER_V2 else 6
    return bytes(buf[header : header + buf[1]])


def decode_attitude_target(msg: MAVLinkMessage) -> AttitudeSetpoint:
    """SET_ATTITUDE_TARGET as PX4's ``handle_message_set_attitude_target`` reads it.

    type_mask: bits 0-2 ignore body roll/pitch/yaw rate, bit 5 thrust_body set, bit 6 ignore
    thrust, bit 7 ignore attitude. ``thrust`` is normalised; with bit 5 the collective thrust is
    ``-thrust_body[2]`` (the newer extension field, read from the raw payload).

    Raises
    ------
    Refused
        A used field that is NaN/infinite, a quaternion far from unit norm, an absurd rate.
    """
    mask = int(msg.type_mask)
    q = None
    if not mask & ATTITUDE_IGNORE:
        q = tuple(float(v) for v in msg.q)
        if not all(math.isfinite(v) for v in q):
            raise Refused("attitude quaternion not finite")
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
            raise Refused(f"attitude quaternion norm {norm:.3g}, expected 1")
        q = tuple(v / norm for v in q)
    rates: list[float | None] = []
    for bit, value in zip(RATE_IGNORE, (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)):
        if mask & bit:
            rates.append(None)
            continue
        value = float(value)
        if not math.isfinite(value):
            raise Refused("body rate not finite")
        if abs(value) > MAX_BODY_RATE_RAD_S:
            raise Refused(f"body rate {value:.3g} rad/s beyond {MAX_BODY_RATE_RAD_S:g}")
        rates.append(value)
    thrust: float | None = None
    if mask & THRUST_BODY_SET:
        payload = _payload(msg).ljust(_SET_ATTITUDE_TARGET_BASE_LEN + 12, b"\x00")
        tb = struct.unpack_from("<3f", payload, _SET_ATTITUDE_TARGET_BASE_LEN)
        if not all(math.isfinite(v) for v in tb):
            raise Refused("thrust_body not finite")
        thrust = -tb[2]
    elif not mask & THROTTLE_IGNORE:
        thrust = float(msg.thrust)
        if not math.isfinite(thrust):
            raise Refused("thrust not finite")
    return AttitudeSetpoint(int(msg.time_boot_ms), q, (rates[0], rates[1], rates[2]), thrust)  # type: ignore[arg-type]


def decode_actuator_target(msg: MAVLinkMessage) -> ActuatorSetpoint:
    """SET_ACTUATOR_CONTROL_TARGET, group 0 only: controls[0..3] = roll, pitch, yaw, thrust.

    Values are clipped to [-1, 1] (torques) and [0, 1] (thrust) as PX4's mixer saturates them.

    Raises
    ------
    Refused
        Another group, or a NaN/infinite control among the four used.
    """
    if int(msg.group_mlx) != 0:
        raise Refused(f"actuator control group {msg.group_mlx} not supported (only 0)")
    c = [float(v) for v in msg.controls[:4]]
    if not all(math.isfinite(v) for v in c):
        raise Refused("actuator control not finite")
    controls = (
        min(max(c[0], -1.0), 1.0),
        min(max(c[1], -1.0), 1.0),
        min(max(c[2], -1.0), 1.0),
        min(max(c[3], 0.0), 1.0),
    )
    return ActuatorSetpoint(int(msg.time_usec), controls)


POSITION_IGNORE = (1, 2, 4)  # POSITION_TARGET_TYPEMASK_X/Y/Z_IGNORE
VELOCITY_IGNORE = (8, 16, 32)  # VX/VY/VZ_IGNORE
YAW_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE  # 1024
MAX_POSITION_M = 1e6
MAX_SPEED_M_S = 100.0


def decode_position_target(msg: MAVLinkMessage, yaw_rad: float = 0.0) -> PositionSetpoint:
    """SET_POSITION_TARGET_LOCAL_NED: positions and velocities in MAV_FRAME_LOCAL_NED, yaw;
    or, in MAV_FRAME_BODY_NED, velocities forward-right-down turned into NED by the heading
    ``yaw_rad`` (rad) at receipt, positions not used, as PX4's mavlink_receiver.cpp
    (``handle_message_set_position_target_local_ned``; PX4 v1.16 measured: forward 2 m/s at
    yaw 90 deg flies east). MAV_FRAME_LOCAL_OFFSET_NED and BODY_OFFSET_NED are refused (PX4 v1.16
    flies neither: it logs "coordinate frame 9 unsupported", and frame 7 is no offboard signal).

    Accelerations and yaw rate are not flown (ignored). Each axis needs a position or a velocity.
    ``yaw`` is absolute (NED) in both frames, as PX4 reads it.

    Raises
    ------
    Refused
        Another frame, an axis with neither, a used NaN/infinite or absurd value.
    """
    frame = int(msg.coordinate_frame)
    if frame not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_NED):
        raise Refused(f"position target frame {frame} not supported (only MAV_FRAME_LOCAL_NED and MAV_FRAME_BODY_NED)")
    mask = int(msg.type_mask)
    if frame == mavlink.MAV_FRAME_BODY_NED:
        mask |= POSITION_IGNORE[0] | POSITION_IGNORE[1] | POSITION_IGNORE[2]
    pos: list[float | None] = []
    vel: list[float | None] = []
    for i, (p, v) in enumerate(zip((msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz))):
        p = None if mask & POSITION_IGNORE[i] else float(p)
        v = None if mask & VELOCITY_IGNORE[i] else float(v)
        if p is None and v is None:
            raise Refused("position target: an axis has neither position nor velocity")
        if p is not None and not (math.isfinite(p) and abs(p) < MAX_POSITION_M):
            raise Refused(f"position target: position {p} not finite or beyond {MAX_POSITION_M:g} m")
        if v is not None and not (math.isfinite(v) and abs(v) < MAX_SPEED_M_S):
            raise Refused(f"position target: velocity {v} not finite or beyond {MAX_SPEED_M_S:g} m/s")
        pos.append(p)
        vel.append(v)
    if frame == mavlink.MAV_FRAME_BODY_NED and vel[0] is not None and vel[1] is not None:
        vel[0], vel[1] = body_to_ned_velocity(vel[0], vel[1], yaw_rad)
    elif frame == mavlink.MAV_FRAME_BODY_NED and (vel[0] is not None or vel[1] is not None):
        raise Refused("position target: a body-frame velocity needs both forward and right components")
    yaw = None
    if not mask & YAW_IGNORE:
        yaw = float(msg.yaw)
        if not math.isfinite(yaw):
            raise Refused("position target: yaw not finite")
    return PositionSetpoint(int(msg.time_boot_ms), tuple(pos), tuple(vel), yaw)  # type: ignore[arg-type]


def body_to_ned_velocity(forward_m_s: float, right_m_s: float, yaw_rad: float) -> tuple[float, float]:
    """A horizontal velocity forward/right of a heading ``yaw_rad`` (rad, NED, about down) as
    (north, east) m/s: the rotation about down by the yaw alone, as PX4 (not the full attitude)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * forward_m_s - s * right_m_s, s * forward_m_s + c * right_m_s


def decode_command(msg: MAVLinkMessage) -> Command:
    """COMMAND_LONG or COMMAND_INT as one ``Command`` (unused params may be NaN: normal)."""
    if msg.get_type() == "COMMAND_INT":
        params = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
    else:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
    return Command(int(msg.command), tuple(float(p) for p in params), msg.get_srcSystem(), msg.get_srcComponent())  # type: ignore[arg-type]


def decode_set_mode(msg: MAVLinkMessage) -> Mode | None:
    """The legacy SET_MODE message: PX4 custom mode in ``custom_mode`` when the flag is set."""
    if not int(msg.base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return None
    return Mode.from_custom_mode(int(msg.custom_mode))


def addressed_to(msg: MAVLinkMessage, sysid: int, compid: int) -> bool:
    """Whether a targeted message is for us (0 = broadcast); untargeted messages always are."""
    ts = getattr(msg, "target_system", None)
    if ts is not None and ts not in (0, sysid):
        return False
    tc = getattr(msg, "target_component", None)
    return tc is None or tc in (0, compid)


# --- the mission protocol (sitl_plant/mission.py) -----------------------------------------------

_MISSION_CONSTRUCTORS = {
    "MISSION_REQUEST_INT": mavlink.MAVLink_mission_request_int_message,
    "MISSION_REQUEST": mavlink.MAVLink_mission_request_message,
    "MISSION_ACK": mavlink.MAVLink_mission_ack_message,
    "MISSION_COUNT": mavlink.MAVLink_mission_count_message,
    "MISSION_ITEM_INT": mavlink.MAVLink_mission_item_int_message,
    "MISSION_ITEM": mavlink.MAVLink_mission_item_message,
}


def mission_message(out: Out) -> MAVLinkMessage:
    """The pymavlink message of a ``mission.Out`` (target system and component first, for the
    messages that have them)."""
    kind, target, fields = out.kind, out.target, out.fields
    if kind == "MISSION_CURRENT":
        return mavlink.MAVLink_mission_current_message(*fields)
    if kind == "MISSION_ITEM_REACHED":
        return mavlink.MAVLink_mission_item_reached_message(*fields)
    assert target is not None  # the others are addressed
    return _MISSION_CONSTRUCTORS[kind](target[0], target[1], *fields)


_UNSET_E7 = (0, 2**31 - 1)  # COMMAND_INT x/y that mean "here" (0, or INT32_MAX as PX4's "not set")


def command_position_ned(msg: MAVLinkMessage, frame: Frame, here_ned_m: np.ndarray) -> tuple[float, float, float] | None:
    """The position of a DO_REPOSITION / DO_ORBIT command in local NED (m), or None for a frame
    the plant does not take. ``frame`` is the autopilot's ``navigator.Frame``.

    COMMAND_LONG: param5, param6 latitude, longitude in degrees (NaN: here), param7 altitude AMSL
    (NaN: the current one). COMMAND_INT in MAV_FRAME_GLOBAL(_INT): x, y degE7 (0: here), z AMSL.
    COMMAND_INT in the global-relative frames, as PX4 v1.16 SITL was measured to fly them
    (docs/parity/mission.md): x, y are not taken (the vehicle stays where it is) and z is read as
    an altitude AMSL, so a height of 12 m above home sends it down towards the ground.
    """
    here = (float(here_ned_m[0]), float(here_ned_m[1]), float(here_ned_m[2]))
    if msg.get_type() == "COMMAND_INT":
        if msg.frame in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT):
            unset = msg.x in _UNSET_E7 and msg.y in _UNSET_E7
        elif msg.frame in (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            unset = True
        else:
            return None
        lat, lon, alt = msg.x * 1e-7, msg.y * 1e-7, float(msg.z)
    else:
        unset = not (math.isfinite(msg.param5) and math.isfinite(msg.param6))
        lat, lon, alt = float(msg.param5), float(msg.param6), float(msg.param7)
    if not (unset or (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0)):
        return None
    n, e, d = frame.to_ned(0.0 if unset else lat, 0.0 if unset else lon, alt if math.isfinite(alt) else 0.0, False)
    if unset:
        n, e = here[0], here[1]
    if not math.isfinite(alt):
        d = here[2]
    return n, e, d
