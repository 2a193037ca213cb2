"""offboard.codec: telemetry in, setpoints out, checked through pymavlink pack()/parse and against
the plant's own decoder, with no socket."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pymavlink.dialects.v20 import common as mavlink

from offboard import codec
from offboard.controller import PAPER_CONTROLLER_FILE, RosalesController, TrackingReference, load_controller
from offboard.controller.command import MissingCommand
from offboard.controller.paper import paper_command, paper_state_of
from offboard.frames import paper_state, tilt_about_heading
from offboard.model.euler_lagrange import body_torque_from_generalized, euler_rates_from_body_rates
from sitl_plant import codec as plant_codec
from offboard.model.euler_lagrange import euler_rate_matrix
from offboard.model.rotations import euler_from_quat, quat_from_euler, rotation_matrix

SCALING = codec.Scaling(19.6, 1.176, 0.1568)


def wire(msg, sysid=1, compid=1):
    """The message as it arrives: packed, sent, parsed by pymavlink."""
    packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    parser = mavlink.MAVLink(None)
    out = parser.parse_buffer(msg.pack(packer))
    assert out and len(out) == 1
    return out[0]


def telemetry(euler=(0.1, -0.2, 0.7), rates=(0.3, -0.1, 0.05), pos=(1.0, -2.0, -3.0), vel=(0.5, 0.25, -0.125), t_ms=1234):
    att = wire(mavlink.MAVLink_attitude_message(t_ms, *euler, *rates))
    lpn = wire(mavlink.MAVLink_local_position_ned_message(t_ms, *pos, *vel))
    return att, lpn


def control_output(euler=(0.1, -0.2, 0.7), form="zyx", yaw_aware=True, ref=(2.0, 1.0, 3.0, 1.2), still=False):
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(euler_rate_form=form, yaw_aware=yaw_aware)
    att, lpn = telemetry(euler=euler, **({"rates": (0.0, 0.0, 0.0), "vel": (0.0, 0.0, 0.0)} if still else {}))
    measured = codec.measured_state(att, lpn)
    x = paper_state_of(measured, form)
    ctrl = RosalesController(params)
    r = TrackingReference(*ref)
    return ctrl.step(x, r, r), measured


def encode(out, m, form, yaw_aware, model, output):
    """The law's output as offboard fly sends it: its command, then the command's setpoint."""
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(euler_rate_form=form, yaw_aware=yaw_aware)
    return codec.command_setpoint(paper_command(out, m.euler_rad, params, model), SCALING,
                                  output=output, model=model)


def test_measured_state_from_the_two_messages():
    att, lpn = telemetry()
    m = codec.measured_state(att, lpn)
    assert m.time_boot_ms == 1234 and m.position_time_boot_ms == 1234
    assert_allclose(m.pos_ned_m, [1.0, -2.0, -3.0])
    assert_allclose(m.vel_ned_m_s, [0.5, 0.25, -0.125])
    assert_allclose(m.euler_rad, [0.1, -0.2, 0.7], atol=1e-7)  # float32 on the wire
    assert_allclose(m.body_rate_frd_rad_s, [0.3, -0.1, 0.05], atol=1e-7)


@pytest.mark.parametrize("field", ["roll", "yawspeed"])
def test_non_finite_attitude_is_refused(field):
    att, lpn = telemetry()
    setattr(att, field, math.nan)
    with pytest.raises(codec.BadTelemetry):
        codec.measured_state(att, lpn)


def test_non_finite_position_is_refused():
    att, lpn = telemetry()
    lpn.vz = math.inf
    with pytest.raises(codec.BadTelemetry):
        codec.measured_state(att, lpn)


@pytest.mark.parametrize("form", ["zyx", "castillo"])
def test_controller_state_is_the_paper_state_with_euler_rates_from_body_rates(form):
    att, lpn = telemetry()
    m = codec.measured_state(att, lpn)
    x = paper_state_of(m, form)
    eta_dot = np.linalg.solve(euler_rate_matrix(m.euler_rad, form), m.body_rate_frd_rad_s)  # eq. 3
    assert_allclose(x, paper_state(m.pos_ned_m, m.vel_ned_m_s, m.euler_rad, eta_dot))
    assert x[4] == pytest.approx(3.0) and x[5] == pytest.approx(0.125)  # z up = -down


def test_euler_rate_form_follows_the_vehicle_model():
    assert codec.euler_rate_form_for("rigid-body", "castillo") == "zyx"
    assert codec.euler_rate_form_for("paper", "castillo") == "castillo"
    with pytest.raises(ValueError):
        codec.euler_rate_form_for("blimp", "zyx")


def test_paper_attitude_output_is_the_rate_setpoint_the_paper_loop_inverts():
    out, m = control_output(form="castillo", yaw_aware=False)
    sp = encode(out, m, "castillo", False, "paper", "attitude")
    assert sp.type_mask == mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
    assert_allclose(sp.q_wxyz, quat_from_euler(out.law.roll_ref_rad, out.law.pitch_ref_rad, out.law.yaw_ref_rad))
    msg = wire(codec.set_attitude_target(m.time_boot_ms, sp, 1, 1), sysid=245, compid=191)
    decoded = plant_codec.decode_attitude_target(msg)  # as the plant reads it
    assert decoded.time_boot_ms == m.time_boot_ms and decoded.q_wxyz is None and decoded.flies_rates
    # the paper loop's first step: eta_dot_ref = W_eta^-1 omega at the same attitude (eq. 3)
    eta_dot_ref = euler_rates_from_body_rates(m.euler_rad, np.array(decoded.body_rates_frd_rad_s), "castillo")
    assert_allclose(eta_dot_ref, out.law.euler_rate_ref_rad_s, rtol=1e-5, atol=1e-5)
    assert decoded.thrust_norm == pytest.approx(min(max(out.law.thrust_n / 19.6, 0.0), 1.0), abs=1e-6)


def test_rigid_body_attitude_output_keeps_the_thrust_axis_at_the_reference_heading():
    out, m = control_output(euler=(0.1, -0.2, 0.7), form="zyx", yaw_aware=True, ref=(2.0, 1.0, 3.0, 2.5, 0.4))
    law = out.law
    sp = encode(out, m, "zyx", True, "rigid-body", "attitude")
    assert sp.type_mask == codec.RIGID_BODY_TYPE_MASK == 3
    # PX4's yaw feed-forward is the reference's own yaw rate, not x12ref (the law's yaw feedback:
    # here 7.2 rad/s for a 1.8 rad yaw error, 63 rad/s at the paper's pi step)
    assert sp.body_rates_frd_rad_s[2] == pytest.approx(0.4) and abs(law.euler_rate_ref_rad_s[2]) > 5.0
    q = np.array(sp.q_wxyz)
    intended = rotation_matrix(quat_from_euler(law.roll_ref_rad, law.pitch_ref_rad, m.euler_rad[2]))[:, 2]
    assert_allclose(rotation_matrix(q)[:, 2], intended, atol=1e-12)  # the law's thrust axis ...
    assert euler_from_quat(q)[2] == pytest.approx(law.yaw_ref_rad)  # ... at the reference heading
    decoded = plant_codec.decode_attitude_target(wire(codec.set_attitude_target(7, sp, 1, 1)))
    assert decoded.flies_attitude and decoded.body_rates_frd_rad_s[:2] == (None, None)


@pytest.mark.parametrize("roll, pitch, heading", [(0.1, 0.2, 0.5), (-0.3, 0.05, -2.0), (0.0, 0.0, 1.0)])
def test_tilt_about_the_same_heading_is_unchanged(roll, pitch, heading):
    assert_allclose(tilt_about_heading(roll, pitch, heading, heading), (roll, pitch), atol=1e-12)


def test_tilt_about_a_quarter_turn():
    # rolling right while facing north pushes east; facing east that is pitching forward (nose down)
    roll, pitch = tilt_about_heading(0.2, 0.0, 0.0, math.pi / 2)
    assert roll == pytest.approx(0.0, abs=1e-12) and pitch == pytest.approx(-0.2)


@pytest.mark.parametrize("thrust_n, expected", [(9.8, 0.5), (-3.0, 0.0), (50.0, 1.0)])
def test_thrust_is_normalised_and_clipped(thrust_n, expected):
    assert codec.thrust_norm(thrust_n, SCALING) == pytest.approx(expected)


def test_rigid_body_actuator_output_is_the_body_torque_of_the_generalised_one():
    out, m = control_output(euler=(0.01, -0.02, 0.7), ref=(1.0, -2.0, 3.0, 0.7), still=True)  # near the state: small torques
    sp = encode(out, m, "zyx", True, "rigid-body", "actuator")
    assert np.all(np.abs(sp.controls[:3]) < 1.0) and 0.0 < sp.controls[3] < 1.0
    tau_body = np.array(sp.controls[:3]) * [1.176, 1.176, 0.1568]
    # virtual work: tau_gen = W_eta^T tau_body
    assert_allclose(euler_rate_matrix(m.euler_rad, "zyx").T @ tau_body, out.torques_nm, rtol=1e-9, atol=1e-12)
    assert sp.controls[3] == pytest.approx(out.law.thrust_n / 19.6)
    msg = wire(codec.set_actuator_control_target(m.time_boot_ms, sp, 1, 1))
    assert msg.time_usec == m.time_boot_ms * 1000 and msg.group_mlx == 0
    decoded = plant_codec.decode_actuator_target(msg)
    assert_allclose(decoded.controls, sp.controls, atol=1e-6)


def test_actuator_controls_saturate_like_the_mixer():
    out, m = control_output()  # 2 m from the reference: torques beyond the rotors'
    sp = encode(out, m, "zyx", True, "rigid-body", "actuator")
    assert max(abs(c) for c in sp.controls[:3]) == 1.0
    assert all(-1.0 <= c <= 1.0 for c in sp.controls[:3]) and 0.0 <= sp.controls[3] <= 1.0


def test_actuator_torque_round_trip_on_the_rigid_body():
    euler = np.array([0.3, -0.4, 1.1])
    tau_gen = np.array([0.2, -0.1, 0.05])
    body = body_torque_from_generalized(tau_gen, euler, "zyx")
    assert_allclose(euler_rate_matrix(euler, "zyx").T @ body, tau_gen, atol=1e-12)


def test_paper_actuator_output_is_the_generalised_torque_clipped():
    out, m = control_output(form="castillo", yaw_aware=False)
    sp = encode(out, m, "castillo", False, "paper", "actuator")
    expected = np.clip(np.asarray(out.torques_nm) / [1.176, 1.176, 0.1568], -1, 1)
    assert_allclose(sp.controls[:3], expected)


def test_actuator_output_needs_the_torque_scaling():
    out, m = control_output()
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(euler_rate_form="zyx", yaw_aware=True)
    with pytest.raises(ValueError, match="SIM_TQ_RP_MAX"):
        codec.command_setpoint(paper_command(out, m.euler_rad, params, "rigid-body"), codec.Scaling(19.6),
                               output="actuator", model="rigid-body")


def test_hold_setpoint_is_the_vehicles_attitude():
    sp = codec.hold_setpoint(np.array([0.1, 0.2, -1.0]), 0.0)
    assert_allclose(euler_from_quat(np.array(sp.q_wxyz)), [0.1, 0.2, -1.0], atol=1e-12)
    assert sp.thrust_norm == 0.0 and sp.type_mask == 0 and sp.body_rates_frd_rad_s == (0.0, 0.0, 0.0)


def test_heartbeat_of_px4_offboard_decodes():
    status = plant_codec.heartbeat(_plant_status(armed=True, mode=(6, 0)))
    s = codec.vehicle_status(wire(status))
    assert s.armed and s.offboard and s.mode_name == "Offboard" and not s.critical
    hold = codec.vehicle_status(wire(plant_codec.heartbeat(_plant_status(armed=False, mode=(4, 3)))))
    assert not hold.armed and not hold.offboard and hold.mode_name == "Hold"
    assert codec.is_autopilot_heartbeat(wire(status))
    assert not codec.is_autopilot_heartbeat(wire(codec.heartbeat(), 245, 191))


def _plant_status(armed: bool, mode: tuple[int, int]):
    from sitl_plant.autopilot import Mode, Status

    return Status(armed, Mode(mode), mavlink.MAV_STATE_ACTIVE, 1, False, frozenset(), True)


def test_own_heartbeat_is_an_onboard_controller():
    hb = wire(codec.heartbeat(), 245, 191)
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mavlink.MAV_AUTOPILOT_INVALID


def test_param_value_decodes_real_and_px4_int32():
    name, value = codec.param_value(wire(plant_codec.param_value("SIM_THR_MAX", 19.6, False, 10, 3)))
    assert name == "SIM_THR_MAX" and value == pytest.approx(19.6, rel=1e-7)
    name, value = codec.param_value(wire(plant_codec.param_value("COM_OBL_RC_ACT", 4, True, 10, 4)))
    assert name == "COM_OBL_RC_ACT" and value == 4.0


def test_param_request_read_by_name():
    msg = wire(codec.param_request_read(1, 1, "SIM_MASS"), 245, 191)
    assert plant_codec.param_name(msg.param_id) == "SIM_MASS" and msg.param_index == -1


@pytest.mark.parametrize("result, name", [(0, "ACCEPTED"), (1, "TEMPORARILY_REJECTED"), (2, "DENIED"), (4, "FAILED")])
def test_mav_result_names(result, name):
    assert codec.mav_result_name(result) == name


def test_commands_carry_px4s_numbers():
    command, params = codec.set_mode_offboard_params()
    msg = wire(codec.command_long(1, 1, command, params, 2), 245, 191)
    assert msg.command == mavlink.MAV_CMD_DO_SET_MODE and (msg.param1, msg.param2) == (1.0, 6.0) and msg.confirmation == 2
    command, params = codec.arm_params(False)
    assert command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and params[0] == 0.0
    assert codec.mav_cmd_name(mavlink.MAV_CMD_NAV_LAND) == "MAV_CMD_NAV_LAND"


def test_timesync_offset_assumes_a_symmetric_link():
    offset, rtt = codec.timesync_offset_ns(ts1_ns=1_000, tc1_ns=50_500, now_ns=2_000)
    assert rtt == 1_000 and offset == 49_000  # remote stamped at our 1500 ns: 50 500 - 1 500


def test_set_attitude_target_wire_layout():
    sp = codec.AttitudeSetpoint((1.0, 0.0, 0.0, 0.0), (0.1, 0.2, 0.3), 0.4, 3)
    raw = codec.set_attitude_target(2**32 + 5, sp, 1, 1).pack(mavlink.MAVLink(None, 245, 191))
    msg = mavlink.MAVLink(None).parse_buffer(raw)[0]
    assert msg.time_boot_ms == 5 and msg.type_mask == 3  # time_boot_ms wraps as uint32
    assert_allclose([msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate, msg.thrust], [0.1, 0.2, 0.3, 0.4], rtol=1e-7)


@pytest.mark.parametrize("output, model, form, yaw_aware", [
    ("attitude", "rigid-body", "zyx", True),
    ("attitude", "paper", "castillo", False),
    ("actuator", "rigid-body", "zyx", True),
    ("actuator", "paper", "castillo", False),
])  # fmt: skip
def test_command_setpoint_fields_are_what_the_message_carries(output, model, form, yaw_aware):
    out, m = control_output(euler=(0.01, -0.02, 0.7), form=form, yaw_aware=yaw_aware, still=True)
    sp = encode(out, m, form, yaw_aware, model, output)
    if output == "attitude":
        msg = wire(codec.set_attitude_target(m.time_boot_ms, sp, 1, 1))
        carried = (*msg.q, msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate, msg.thrust)
    else:
        msg = wire(codec.set_actuator_control_target(m.time_boot_ms, sp, 1, 1))
        carried = tuple(msg.controls[:4])
    # setpoint_fields lists what the message carries, in its order (float32 on the wire)
    assert_allclose(np.float32(codec.setpoint_fields(sp)), np.float32(carried), rtol=0, atol=0)


def test_command_setpoint_refuses_an_unknown_output_or_model():
    out, m = control_output()
    params = load_controller(PAPER_CONTROLLER_FILE)
    command = paper_command(out, m.euler_rad, params, "rigid-body")
    with pytest.raises(ValueError, match="output must be one of"):
        codec.command_setpoint(command, SCALING, output="position", model="rigid-body")
    with pytest.raises(ValueError, match="model must be one of"):
        codec.command_setpoint(command, SCALING, output="attitude", model="blimp")
    with pytest.raises(ValueError, match="vehicle_model must be one of"):
        paper_command(out, m.euler_rad, params, "blimp")


@pytest.mark.parametrize("output", ["rates", "actuator"])
def test_a_form_the_controller_does_not_give_is_refused_by_name(output):
    from offboard.baselines import Px4PositionController
    from offboard.trajectory.base import Reference

    _, m = control_output()
    command = Px4PositionController(0.5, 0.05).step(m, Reference(np.zeros(3)), Reference(np.zeros(3)))
    with pytest.raises(MissingCommand, match="the px4 controller gives no (body-rate|torque) command"):
        codec.command_setpoint(command, SCALING, output=output, model="rigid-body", controller="px4")
    assert codec.command_setpoint(command, SCALING, output="attitude", model="rigid-body").type_mask == codec.RIGID_BODY_TYPE_MASK


def test_rates_output_is_a_body_rate_setpoint_from_the_laws_euler_rate_references():
    out, m = control_output(euler=(0.1, -0.2, 0.7), form="zyx", yaw_aware=True)
    sp = encode(out, m, "zyx", True, "rigid-body", "rates")
    assert sp.type_mask == mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE  # PX4 flies the rates
    decoded = plant_codec.decode_attitude_target(wire(codec.set_attitude_target(m.time_boot_ms, sp, 1, 1)))
    assert decoded.flies_rates and decoded.q_wxyz is None
    # eq. 3 with the rigid body's W_eta at the measured attitude: back to the law's Euler-rate references
    eta_dot = euler_rates_from_body_rates(m.euler_rad, np.array(decoded.body_rates_frd_rad_s), "zyx")
    assert_allclose(eta_dot, out.law.euler_rate_ref_rad_s, rtol=1e-5, atol=1e-5)
    assert decoded.thrust_norm == pytest.approx(min(max(out.law.thrust_n / 19.6, 0.0), 1.0), abs=1e-6)
