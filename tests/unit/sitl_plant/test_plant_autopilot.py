"""The autopilot state machine, driven by hand (no simulation, no sockets)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl_plant.autopilot import (
    DEAD_RECKONING_S,
    FORCE_MAGIC,
    GPS_DROPPED_S,
    LAND_DETECT_WINDDOWN_S,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_INJECT_FAILURE,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_TAKEOFF,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    MAV_STATE_ACTIVE,
    MAV_STATE_CRITICAL,
    MAV_STATE_STANDBY,
    MAV_STATE_UNINIT,
    ActuatorSetpoint,
    AttitudeSetpoint,
    Autopilot,
    Command,
    IdleTask,
    ManualInput,
    Mode,
    OffboardTask,
    PositionTask,
)
from sitl_plant.codec import estimator_flags, sys_status
from sitl_plant.params import plant_params
from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams

NAN = math.nan


def state(down_m: float = 0.0, on_ground: bool | None = None, yaw: float = 0.0) -> VehicleState:
    z = np.zeros(3)
    return VehicleState(
        time_s=0.0,
        pos_ned_m=np.array([1.0, 2.0, down_m]),
        vel_ned_m_s=z,
        acc_ned_m_s2=z,
        euler_rad=np.array([0.0, 0.0, yaw]),
        euler_rate_rad_s=z,
        body_rate_frd_rad_s=z,
        quat_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
        on_ground=(down_m >= 0.0) if on_ground is None else on_ground,
    )


def cmd(command: int, *params: float) -> Command:
    p = list(params) + [NAN] * (7 - len(params))
    return Command(command, tuple(p), 255, 190)  # type: ignore[arg-type]


def offboard_mode() -> Command:
    return cmd(MAV_CMD_DO_SET_MODE, 1, 6, 0)


SETPOINT = AttitudeSetpoint(0, (1.0, 0.0, 0.0, 0.0), (None, None, None), 0.5)


@pytest.fixture
def ap():
    a = Autopilot(plant_params(VehicleParams()), home_alt_amsl_m=488.0)
    a.observe(state())
    return a


def test_boots_disarmed_in_hold(ap):
    st = ap.status()
    assert (st.armed, st.mode, st.system_status, st.failsafe) == (False, Mode.AUTO_LOITER, MAV_STATE_STANDBY, False)
    assert isinstance(ap.task(), IdleTask)


def test_px4_custom_mode_encoding():
    assert Mode.OFFBOARD.custom_mode == 6 << 16
    assert Mode.AUTO_LOITER.custom_mode == (4 << 16) | (3 << 24)
    assert Mode.AUTO_LAND.custom_mode == (4 << 16) | (6 << 24)
    for m in Mode:
        assert Mode.from_custom_mode(m.custom_mode) is m


def test_arm_and_disarm_on_the_ground(ap):
    reply = ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    assert reply.result == MAV_RESULT_ACCEPTED
    assert ap.status().armed and ap.status().system_status == MAV_STATE_ACTIVE
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 0), 1.0).result == MAV_RESULT_ACCEPTED
    assert not ap.armed


def test_prearm_refusal_and_force(ap):
    ap.failures.add("gps")
    reply = ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    assert reply.result == MAV_RESULT_TEMPORARILY_REJECTED  # PX4's commander answer to a failed pre-arm check
    assert "gps" in reply.texts[0].text and not ap.armed
    assert not ap.status().prearm_ok
    reply = ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1, FORCE_MAGIC), 0.0)
    assert reply.result == MAV_RESULT_ACCEPTED and ap.armed


def test_bad_arm_parameter_is_denied(ap):
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 0.7 + 1.0), 0.0).result == MAV_RESULT_DENIED
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, NAN), 0.0).result == MAV_RESULT_DENIED
    assert not ap.armed


def test_no_disarm_in_the_air_unless_forced(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-3.0))
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 0), 1.0).result == MAV_RESULT_TEMPORARILY_REJECTED
    assert ap.armed
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 0, FORCE_MAGIC), 1.0).result == MAV_RESULT_ACCEPTED
    assert not ap.armed


def test_offboard_needs_recent_setpoints_only_when_armed(ap):
    # PX4 v1.16: disarmed, every mode change is accepted; arming is what is refused
    assert ap.on_command(offboard_mode(), 0.0).result == MAV_RESULT_ACCEPTED
    assert ap.mode is Mode.OFFBOARD and ap.status().system_status == MAV_STATE_UNINIT
    assert ap.status().base_mode == 1  # no setpoints: CUSTOM_MODE_ENABLED only
    reply = ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    assert reply.result == MAV_RESULT_TEMPORARILY_REJECTED
    assert reply.texts[0].text == "Arming denied: Resolve system health failures first"
    ap.update(1.5)
    assert ap.mode is Mode.OFFBOARD  # disarmed, no fallback
    ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 4, 3), 1.5)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 1.5)
    ap.on_setpoint(SETPOINT, 1.0)
    # armed, setpoints too old (more than COM_OF_LOSS_T): refused as PX4 refuses it
    reply = ap.on_command(offboard_mode(), 2.5)
    assert reply.result == MAV_RESULT_TEMPORARILY_REJECTED and "Switching to Offboard is currently not available" in reply.texts[0].text
    ap.on_setpoint(SETPOINT, 3.0)
    assert ap.on_command(offboard_mode(), 3.5).result == MAV_RESULT_ACCEPTED
    assert ap.mode is Mode.OFFBOARD and ap.status().base_mode == 145


def test_setpoints_outside_offboard_are_remembered_not_flown(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    flown = ap.on_setpoint(SETPOINT, 0.1)
    assert not flown
    assert ap.last_setpoint is SETPOINT
    assert not isinstance(ap.task(), OffboardTask)
    ap.on_command(offboard_mode(), 0.2)
    task = ap.task()
    assert isinstance(task, OffboardTask) and task.setpoint is SETPOINT
    other = ActuatorSetpoint(0, (0.0, 0.0, 0.0, 0.5))
    assert ap.on_setpoint(other, 0.3)
    assert ap.task().setpoint is other  # type: ignore[union-attr]


def test_an_all_ignored_attitude_target_is_no_proof_of_life(ap):
    tick = AttitudeSetpoint(0, None, (None, None, None), None)
    assert not tick.is_setpoint
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.on_setpoint(tick, 0.0)
    assert ap.on_command(offboard_mode(), 0.1).result == MAV_RESULT_TEMPORARILY_REJECTED


STICKS_CENTRED = ManualInput(0.0, 0.0, 0.5, 0.0)


def test_manual_modes_accepted_disarmed_and_need_sticks_to_arm(ap):
    for main in (1, 2, 3, 5, 7):
        reply = ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, main, 0), 0.0)
        assert reply.result == MAV_RESULT_ACCEPTED
        assert ap.status().system_status == MAV_STATE_UNINIT  # no manual control input: cannot arm
    ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 3, 0), 0.0)
    assert ap.status().base_mode == 81  # MANUAL_INPUT | STABILIZE | CUSTOM, as PX4's Position
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0).result == MAV_RESULT_TEMPORARILY_REJECTED
    ap.on_manual_input(STICKS_CENTRED, 0.1)
    assert ap.status().system_status == MAV_STATE_STANDBY
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.1).result == MAV_RESULT_ACCEPTED
    assert ap.status().base_mode == 209
    assert ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 42, 0), 0.0).result == MAV_RESULT_DENIED


def test_position_refused_in_the_air_without_sticks(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-5.0))
    ap.update(0.5)
    reply = ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 3, 0), 0.6)
    assert reply.result == MAV_RESULT_TEMPORARILY_REJECTED and reply.texts[0].text == "Switching to Position is currently not available"
    ap.on_manual_input(STICKS_CENTRED, 0.7)
    assert ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 3, 0), 0.7).result == MAV_RESULT_ACCEPTED


def _in_position_at_5_m(ap: Autopilot) -> None:
    """Armed with the sticks centred, in the air at 5 m, in Position."""
    ap.on_manual_input(STICKS_CENTRED, 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-5.0))
    ap.update(0.0)
    ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 3, 0), 0.0)


def test_position_mode_sticks(ap):
    _in_position_at_5_m(ap)
    task = ap.task()
    assert isinstance(task, PositionTask) and task.pos_ned_m == (1.0, 2.0, -5.0)  # centred: hold
    t = 0.0
    for _ in range(200):  # full forward stick for 2 s, heading north: the velocity grows at MPC_ACC_HOR less drag
        t += 0.01
        ap.on_manual_input(ManualInput(1.0, 0.0, 1.0, 0.0), t)
        ap.update(t)
    task = ap.task()
    v_max, acc = ap.params["MPC_VEL_MANUAL"], ap.params["MPC_ACC_HOR"]
    expected = v_max * (1.0 - math.exp(-acc / v_max * 2.0))
    assert task.pos_ned_m[:2] == (None, None) and task.vel_ned_m_s[0] == pytest.approx(expected, rel=0.02)
    assert task.vel_ned_m_s[2] == pytest.approx(-ap.params["MPC_Z_VEL_MAX_UP"])  # full throttle: climb
    ap.on_manual_input(ManualInput(0.0, 0.0, 0.5, 1.0), t)  # release, full yaw
    ap.update(t + 0.5)
    assert ap.task().yaw_rad == pytest.approx(math.radians(ap.params["MPC_MAN_Y_MAX"]) * 0.5)


def test_position_without_sticks_descends_at_land_speed(ap):
    _flying_offboard(ap)
    ap.update(1.5)  # offboard loss, COM_OBL_RC_ACT 0: Position, no sticks
    task = ap.task()
    assert ap.mode is Mode.POSCTL and isinstance(task, PositionTask)
    assert task.pos_ned_m == (1.0, 2.0, None) and task.descend_m_s == ap.params["MPC_LAND_SPEED"]


def test_manual_control_loss_holds_then_returns(ap):
    _in_position_at_5_m(ap)
    ap.update(0.5)
    assert ap.mode is Mode.POSCTL
    texts = ap.update(0.51)  # COM_RC_LOSS_T 0.5 s without MANUAL_CONTROL
    assert ap.mode is Mode.AUTO_LOITER and ap.failsafe and "Hold for 5 seconds" in texts[0].text
    ap.update(0.51 + ap.params["COM_FAIL_ACT_T"])
    assert ap.mode is Mode.AUTO_RTL  # NAV_RCL_ACT 2


def _flying_offboard(ap: Autopilot) -> None:
    ap.on_setpoint(SETPOINT, 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.on_command(offboard_mode(), 0.0)
    ap.observe(state(-5.0))
    ap.update(0.5)
    assert ap.mode is Mode.OFFBOARD


@pytest.mark.parametrize(
    "action, mode",
    [(0, Mode.POSCTL), (1, Mode.ALTCTL), (2, Mode.STABILIZED), (3, Mode.AUTO_RTL), (4, Mode.AUTO_LAND), (5, Mode.AUTO_LOITER)],
)
def test_offboard_loss_failsafe_table(ap, action, mode):
    """PX4's failsafe.cpp fromOffboardLossActParam: a mode fallback, at once (not deferred)."""
    ap.params.set("COM_OBL_RC_ACT", action)
    _flying_offboard(ap)
    assert ap.update(1.0) == []  # last setpoint exactly COM_OF_LOSS_T old: still fine
    texts = ap.update(1.01)
    assert ap.mode is mode and ap.failsafe and ap.armed
    assert texts[0].text == "Failsafe activated"
    assert ap.status().system_status == MAV_STATE_CRITICAL
    ap.update(100.0)
    assert ap.mode is mode  # no COM_FAIL_ACT_T stage
    # the setpoints come back: the fallback clears, back to Offboard
    ap.on_setpoint(SETPOINT, 100.5)
    ap.update(100.5)
    assert ap.mode is Mode.OFFBOARD and not ap.failsafe


