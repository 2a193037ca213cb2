"""The codec: state -> MAVLink and MAVLink -> setpoints, through real pymavlink pack/parse."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant import codec
from sitl_plant.autopilot import Mode, Status
from sitl_plant.codec import Home, Refused
from offboard.model.rotations import quat_from_euler
from offboard.model.state import VehicleState


def wire(msg, src=(255, 190)):
    """Pack as a client would and parse back as the plant does."""
    sender = mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    parser = mavlink.MAVLink(None)
    parsed = parser.parse_buffer(msg.pack(sender))
    assert parsed is not None and len(parsed) == 1
    return parsed[0]


def status(**kw) -> Status:
    base = dict(armed=False, mode=Mode.AUTO_LOITER, system_status=3, landed_state=1, failsafe=False, failures=frozenset(), prearm_ok=True)
    base.update(kw)
    return Status(**base)  # type: ignore[arg-type]


def vstate(pos=(0.0, 0.0, 0.0), euler=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0)) -> VehicleState:
    return VehicleState(
        time_s=0.0,
        pos_ned_m=np.array(pos, float),
        vel_ned_m_s=np.array(vel, float),
        acc_ned_m_s2=np.array(acc, float),
        euler_rad=np.array(euler, float),
        euler_rate_rad_s=np.zeros(3),
        body_rate_frd_rad_s=np.array([0.1, -0.2, 0.3]),
        quat_wxyz=quat_from_euler(*euler),
    )


# --- outgoing -------------------------------------------------------------------------------------


def test_heartbeat_px4_fields():
    hb = wire(codec.heartbeat(status(armed=True, mode=Mode.OFFBOARD, system_status=4)))
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == 6 << 16
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE
    hb = wire(codec.heartbeat(status()))
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert (hb.custom_mode >> 16) & 0xFF == 4 and hb.custom_mode >> 24 == 3  # AUTO / LOITER


def test_pymavlink_names_our_modes():
    from pymavlink import mavutil

    for mode, name in [(Mode.OFFBOARD, "OFFBOARD"), (Mode.AUTO_LOITER, "LOITER"), (Mode.AUTO_LAND, "LAND"), (Mode.AUTO_TAKEOFF, "TAKEOFF")]:
        hb = wire(codec.heartbeat(status(mode=mode)))
        assert mavutil.mode_string_v10(hb) == name


def test_attitude_and_position_round_trip():
    st = vstate(pos=(1.5, -2.0, -3.25), euler=(0.1, -0.2, 1.0), vel=(0.5, 0.0, -1.0))
    att = wire(codec.attitude(1234, st))
    assert att.time_boot_ms == 1234
    np.testing.assert_allclose([att.roll, att.pitch, att.yaw], [0.1, -0.2, 1.0], atol=1e-6)
    np.testing.assert_allclose([att.rollspeed, att.pitchspeed, att.yawspeed], [0.1, -0.2, 0.3], atol=1e-6)
    pos = wire(codec.local_position_ned(1234, st))
    np.testing.assert_allclose([pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz], [1.5, -2.0, -3.25, 0.5, 0.0, -1.0], atol=1e-6)
    q = wire(codec.attitude_quaternion(1234, st))
    np.testing.assert_allclose([q.q1, q.q2, q.q3, q.q4], quat_from_euler(0.1, -0.2, 1.0), atol=1e-6)


def test_global_position_from_home():
    home = Home(47.397742, 8.545594, 488.0)
    st = vstate(pos=(111.0, 0.0, -10.0), vel=(1.0, -2.0, 0.5), euler=(0, 0, -math.pi / 2))
    g = wire(codec.global_position_int(5, st, home))
    # 111 m north is 0.000998 deg of latitude (R = 6371 km)
    assert g.lat * 1e-7 == pytest.approx(47.397742 + math.degrees(111.0 / 6371000.0), abs=2e-7)
    assert g.lon * 1e-7 == pytest.approx(8.545594, abs=2e-7)
    assert g.alt == 498000 and g.relative_alt == 10000
    assert (g.vx, g.vy, g.vz) == (100, -200, 50)
    assert g.hdg == 27000


def test_geodetic_east_and_parse_home():
    home = Home.parse("0,0,0")
    lat, lon, alt = codec.ned_to_geodetic(np.array([0.0, 1000.0, 5.0]), home)
    assert lat == pytest.approx(0.0, abs=1e-9) and lon == pytest.approx(math.degrees(1000.0 / 6371000.0), rel=1e-6) and alt == -5.0
    for bad in ("1,2", "a,b,c", "91,0,0", "0,200,0"):
        with pytest.raises(ValueError):
            Home.parse(bad)


def test_highres_imu_at_rest_measures_minus_g_along_body_z():
    imu = wire(codec.highres_imu(1000, vstate(), Home()))
    np.testing.assert_allclose([imu.xacc, imu.yacc, imu.zacc], [0.0, 0.0, -9.81], atol=1e-5)
    # pitched up 30 degrees: gravity shows on the body x axis
    imu = wire(codec.highres_imu(1000, vstate(euler=(0.0, math.radians(30), 0.0)), Home()))
    assert imu.xacc == pytest.approx(9.81 * math.sin(math.radians(30)), abs=1e-4)
    assert imu.abs_pressure == pytest.approx(codec.pressure_hpa(488.0), rel=1e-6)


def test_sys_status_health_follows_failures():
    ok = wire(codec.sys_status(status()))
    gyro = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert ok.onboard_control_sensors_present & gyro and ok.onboard_control_sensors_health & gyro
    assert ok.onboard_control_sensors_health & prearm
    bad = wire(codec.sys_status(status(failures=frozenset({"gyro"}), prearm_ok=False)))
    assert bad.onboard_control_sensors_present & gyro and not bad.onboard_control_sensors_health & gyro
    assert not bad.onboard_control_sensors_health & prearm


def test_param_value_int32_travels_as_bytes():
    pv = wire(codec.param_value("COM_OBL_RC_ACT", 4.0, True, 10, 3))
    assert pv.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == 4
    assert pv.param_id == "COM_OBL_RC_ACT" and (pv.param_count, pv.param_index) == (10, 3)
    set_msg = wire(mavlink.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 5))[0], mavlink.MAV_PARAM_TYPE_INT32))
    assert codec.param_set_value(set_msg) == 5.0
    set_msg = wire(mavlink.MAVLink_param_set_message(1, 1, b"PAP_TO", 0.02, mavlink.MAV_PARAM_TYPE_REAL32))
    assert codec.param_set_value(set_msg) == pytest.approx(0.02)
    assert codec.param_name(set_msg.param_id) == "PAP_TO"


def test_statustext_chunks_long_texts():
    short = codec.statustext(6, "hello", 7)
    assert len(short) == 1 and wire(short[0]).text == "hello"
    long_text = "x" * 120
    parts = [wire(m) for m in codec.statustext(2, long_text, 7)]
    assert len(parts) == 3 and {p.id for p in parts} == {7} and [p.chunk_seq for p in parts] == [0, 1, 2]
    assert "".join(p.text for p in parts) == long_text
    whole = [wire(m) for m in codec.statustext(2, "y" * 100, 8)]  # two whole chunks: an empty one ends it
    assert [(p.chunk_seq, p.text) for p in whole] == [(0, "y" * 50), (1, "y" * 50), (2, "")]


def test_servo_outputs_scale_with_rotor_speed():
    m = wire(codec.servo_output_raw(10, np.array([0.0, 350.0, 700.0, 1000.0]), 700.0, True))
    assert (m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw) == (1000, 1500, 2000, 2000)
    m = wire(codec.servo_output_raw(10, np.array([0.0, 350.0, 700.0, 1000.0]), 700.0, False))
    assert m.servo1_raw == 900


# --- incoming -------------------------------------------------------------------------------------


def set_attitude_target(mask, q=(1.0, 0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), thrust=0.5, t_ms=50):
    return wire(mavlink.MAVLink_set_attitude_target_message(t_ms, 1, 1, mask, q, rates[0], rates[1], rates[2], thrust))


def test_attitude_setpoint_with_attitude():
    q = tuple(quat_from_euler(0.0, 0.2, 0.0))
    sp = codec.decode_attitude_target(set_attitude_target(0b00000111, q=q, thrust=0.4, t_ms=250))
    assert sp.time_boot_ms == 250 and sp.flies_attitude and not sp.flies_rates
    np.testing.assert_allclose(sp.q_wxyz, q, atol=1e-6)
    assert sp.body_rates_frd_rad_s == (None, None, None) and sp.thrust_norm == pytest.approx(0.4)


def test_attitude_setpoint_with_rates_ignoring_yaw():
    sp = codec.decode_attitude_target(set_attitude_target(0b10000100, rates=(0.5, -0.25, 9.0), thrust=0.3))
    assert sp.flies_rates and sp.q_wxyz is None
    assert sp.body_rates_frd_rad_s == (pytest.approx(0.5), pytest.approx(-0.25), None)


def test_thrust_ignored_and_all_ignored():
    sp = codec.decode_attitude_target(set_attitude_target(0b11000111))
    assert sp.thrust_norm is None and not sp.is_setpoint


def test_thrust_body_extension_is_read():
    # a newer client: 12 more payload bytes (thrust_body) and type_mask bit 5
    msg = mavlink.MAVLink_set_attitude_target_message(9, 1, 1, 0b10100000, (1.0, 0, 0, 0), 0.0, 0.0, 0.0, 0.0)
    sender = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    packed = bytearray(msg.pack(sender))
    payload = bytes(packed[10 : 10 + packed[1]]).ljust(39, b"\x00") + struct.pack("<3f", 0.0, 0.0, -0.6)
    # re-frame with the longer payload and a recomputed CRC
    from pymavlink.generator.mavcrc import x25crc

    header = bytearray(packed[:10])
    header[1] = len(payload)
    crc = x25crc(bytes(header[1:]) + payload)
    crc.accumulate(struct.pack("B", mavlink.MAVLink_set_attitude_target_message.crc_extra))
    frame = bytes(header) + payload + struct.pack("<H", crc.crc)
    parsed = mavlink.MAVLink(None).parse_buffer(frame)[0]
    sp = codec.decode_attitude_target(parsed)
    assert sp.thrust_norm == pytest.approx(0.6)


@pytest.mark.parametrize(
    ("mask", "kw", "match"),
    [
        (0b00000111, {"q": (math.nan, 0, 0, 0)}, "quaternion"),
        (0b00000111, {"q": (0.0, 0.0, 0.0, 0.0)}, "norm"),
        (0b10000000, {"rates": (math.inf, 0.0, 0.0)}, "rate"),
        (0b10000000, {"rates": (500.0, 0.0, 0.0)}, "rate"),
        (0b00000111, {"thrust": math.nan}, "thrust"),
    ],
)
def test_refused_attitude_setpoints(mask, kw, match):
    with pytest.raises(Refused, match=match):
        codec.decode_attitude_target(set_attitude_target(mask, **kw))


def test_nan_in_an_ignored_field_is_fine():
    sp = codec.decode_attitude_target(set_attitude_target(0b00000111, rates=(math.nan, math.nan, math.nan)))
    assert sp.flies_attitude


def test_actuator_setpoint_clipped_and_validated():
    msg = wire(mavlink.MAVLink_set_actuator_control_target_message(123000, 0, 1, 1, [0.5, -2.0, 0.1, 1.5, 0, 0, 0, 0]))
    sp = codec.decode_actuator_target(msg)
    assert sp.time_usec == 123000 and sp.controls == pytest.approx((0.5, -1.0, 0.1, 1.0))
    with pytest.raises(Refused, match="group"):
        codec.decode_actuator_target(wire(mavlink.MAVLink_set_actuator_control_target_message(0, 1, 1, 1, [0.0] * 8)))
    with pytest.raises(Refused, match="finite"):
        codec.decode_actuator_target(wire(mavlink.MAVLink_set_actuator_control_target_message(0, 0, 1, 1, [math.nan] + [0.0] * 7)))


def test_commands_long_and_int():
    c = codec.decode_command(wire(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 21196, math.nan, math.nan, math.nan, math.nan, math.nan)))
    assert c.command == 400 and c.params[:2] == (1.0, 21196.0) and math.isnan(c.params[6])
    assert (c.source_system, c.source_component) == (255, 190)
    c = codec.decode_command(wire(mavlink.MAVLink_command_int_message(1, 1, 6, 22, 0, 0, 0, 0, 0, 0, 473977420, 85455940, 500.0)))
    assert c.command == 22 and c.params[4] == 473977420.0 and c.params[6] == 500.0


def test_set_mode_message():
    m = wire(mavlink.MAVLink_set_mode_message(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.AUTO_LAND.custom_mode))
    assert codec.decode_set_mode(m) is Mode.AUTO_LAND
    assert codec.decode_set_mode(wire(mavlink.MAVLink_set_mode_message(1, 0, 6 << 16))) is None


def test_addressed_to():
    ours = wire(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    broadcast = wire(mavlink.MAVLink_command_long_message(0, 0, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    other_sys = wire(mavlink.MAVLink_command_long_message(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    other_comp = wire(mavlink.MAVLink_command_long_message(1, 154, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    hb = wire(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
    assert codec.addressed_to(ours, 1, 1) and codec.addressed_to(broadcast, 1, 1) and codec.addressed_to(hb, 1, 1)
    assert not codec.addressed_to(other_sys, 1, 1) and not codec.addressed_to(other_comp, 1, 1)


def test_gps_raw_and_vfr_hud():
    st = vstate(pos=(0.0, 0.0, -20.0), vel=(3.0, 4.0, -1.0), euler=(0.0, 0.0, math.pi / 2))
    gps = wire(codec.gps_raw_int(5000, st, Home()))
    assert gps.fix_type == mavlink.GPS_FIX_TYPE_3D_FIX and gps.satellites_visible == 10
    assert (gps.lat, gps.lon, gps.alt, gps.vel) == (473977420, 85455940, 508000, 500)
    assert gps.cog == pytest.approx(math.degrees(math.atan2(4.0, 3.0)) * 100, abs=1)
    assert wire(codec.gps_raw_int(5000, st, Home(), healthy=False)).fix_type == mavlink.GPS_FIX_TYPE_NO_FIX
    hud = wire(codec.vfr_hud(st, Home(), 0.42))
    assert (hud.groundspeed, hud.heading, hud.throttle, hud.alt, hud.climb) == (pytest.approx(5.0), 90, 42, pytest.approx(508.0), pytest.approx(1.0))


def position_target(mask, frame=mavlink.MAV_FRAME_LOCAL_NED, pos=(1.0, 2.0, -3.0), vel=(0.0, 0.0, 0.0), yaw=0.5):
    return wire(mavlink.MAVLink_set_position_target_local_ned_message(70, 1, 1, frame, mask, *pos, *vel, 0, 0, 0, yaw, 0))


def test_position_target_as_mavsdk_sends_them():
    ignore_vel_acc_rate = 0b0000_1001_1111_1000  # set_position_ned: position and yaw
    sp = codec.decode_position_target(position_target(ignore_vel_acc_rate))
    assert sp.pos_ned_m == (1.0, 2.0, -3.0) and sp.vel_ned_m_s == (None, None, None) and sp.yaw_rad == pytest.approx(0.5)
    ignore_pos_acc_yaw = 0b0000_1101_1100_0111  # set_velocity_ned without yaw
    sp = codec.decode_position_target(position_target(ignore_pos_acc_yaw, vel=(0.5, 0.0, -0.2)))
    assert sp.pos_ned_m == (None, None, None) and sp.vel_ned_m_s == pytest.approx((0.5, 0.0, -0.2)) and sp.yaw_rad is None


@pytest.mark.parametrize(
    ("mask", "kw", "match"),
    [
        (0b0000_1001_1111_1000, {"frame": mavlink.MAV_FRAME_BODY_OFFSET_NED}, "frame"),  # PX4 v1.16 flies BODY_NED, not this
        (0b0000_1001_1111_1111, {}, "neither"),
        (0b0000_1001_1111_1000, {"pos": (math.nan, 0.0, 0.0)}, "position"),
        (0b0000_1101_1100_0111, {"vel": (500.0, 0.0, 0.0)}, "velocity"),
        (0b0000_1001_1111_1000, {"yaw": math.inf}, "yaw"),
    ],
)
def test_refused_position_targets(mask, kw, match):
    with pytest.raises(Refused, match=match):
        codec.decode_position_target(position_target(mask, **kw))
