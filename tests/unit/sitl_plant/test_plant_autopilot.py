"""The autopilot state machine, driven by hand (no simulation, no sockets)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl_plant.autopilot import (
    FORCE_MAGIC,
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
    ActuatorSetpoint,
    AttitudeSetpoint,
    Autopilot,
    Command,
    IdleTask,
    Mode,
    OffboardTask,
    PositionTask,
)
from sitl_plant.params import OBL_ACT_HOLD, plant_params
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


def test_offboard_needs_recent_setpoints(ap):
    assert ap.on_command(offboard_mode(), 0.0).result == MAV_RESULT_TEMPORARILY_REJECTED
    assert ap.mode is Mode.AUTO_LOITER
    ap.on_setpoint(SETPOINT, 1.0)
    # too old: more than COM_OF_LOSS_T (1 s) ago
    assert ap.on_command(offboard_mode(), 2.5).result == MAV_RESULT_TEMPORARILY_REJECTED
    ap.on_setpoint(SETPOINT, 3.0)
    assert ap.on_command(offboard_mode(), 3.5).result == MAV_RESULT_ACCEPTED
    assert ap.mode is Mode.OFFBOARD


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
    ap.on_setpoint(tick, 0.0)
    assert ap.on_command(offboard_mode(), 0.1).result == MAV_RESULT_TEMPORARILY_REJECTED


def test_manual_modes_refused_without_rc(ap):
    for main in (1, 2, 3, 5, 7):
        reply = ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, main, 0), 0.0)
        assert reply.result == MAV_RESULT_TEMPORARILY_REJECTED
    assert ap.mode is Mode.AUTO_LOITER
    assert ap.on_command(cmd(MAV_CMD_DO_SET_MODE, 1, 42, 0), 0.0).result == MAV_RESULT_DENIED


def _flying_offboard(ap: Autopilot) -> None:
    ap.on_setpoint(SETPOINT, 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.on_command(offboard_mode(), 0.0)
    ap.observe(state(-5.0))
    ap.update(0.5)
    assert ap.mode is Mode.OFFBOARD


def test_failsafe_hold_then_land(ap):
    _flying_offboard(ap)
    assert ap.update(1.0) == []  # last setpoint exactly COM_OF_LOSS_T old: still fine
    texts = ap.update(1.01)
    assert ap.mode is Mode.AUTO_LOITER and ap.failsafe
    assert ap.status().system_status == MAV_STATE_CRITICAL
    assert "Failsafe" in texts[0].text
    task = ap.task()
    assert isinstance(task, PositionTask) and task.pos_ned_m == (1.0, 2.0, -5.0) and task.descend_m_s is None
    ap.update(1.01 + ap.params["COM_FAIL_ACT_T"] - 0.05)
    assert ap.mode is Mode.AUTO_LOITER
    texts = ap.update(1.01 + ap.params["COM_FAIL_ACT_T"])
    assert ap.mode is Mode.AUTO_LAND and "landing" in texts[0].text
    assert isinstance(ap.task(), PositionTask) and ap.task().descend_m_s > 0  # type: ignore[union-attr]
    # touchdown, then auto-disarm after COM_DISARM_LAND
    ap.observe(state(0.0))
    ap.update(10.0)
    assert ap.armed
    ap.update(10.0 + ap.params["COM_DISARM_LAND"])
    assert not ap.armed and not ap.failsafe


def test_failsafe_hold_only(ap):
    ap.params.set("COM_OBL_RC_ACT", OBL_ACT_HOLD)
    _flying_offboard(ap)
    ap.update(1.5)
    ap.update(100.0)
    assert ap.mode is Mode.AUTO_LOITER and ap.failsafe and ap.armed


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
    task = ap.task()
    assert isinstance(task, PositionTask) and task.pos_ned_m[2] == pytest.approx(-4.0) and task.max_climb_m_s > 0
    ap.observe(state(-2.0))
    ap.update(1.0)
    assert ap.mode is Mode.AUTO_TAKEOFF
    ap.observe(state(-3.95))
    texts = ap.update(2.0)
    assert ap.mode is Mode.AUTO_LOITER and texts
    assert ap.task().pos_ned_m[2] == pytest.approx(-4.0)  # type: ignore[union-attr]


def test_takeoff_height_defaults_to_mis_takeoff_alt(ap):
    ap.on_command(cmd(MAV_CMD_NAV_TAKEOFF), 0.0)
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    assert ap.task().pos_ned_m[2] == pytest.approx(-ap.params["MIS_TAKEOFF_ALT"])  # type: ignore[union-attr]


def test_land_command_and_idle_on_the_ground(ap):
    ap.on_command(cmd(MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0)
    ap.observe(state(-3.0))
    ap.update(0.1)
    assert ap.on_command(cmd(MAV_CMD_NAV_LAND), 0.2).result == MAV_RESULT_ACCEPTED
    assert ap.status().landed_state == 4  # MAV_LANDED_STATE_LANDING
    ap.observe(state(0.0))
    ap.update(0.3)
    assert isinstance(ap.task(), IdleTask)
    assert ap.status().landed_state == 1  # ON_GROUND


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