def test_offboard_loss_terminate_and_disarm(ap):
    """As PX4 v1.16 SITL did (flown, docs/parity/commander.md): Terminate stops the motors and
    stays, armed, in custom main mode 10 with base_mode 129 and status FLIGHT_TERMINATION, on the
    ground too (the plant used to disarm once landed: PX4 does not); Disarm disarms at once, with
    "Disarmed by failsafe", and the heartbeat keeps Offboard's STABILIZE flag (17)."""
    ap.params.set("COM_OBL_RC_ACT", 6)
    _flying_offboard(ap)
    ap.update(1.5)
    assert isinstance(ap.task(), IdleTask) and ap.armed and ap.failsafe  # motors stopped: it falls
    ap.observe(state(0.0))
    ap.update(1.6)
    ap.update(1.6 + ap.params["LNDMC_TRIG_TIME"] + LAND_DETECT_WINDDOWN_S + ap.params["COM_DISARM_LAND"] + 1.0)
    status = ap.status()
    assert ap.armed and status.mode is Mode.TERMINATION and status.mode.custom_mode == 10 << 16
    assert (status.base_mode, status.system_status) == (129, 8)
    ap.on_setpoint(SETPOINT, 20.0)
    assert ap.set_mode(Mode.AUTO_LOITER, 20.0).result == MAV_RESULT_TEMPORARILY_REJECTED
    assert ap.mode is Mode.TERMINATION and isinstance(ap.task(), IdleTask)
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196), 20.0).result == MAV_RESULT_ACCEPTED
    ap.params.set("COM_OBL_RC_ACT", 7)
    ap.observe(state(0.0))
    _flying_offboard(ap)
    texts = ap.update(26.0)
    assert not ap.armed and [t.text for t in texts] == ["Failsafe activated", "Disarmed by failsafe"]
    assert ap.mode is Mode.OFFBOARD and (ap.status().base_mode, ap.status().system_status) == (17, 0)


