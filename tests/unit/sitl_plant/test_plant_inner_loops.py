"""The plant's inner loops flying the simulated vehicle, driven through ``Plant.handle`` with
real pymavlink messages (no sockets): hover, tilt directions, actuator path, the paper's loop
against the in-process reproduction, the built-in position modes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant.autopilot import LAND_DETECT_WINDDOWN_S, Autopilot, Mode
from offboard.model.rotations import quat_from_euler
from sitl_plant.params import plant_params
from sitl_plant.server import API, Plant, PlantConfig
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

NAN = math.nan
_SENDER = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
_PARSER = mavlink.MAVLink(None)


def wire(msg):
    return _PARSER.parse_buffer(msg.pack(_SENDER))[0]


def make_plant(model="rigid-body", inner_loop="px4", period_s=0.02, vehicle=None, seed=0) -> Plant:
    vehicle = vehicle or load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    params.set("MPC_TKO_SPEED", 3.0)  # quicker take-offs keep the tests short
    config = PlantConfig(model=model, inner_loop=inner_loop, lockstep=True, lockstep_period_s=period_s, seed=seed)
    return Plant(config, vehicle, params, Autopilot(params, home_alt_amsl_m=config.home.alt_m))


def command(plant: Plant, number: int, *params: float) -> int:
    p = list(params) + [NAN] * (7 - len(params))
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, number, 0, *p)))
    acks = [m for m in plant.outbox[API] if m.get_type() == "COMMAND_ACK" and m.command == number]
    plant.outbox[API].clear()
    return acks[-1].result


def attitude_target(plant: Plant, roll=0.0, pitch=0.0, yaw=0.0, thrust=0.25, mask=0b00000111, rates=(0.0, 0.0, 0.0)):
    q = quat_from_euler(roll, pitch, yaw)
    msg = mavlink.MAVLink_set_attitude_target_message(plant.time_ms, 1, 1, mask, q, rates[0], rates[1], rates[2], thrust)
    plant.handle(API, wire(msg))


def hover_thrust(plant: Plant) -> float:
    return plant.vehicle.mass_kg * plant.vehicle.gravity_m_s2 / plant.params["SIM_THR_MAX"]


def run(plant: Plant, seconds: float, each=None) -> None:
    for _ in range(int(round(seconds / (plant.tick_steps * plant.dt_us * 1e-6)))):
        if each is not None:
            each()
        plant.advance(plant.tick_steps)


def take_off_and_switch_to_offboard(plant: Plant, height_m: float = 3.0) -> None:
    """Take off in AUTO_TAKEOFF (no spool-up, no ramp: these tests are about the loops), settle in
    Hold, then enter Offboard at rest."""
    plant.params.set("COM_SPOOLUP_TIME", 0.0)
    plant.params.set("MPC_TKO_RAMP_T", 0.0)
    plant.params.set("NAV_MC_ALT_RAD", 0.1)
    assert command(plant, mavlink.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, plant.config.home.alt_m + height_m) == 0
    assert command(plant, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    for _ in range(12):
        run(plant, 0.5)
        if plant.autopilot.mode is Mode.AUTO_LOITER:
            break
    run(plant, 0.5)
    assert plant.autopilot.mode is Mode.AUTO_LOITER
    assert plant.sim.truth().pos_ned_m[2] == pytest.approx(-height_m, abs=0.15)
    attitude_target(plant, thrust=hover_thrust(plant))
    assert command(plant, mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0) == 0
    assert plant.autopilot.mode is Mode.OFFBOARD


LOOPS = [("rigid-body", "px4"), ("paper", "px4"), ("paper", "paper"), ("rigid-body", "paper")]


@pytest.mark.parametrize(("model", "loop"), LOOPS)
def test_hover_thrust_holds_altitude(model, loop):
    plant = make_plant(model, loop)
    take_off_and_switch_to_offboard(plant)
    start = plant.sim.truth().pos_ned_m.copy()
    run(plant, 3.0, lambda: attitude_target(plant, thrust=hover_thrust(plant)))
    end = plant.sim.truth()
    assert plant.autopilot.mode is Mode.OFFBOARD
    assert abs(end.pos_ned_m[2] - start[2]) < 0.3
    assert np.max(np.abs(end.euler_rad[:2])) < 0.02


@pytest.mark.parametrize(("model", "loop"), LOOPS)
@pytest.mark.parametrize(("roll", "pitch", "axis", "sign"), [(0.0, 0.1, 0, -1), (0.1, 0.0, 1, +1)])
def test_tilt_moves_the_right_way(model, loop, roll, pitch, axis, sign):
    """Positive pitch (nose up) accelerates towards -north; positive roll towards +east."""
    plant = make_plant(model, loop)
    take_off_and_switch_to_offboard(plant)
    start = plant.sim.truth().pos_ned_m.copy()
    thrust = hover_thrust(plant) / (math.cos(roll) * math.cos(pitch))
    run(plant, 2.0, lambda: attitude_target(plant, roll=roll, pitch=pitch, thrust=thrust))
    end = plant.sim.truth()
    moved = end.pos_ned_m - start
    assert sign * moved[axis] > 0.5
    assert abs(moved[1 - axis]) < 0.2 * abs(moved[axis])
    assert abs(moved[2]) < 0.5
    np.testing.assert_allclose(end.euler_rad[:2], [roll, pitch], atol=0.02)


def test_body_rate_setpoint_turns_the_vehicle():
    plant = make_plant("rigid-body", "px4")
    take_off_and_switch_to_offboard(plant)
    run(plant, 1.0, lambda: attitude_target(plant, thrust=hover_thrust(plant), mask=0b10000000, rates=(0.0, 0.0, 0.5)))
    st = plant.sim.truth()
    assert st.body_rate_frd_rad_s[2] == pytest.approx(0.5, abs=0.05)
    assert st.euler_rad[2] > 0.3


@pytest.mark.parametrize("model", ["rigid-body", "paper"])
def test_actuator_setpoints_are_flown(model):
    plant = make_plant(model)
    take_off_and_switch_to_offboard(plant)
    z0 = plant.sim.truth().pos_ned_m[2]
    hover = hover_thrust(plant)

    def actuators(pitch_torque: float) -> None:
        msg = mavlink.MAVLink_set_actuator_control_target_message(plant.time_us, 0, 1, 1, [0.0, pitch_torque, 0.0, hover, 0, 0, 0, 0])
        plant.handle(API, wire(msg))

    run(plant, 0.5, lambda: actuators(0.0))
    st = plant.sim.truth()
    assert abs(st.pos_ned_m[2] - z0) < 0.05  # hover thrust through the direct path
    run(plant, 0.1, lambda: actuators(0.01))
    st = plant.sim.truth()
    # a held pitch torque of 0.01 * SIM_TQ_RP_MAX for 0.1 s: theta ~ tau t^2 / (2 Iyy), the rigid
    # body's rotors reaching it one motor time constant late
    lag = plant.vehicle.motor_time_constant_s if model == "rigid-body" else 0.0
    expected = 0.01 * plant.params["SIM_TQ_RP_MAX"] * (0.1 - lag) ** 2 / (2 * plant.vehicle.inertia_kg_m2[1])
    assert st.euler_rad[1] == pytest.approx(expected, rel=0.2)


def test_setpoints_outside_offboard_do_not_move_the_vehicle():
    plant = make_plant()
    assert command(plant, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
    run(plant, 1.0, lambda: attitude_target(plant, thrust=1.0))
    assert plant.sim.truth().pos_ned_m[2] == 0.0


def test_nan_setpoint_is_refused_and_the_vehicle_keeps_flying():
    plant = make_plant()
    take_off_and_switch_to_offboard(plant)
    run(plant, 0.5, lambda: attitude_target(plant, thrust=hover_thrust(plant)))
    before = plant.sim.truth()
    run(plant, 0.5, lambda: attitude_target(plant, thrust=NAN))
    after = plant.sim.truth()
    assert plant.counters.refused_setpoints == 25
    assert abs(after.pos_ned_m[2] - before.pos_ned_m[2]) < 0.05
    assert np.all(np.isfinite(plant.sim.x))


@pytest.mark.parametrize("model", ["rigid-body", "paper"])
def test_hold_at_a_heading(model):
    """The position modes hold at any yaw, also on the paper model whose eq. 18 ignores yaw."""
    plant = make_plant(model)
    take_off_and_switch_to_offboard(plant)
    run(plant, 3.0, lambda: attitude_target(plant, yaw=math.pi / 2, thrust=hover_thrust(plant)))
    assert command(plant, mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 3) == 0
    hold = plant.sim.truth().pos_ned_m.copy()
    run(plant, 6.0)
    st = plant.sim.truth()
    assert np.linalg.norm(st.pos_ned_m - hold) < 0.3
    assert st.euler_rad[2] == pytest.approx(math.pi / 2, abs=0.1)


def test_land_then_auto_disarm():
    plant = make_plant()
    take_off_and_switch_to_offboard(plant, 2.0)
    assert command(plant, mavlink.MAV_CMD_NAV_LAND) == 0
    run(plant, 1.0 / plant.params["MPC_LAND_SPEED"] + 1.0 / plant.params["MPC_LAND_CRWL"] + 1.0
        + plant.params["LNDMC_TRIG_TIME"] + LAND_DETECT_WINDDOWN_S + plant.params["COM_DISARM_LAND"])
    assert plant.sim.on_ground and not plant.autopilot.armed


def test_changing_the_mass_rebuilds_the_vehicle_only_when_disarmed():
    plant = make_plant()

    def set_mass(value: float) -> float:
        plant.handle(API, wire(mavlink.MAVLink_param_set_message(1, 1, b"SIM_MASS", value, mavlink.MAV_PARAM_TYPE_REAL32)))
        answers = [m for m in plant.outbox[API] if m.get_type() == "PARAM_VALUE"]
        plant.outbox[API].clear()
        return answers[-1].param_value

    assert set_mass(0.6) == pytest.approx(0.6)
    assert plant.sim.model.params.mass_kg == pytest.approx(0.6)
    command(plant, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert set_mass(0.7) == pytest.approx(0.6)  # refused while armed: the old value comes back
    assert plant.sim.model.params.mass_kg == pytest.approx(0.6)


def test_paper_loop_reproduces_the_in_process_law():
    """The paper's law flown through SET_ATTITUDE_TARGET and ``--inner-loop paper`` (lockstep at
    To) follows the in-process reproduction (offboard.inprocess, drive ``inner-loop``)."""
    from offboard.controller import RosalesController
    from offboard.controller.params import PAPER_CONTROLLER_FILE, load_controller
    from offboard.frames import paper_state, tracking_reference
    from offboard.model.euler_lagrange import body_rates_from_euler_rates
    from offboard.model.euler_lagrange import euler_rates_from_body_rates
    from offboard.inprocess import Scenario, run_scenario
    from offboard.trajectory.analytic import Line

    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    ctrl = load_controller(PAPER_CONTROLLER_FILE)
    trajectory = Line((0.0, 0.0, 0.0), (1.0, 0.5, -2.0), 0.5, yaw_rad=0.3)
    duration = 4.0
    reference = run_scenario(Scenario("line", trajectory, vehicle, ctrl, model="paper", drive="inner-loop", duration_s=duration))
    thr_max = vehicle.max_thrust_n
    assert reference.status.name == "COMPLETE"
    assert 0.0 < np.min(reference["thrust_n"]) and np.max(reference["thrust_n"]) < thr_max  # no clipping in this flight

    plant = make_plant("paper", "paper", period_s=ctrl.sample_time_s, vehicle=vehicle)
    plant.autopilot.arm(0.0, forced=True)
    controller = RosalesController(ctrl)
    to = ctrl.sample_time_s
    positions = []
    for n in range(int(round(duration / to)) + 1):
        t = n * to
        measured = plant.sim.truth()
        positions.append(measured.pos_ned_m.copy())
        eta_dot = euler_rates_from_body_rates(measured.euler_rad, measured.body_rate_frd_rad_s, ctrl.euler_rate_form)
        x = paper_state(measured.pos_ned_m, measured.vel_ned_m_s, measured.euler_rad, eta_dot)
        out = controller.step(x, tracking_reference(trajectory.reference(t)), tracking_reference(trajectory.reference(t + to)))
        omega_ref = body_rates_from_euler_rates(measured.euler_rad, np.array(out.law.euler_rate_ref_rad_s), ctrl.euler_rate_form)
        msg = mavlink.MAVLink_set_attitude_target_message(
            plant.time_ms, 1, 1, 0b10000000, (1, 0, 0, 0), *omega_ref, out.law.thrust_n / plant.params["SIM_THR_MAX"]
        )
        plant.handle(API, wire(msg))
        if n == 0:
            assert command(plant, mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0) == 0
            plant.handle(API, wire(msg))  # fly the first sample's setpoint now that we are in Offboard
        if n < int(round(duration / to)):
            plant.advance(plant.tick_steps)
    positions = np.array(positions)
    # float32 on the wire is the only difference
    np.testing.assert_allclose(positions, reference["pos_ned_m"][: len(positions)], atol=1e-5)
    assert np.linalg.norm(positions[-1] - positions[0]) > 1.0


@pytest.mark.slow
@pytest.mark.parametrize("model", ["rigid-body", "paper"])
def test_offboard_position_and_velocity_setpoints(model):
    plant = make_plant(model)
    take_off_and_switch_to_offboard(plant)

    def position(x=0.0, y=0.0, z=0.0, yaw=0.0, mask=0b0000_1001_1111_1000, vel=(0.0, 0.0, 0.0)):
        msg = mavlink.MAVLink_set_position_target_local_ned_message(plant.time_ms, 1, 1, 1, mask, x, y, z, *vel, 0, 0, 0, yaw, 0)
        plant.handle(API, wire(msg))

    run(plant, 6.0, lambda: position(2.0, -1.0, -4.0, 0.5))
    st = plant.sim.truth()
    np.testing.assert_allclose(st.pos_ned_m, [2.0, -1.0, -4.0], atol=0.15)
    assert st.euler_rad[2] == pytest.approx(0.5, abs=0.05)
    # velocity only (MAVSDK set_velocity_ned), keeping the heading
    start = st.pos_ned_m.copy()
    run(plant, 3.0, lambda: position(mask=0b0000_1101_1100_0111, vel=(0.0, 1.0, 0.0)))
    st = plant.sim.truth()
    assert st.vel_ned_m_s[1] == pytest.approx(1.0, abs=0.15)
    assert st.pos_ned_m[1] - start[1] > 2.0


def _reported(plant: Plant) -> tuple[np.ndarray, np.ndarray]:
    """LOCAL_POSITION_NED's position and velocity as the plant sends them now."""
    (msg,) = [m for m in plant.telemetry(API, force=(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,)) if m.get_type() == "LOCAL_POSITION_NED"]
    return np.array([msg.x, msg.y, msg.z]), np.array([msg.vx, msg.vy, msg.vz])