def test_offboard_loss_stabilized_without_sticks_holds_level_at_hover_thrust(ap):
    """COM_OBL_RC_ACT 2: PX4 v1.16 SITL stayed in Stabilized and sank 0.07 m/s (its attitude
    control of an all-zero manual setpoint: level, MPC_THR_HOVER); Altitude descends at
    MPC_LAND_SPEED as Position does."""
    ap.params.set("COM_OBL_RC_ACT", 2)
    _flying_offboard(ap)
    ap.update(1.5)
    task = ap.task()
    assert ap.mode is Mode.STABILIZED and isinstance(task, OffboardTask)
    assert task.setpoint.q_wxyz == pytest.approx((1.0, 0.0, 0.0, 0.0))
    assert task.setpoint.thrust_norm == ap.params["MPC_THR_HOVER"]
    ap.params.set("COM_OBL_RC_ACT", 1)
    ap.on_setpoint(SETPOINT, 2.0)
    ap.update(2.0)
    ap.update(3.5)
    task = ap.task()
    assert ap.mode is Mode.ALTCTL and isinstance(task, PositionTask) and task.descend_m_s == ap.params["MPC_LAND_SPEED"]


def test_offboard_loss_default_is_position(ap):
    assert ap.params["COM_OBL_RC_ACT"] == 0
    _flying_offboard(ap)
    ap.update(1.5)
    assert ap.mode is Mode.POSCTL and ap.status().base_mode == 209


def test_client_mode_change_ends_failsafe(ap):
    _flying_offboard(ap)
    ap.update(1.5)
    assert ap.failsafe
    ap.on_setpoint(SETPOINT, 2.0)
    assert ap.on_command(offboard_mode(), 2.0).result == MAV_RESULT_ACCEPTED
    assert not ap.failsafe
    land_was_due = 1.5 + ap.params["COM_FAIL_ACT_T"]
    ap.on_setpoint(SETPOINT, land_was_due - 0.1)
    ap.update(land_was_due + 0.1)
    assert ap.mode is Mode.OFFBOARD and not ap.failsafe


def test_takeoff_then_hold(ap):
    reply = ap.on_command(cmd(MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, 488.0 + 4.0), 0.0)
    assert reply.result == MAV_RESULT_ACCEPTED and ap.mode is Mode.AUTO_TAKEOFF
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.update(0.5)
    assert isinstance(ap.task(), IdleTask)  # spooling up for COM_SPOOLUP_TIME
    ap.update(1.0)
    task = ap.task()
    assert isinstance(task, PositionTask) and task.pos_ned_m[2] == pytest.approx(-4.0)
    # PX4's ramp starts at the upward limit that gives no thrust, -g / MPC_Z_VEL_P_ACC
    assert task.max_climb_m_s == pytest.approx(-9.80665 / ap.params["MPC_Z_VEL_P_ACC"])
    ap.update(1.0 + ap.params["MPC_TKO_RAMP_T"] / 2)
    # ... to the climb the takeoff asks for, min(MPC_TKO_SPEED, 0.6 sqrt(4 m to go))
    assert ap.task().max_climb_m_s == pytest.approx((-9.80665 / 4.0 + 1.2) / 2)  # type: ignore[union-attr]
    ap.observe(state(-2.0))
    ap.update(5.0)
    assert ap.mode is Mode.AUTO_TAKEOFF  # 2 m to go: more than NAV_MC_ALT_RAD
    assert ap.task().max_climb_m_s == pytest.approx(min(1.5, 0.6 * math.sqrt(2.0)))  # type: ignore[union-attr]
    ap.observe(state(-3.25))  # within NAV_MC_ALT_RAD (0.8 m): done, Hold at the takeoff height
    texts = ap.update(6.0)
    assert ap.mode is Mode.AUTO_LOITER and texts
    assert ap.task().pos_ned_m[2] == pytest.approx(-4.0)  # type: ignore[union-attr]