def test_a_lost_gps_dead_reckons_the_reported_position_away_from_the_truth():
    """Without its GPS PX4's EKF2 integrates the accelerometer alone: its position ran 21 m from
    SIH's truth in 10 s (docs/plant.md). The plant's report drifts by 1/2 b t^2 (b = SIM_DR_ACC_ERR,
    horizontal, in a seeded direction), its velocity by b t, the height not at all, while the
    vehicle itself holds; the GPS back, the report is the truth again."""
    plant = make_plant()
    take_off_and_switch_to_offboard(plant)
    b = plant.params["SIM_DR_ACC_ERR"]
    assert b == pytest.approx(0.4)
    plant.params.set("SYS_FAILURE_EN", 1)
    each = lambda: attitude_target(plant, thrust=hover_thrust(plant))  # noqa: E731
    run(plant, 1.0, each)
    assert np.allclose(_reported(plant)[0], plant.sim.truth().pos_ned_m, atol=1e-3)
    assert command(plant, mavlink.MAV_CMD_INJECT_FAILURE, 4, 1) == mavlink.MAV_RESULT_ACCEPTED
    lost_at = plant.time_s
    run(plant, 10.0, each)
    t = plant.time_s - lost_at
    pos, vel = _reported(plant)
    truth = plant.sim.truth()
    drift, speed = pos - truth.pos_ned_m, vel - truth.vel_ned_m_s
    assert np.hypot(drift[0], drift[1]) == pytest.approx(0.5 * b * t * t, rel=1e-6)  # 20 m in 10 s
    assert np.hypot(speed[0], speed[1]) == pytest.approx(b * t, rel=1e-6)
    assert drift[2] == pytest.approx(0.0, abs=1e-9) and speed[2] == pytest.approx(0.0, abs=1e-9)
    assert math.atan2(speed[1], speed[0]) == pytest.approx(math.atan2(drift[1], drift[0]))  # one direction
    assert np.hypot(truth.pos_ned_m[0], truth.pos_ned_m[1]) < 0.5  # the vehicle held where it was
    assert plant.autopilot.mode is Mode.OFFBOARD
    assert command(plant, mavlink.MAV_CMD_INJECT_FAILURE, 4, 0) == mavlink.MAV_RESULT_ACCEPTED
    run(plant, 0.1, each)
    assert np.allclose(_reported(plant)[0], plant.sim.truth().pos_ned_m, atol=1e-3)