def test_takeoff_height_defaults_to_mis_takeoff_alt(ap):
    ap.on_command(cmd(MAV_CMD_NAV_TAKEOFF), 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.update(1.5)
    assert ap.task().pos_ned_m[2] == pytest.approx(-ap.params["MIS_TAKEOFF_ALT"])  # type: ignore[union-attr]


@pytest.mark.parametrize("height, speed", [(30.0, 1.5), (10.0, 1.5), (7.5, 1.1), (5.0, 0.7), (2.0, 0.7), (0.5, 0.3)])
def test_land_speed_profile(ap, height, speed):
    """FlightTaskAuto: MPC_Z_V_AUTO_DN above ALT1 (10 m), linear to MPC_LAND_SPEED at ALT2 (5 m),
    MPC_LAND_CRWL below ALT3 (1 m)."""
    ap.observe(state(-height))
    assert ap.land_speed_m_s() == pytest.approx(speed)


def test_land_command_and_idle_on_the_ground(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-3.0))
    ap.update(0.1)
    assert ap.on_command(cmd(MAV_CMD_NAV_LAND), 0.2).result == MAV_RESULT_ACCEPTED
    assert ap.status().landed_state == 4  # MAV_LANDED_STATE_LANDING
    ap.observe(state(0.0))
    ap.update(0.3)
    detected = 0.3 + ap.params["LNDMC_TRIG_TIME"] + LAND_DETECT_WINDDOWN_S
    ap.update(detected - 0.01)
    assert ap.status().landed_state == 4  # the land detector waits
    texts = ap.update(detected)
    assert isinstance(ap.task(), IdleTask) and [t.text for t in texts] == ["Landing detected"]
    assert ap.status().landed_state == 1  # ON_GROUND
    ap.update(detected + ap.params["COM_DISARM_LAND"])
    assert not ap.armed and ap.mode is Mode.AUTO_LOITER  # back to the last mode that allows arming


def test_after_landing_back_to_the_last_armable_mode(ap):
    ap.on_manual_input(STICKS_CENTRED, 0.0)
    ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 3, 0), 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-3.0))
    ap.update(0.1)
    ap.on_command(cmd(MAV_CMD_NAV_LAND), 0.2)
    ap.observe(state(0.0))
    for t in (0.3, 3.3, 5.3):
        ap.on_manual_input(STICKS_CENTRED, t)
        ap.update(t)
    assert not ap.armed and ap.mode is Mode.POSCTL  # PX4 measured: Position -> Land -> Position


def test_preflight_auto_disarm(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.update(ap.params["COM_DISARM_PRFLT"] - 0.1)
    assert ap.armed
    ap.update(ap.params["COM_DISARM_PRFLT"])
    assert not ap.armed


def test_failure_injection_needs_sys_failure_en(ap):
    assert ap.on_command(cmd(MAV_CMD_INJECT_FAILURE, 0, 1), 0.0).result == MAV_RESULT_DENIED
    ap.params.set("SYS_FAILURE_EN", 1)
    assert ap.on_command(cmd(MAV_CMD_INJECT_FAILURE, 0, 1), 0.0).result == MAV_RESULT_ACCEPTED
    assert "gyro" in ap.failures
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0).result == MAV_RESULT_TEMPORARILY_REJECTED
    ap.on_command(cmd(MAV_CMD_INJECT_FAILURE, 0, 0), 0.0)
    assert ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0).result == MAV_RESULT_ACCEPTED


def test_unknown_command_is_not_the_autopilots(ap):
    assert ap.on_command(cmd(12345), 0.0) is None


def test_unknown_failure_unit_rejected_at_construction():
    with pytest.raises(ValueError, match="failure unit"):
        Autopilot(plant_params(VehicleParams()), failures={"warp-drive"})


@pytest.mark.parametrize("thrust, lands", [(0.5, False), (0.3, False), (0.1, False), (0.085, True), (0.0, True)])
def test_offboard_on_the_ground_lands_only_at_the_thrust_floor(ap, thrust, lands):
    """PX4's land detector where no climb rate is controlled (Offboard attitude): 'maybe landed'
    takes a thrust of at most MPC_MANTHR_MIN + 0.01 (0.09); a client holding about hover thrust
    with the vehicle resting on the ground is neither landed nor disarmed."""
    _flying_offboard(ap)
    setpoint = AttitudeSetpoint(0, (1.0, 0.0, 0.0, 0.0), (None, None, None), thrust)
    ap.observe(state(0.0))  # resting on the ground
    t = 0.5
    while t < 10.0:
        ap.on_setpoint(setpoint, t)
        ap.update(t)
        t += 0.1
    assert ap.armed is not lands  # landed, then disarmed COM_DISARM_LAND later


# --- a GPS lost in flight, as PX4 v1.16 SITL answers it (docs/plant.md; tests/e2e/test_px4_flight.py) ----


def _holding_at_5_m(ap: Autopilot) -> None:
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-5.0))
    ap.update(0.5)
    assert ap.armed and ap.mode is Mode.AUTO_LOITER


def test_a_gps_lost_in_hold_lands_blind_once_ekf2_stops_dead_reckoning(ap):
    _holding_at_5_m(ap)
    ap.inject_failure("gps", 1.0)
    texts = [t for now in np.arange(1.0, 1.0 + DEAD_RECKONING_S - 0.05, 0.1) for t in ap.update(float(now))]
    assert ap.mode is Mode.AUTO_LOITER and ap.status().system_status == MAV_STATE_ACTIVE and not texts  # dead reckoning
    texts = ap.update(1.0 + DEAD_RECKONING_S)
    assert ap.mode is Mode.AUTO_LAND and ap.status().system_status == MAV_STATE_CRITICAL
    assert [t.text for t in texts] == ["Failsafe activated"]
    # Hold needs the position: refused, the vehicle keeps landing (PX4 v1.16, measured)
    assert ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 4, 3), 1.0 + DEAD_RECKONING_S).result == MAV_RESULT_TEMPORARILY_REJECTED
    assert ap.mode is Mode.AUTO_LAND


def test_a_gps_lost_in_offboard_flies_on(ap):
    """PX4 v1.16 keeps an attitude-driven Offboard running without a position estimate."""
    _flying_offboard(ap)
    ap.inject_failure("gps", 1.0)
    for now in np.arange(1.0, 20.0, 0.1):
        ap.on_setpoint(SETPOINT, float(now))
        ap.update(float(now))
    assert ap.mode is Mode.OFFBOARD and ap.status().system_status == MAV_STATE_ACTIVE
    assert ap.status().gps_lost_s == pytest.approx(19.0, abs=0.11)


@pytest.mark.parametrize(
    "on_ground, lost_s, flags",
    [(True, None, 0x3FF), (False, None, 0x37F), (False, DEAD_RECKONING_S - 0.1, 0x37F), (False, DEAD_RECKONING_S, 0x365),
     (False, GPS_DROPPED_S, 0x025), (True, GPS_DROPPED_S, 0x0E5)],
)  # fmt: skip
def test_ekf2s_flags_as_px4_sends_them(on_ground, lost_s, flags):
    """Measured on PX4 v1.16 SITL: 0x3ff on the ground, 0x37f in the air; its GPS stopped in Hold,
    0x365 5.1 s later, 0x025 7.1 s later, 0x0e5 once landed."""
    assert estimator_flags(on_ground, lost_s) == flags


def test_sys_status_drops_a_lost_gps_as_px4_does(ap):
    from pymavlink.dialects.v20 import common as mavlink

    gps, xy = mavlink.MAV_SYS_STATUS_SENSOR_GPS, mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    _holding_at_5_m(ap)
    ap.inject_failure("gps", 1.0)
    for now, present, xy_ok in ((1.5, True, True), (1.0 + DEAD_RECKONING_S, True, False), (1.0 + GPS_DROPPED_S, False, False)):
        ap.update(now)
        msg = sys_status(ap.status())
        assert bool(msg.onboard_control_sensors_present & gps) is present and not msg.onboard_control_sensors_health & gps
        assert bool(msg.onboard_control_sensors_health & xy) is xy_ok
    ap.clear_failure("gps")
    msg = sys_status(ap.status())
    assert ap.status().gps_lost_s is None and msg.onboard_control_sensors_present & msg.onboard_control_sensors_health & gps