def test_the_dead_reckoning_error_is_drawn_from_the_seed_runs_on_after_landing_and_is_off_at_zero():
    def drift(seed: int, b: float | None = None, land: bool = False) -> np.ndarray:
        plant = make_plant(seed=seed)
        take_off_and_switch_to_offboard(plant)
        if b is not None:
            plant.params.set("SIM_DR_ACC_ERR", b)
        plant.params.set("SYS_FAILURE_EN", 1)
        assert command(plant, mavlink.MAV_CMD_INJECT_FAILURE, 4, 1) == mavlink.MAV_RESULT_ACCEPTED
        run(plant, 2.0, lambda: attitude_target(plant, thrust=hover_thrust(plant)))
        if land:  # landed, the estimate runs on (PX4 v1.16 SIH's did: docs/plant.md)
            assert command(plant, mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED
            for _ in range(40):
                run(plant, 0.5)
                if plant.sim.on_ground:
                    break
            assert plant.sim.on_ground
            before = _reported(plant)[0] - plant.sim.truth().pos_ned_m
            run(plant, 2.0)
            after = _reported(plant)[0] - plant.sim.truth().pos_ned_m
            assert np.hypot(*after[:2]) > np.hypot(*before[:2]) + 2.0  # at the vehicle at rest, b t of velocity error
            assert np.hypot(*_reported(plant)[1][:2]) > 1.0 and np.allclose(plant.sim.truth().vel_ned_m_s, 0.0, atol=1e-6)
            return after
        return _reported(plant)[0] - plant.sim.truth().pos_ned_m

    assert np.array_equal(drift(3), drift(3))
    assert not np.allclose(drift(3), drift(4))
    assert np.hypot(*drift(3)[:2]) == pytest.approx(0.5 * 0.4 * 2.0**2, rel=1e-6)
    assert np.array_equal(drift(3, b=0.0), np.zeros(3))
    assert np.hypot(*drift(3, land=True)[:2]) > 5.0


def test_the_truth_is_sent_on_request_as_px4_sitl_sends_simulator_truth():
    """HIL_STATE_QUATERNION: off until asked for (as PX4 SITL), then the simulator's truth, not the
    estimate (here 20 m away, dead-reckoned), with PX4's quirks: time_usec 0, whole m/s^2."""
    from sitl_plant.codec import ned_to_geodetic

    plant = make_plant()
    take_off_and_switch_to_offboard(plant)
    hil = mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION
    each = lambda: attitude_target(plant, thrust=hover_thrust(plant))  # noqa: E731
    run(plant, 1.0, each)
    assert all(m.get_type() != "HIL_STATE_QUATERNION" for m in plant.telemetry(API))
    assert command(plant, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, hil, 20000) == mavlink.MAV_RESULT_ACCEPTED
    plant.params.set("SYS_FAILURE_EN", 1)
    assert command(plant, mavlink.MAV_CMD_INJECT_FAILURE, 4, 1) == mavlink.MAV_RESULT_ACCEPTED
    run(plant, 10.0, each)
    sent = {m.get_type(): m for m in plant.telemetry(API, force=(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, hil))}
    truth, msg = plant.sim.truth(), sent["HIL_STATE_QUATERNION"]
    lat, lon, alt = ned_to_geodetic(truth.pos_ned_m, plant.config.home)
    assert abs(msg.lat - lat * 1e7) <= 1 and abs(msg.lon - lon * 1e7) <= 1 and abs(msg.alt - alt * 1000.0) <= 1
    assert msg.time_usec == 0 and msg.ind_airspeed == 0 and msg.true_airspeed == 0
    assert list(msg.attitude_quaternion) == pytest.approx(list(truth.quat_wxyz), abs=1e-6)
    assert (msg.vx, msg.vy, msg.vz) == pytest.approx(tuple(100.0 * truth.vel_ned_m_s), abs=1.0)
    assert msg.zacc == math.trunc(float(truth.acc_ned_m_s2[2]))
    estimate = sent["LOCAL_POSITION_NED"]
    assert math.hypot(estimate.x - truth.pos_ned_m[0], estimate.y - truth.pos_ned_m[1]) > 15.0


@pytest.mark.parametrize("gps", ["lost", "kept"])
def test_a_landing_without_a_position_is_blind_and_coasts_on_the_drag(gps):
    """PX4 v1.16 SIH, its GPS stopped, handed to Land by ``offboard fly`` at 1.24 m/s: with the
    horizontal velocity estimate gone it does not brake, it levels and descends; SIH's drag
    (1 N s/m on 1 kg) slowed it to 0.5 m/s in about 1 s (docs/plant.md). The plant's Land, the
    estimator no longer vouching for the position, takes no horizontal acceleration either and
    coasts on the same drag; with the GPS it brakes to the point it landed for."""
    from offboard.model.vehicle import PX4_SIH_VEHICLE_FILE

    plant = make_plant(vehicle=load_vehicle(PX4_SIH_VEHICLE_FILE))
    take_off_and_switch_to_offboard(plant)
    plant.params.set("SYS_FAILURE_EN", 1)
    tilt = lambda: attitude_target(plant, pitch=-0.12, thrust=hover_thrust(plant) / math.cos(0.12))  # noqa: E731  (nose down: north)
    if gps == "lost":
        assert command(plant, mavlink.MAV_CMD_INJECT_FAILURE, 4, 1) == mavlink.MAV_RESULT_ACCEPTED
    run(plant, 5.5, tilt)  # past EKF2's 5 s of dead reckoning
    speed0 = math.hypot(*plant.sim.truth().vel_ned_m_s[:2])
    assert speed0 > 1.0
    assert command(plant, mavlink.MAV_CMD_NAV_LAND) == mavlink.MAV_RESULT_ACCEPTED
    run(plant, 1.0)
    speed1 = math.hypot(*plant.sim.truth().vel_ned_m_s[:2])
    truth = plant.sim.truth()
    tilt_deg = math.degrees(math.acos(math.cos(truth.euler_rad[0]) * math.cos(truth.euler_rad[1])))
    if gps == "lost":
        assert plant.autopilot.mode is Mode.AUTO_LAND and not plant.autopilot.position_valid(plant.time_s)
        assert speed1 == pytest.approx(speed0 * math.exp(-1.0), rel=0.15)  # drag alone: d/m = 1 /s
        assert tilt_deg < 1.0  # level
    else:
        assert speed1 < 0.3 * speed0 and tilt_deg > 1.0  # braking


def test_attitude_target_is_stamped_when_the_setpoint_was_taken_as_px4_stamps_it():
    """PX4's ATTITUDE_TARGET carries vehicle_attitude_setpoint's own timestamp (its
    ATTITUDE_TARGET.hpp), which in offboard its MAVLink receiver sets on each SET_ATTITUDE_TARGET,
    and the quaternion float for float: a client pairs its setpoints with the echo and reads when
    the vehicle took each (offboard.echo; PX4 SITL: 4 ms median after the ATTITUDE
    answered, tests/e2e/test_px4_flight.py). Outside offboard attitude it is the position mode's
    setpoint of the tick."""
    plant = make_plant()
    target = mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET
    echo = lambda: {m.get_type(): m for m in plant.telemetry(API, force=(target,))}["ATTITUDE_TARGET"]  # noqa: E731
    assert echo().time_boot_ms == plant.time_ms  # in Hold, on the ground: the mode's own, now
    take_off_and_switch_to_offboard(plant)
    run(plant, 0.5, lambda: attitude_target(plant, roll=0.05, thrust=hover_thrust(plant)))
    taken_ms = plant.time_ms
    attitude_target(plant, roll=0.1, thrust=hover_thrust(plant))
    sent_q = [float(np.float32(v)) for v in quat_from_euler(0.1, 0.0, 0.0)]
    run(plant, 0.1)  # no newer setpoint: the echo keeps the time it was taken
    msg = echo()
    assert plant.time_ms >= taken_ms + 100 and msg.time_boot_ms == taken_ms
    assert list(msg.q) == sent_q
