"""The controller interface's contract, over every controller and every trajectory class.

As RotorPy's tests/test_controllers.py does for its controllers: each controller is built the
one way (``offboard.controllers.make_controller``), stepped through the one interface
(``step(state, ref_n, ref_n1) -> Command``, NED in) and flown by the one simulation loop
(``offboard.inprocess.simulate``).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from offboard.controller import PAPER_CONTROLLER_FILE, ActionLimits, load_controller
from offboard.controller.command import Command, Controller, MissingCommand
from offboard.controller.tuning import design_for_vehicle, tuned_params, vehicle_values
from offboard.controllers import CONTROLLER_KINDS, make_controller
from offboard.inprocess import Drive, simulate, vehicle_loop
from offboard.missions import MISSIONS_DIR, load_mission
from offboard.record import FlightStatus
from offboard.trajectory import Helix, Hold, Line, Lissajous, Polygon, Sequence, VerticalMove, Waypoint, WaypointLegs
from offboard.trajectory.base import Reference
from offboard.trajectory.shifted import ShiftedTrajectory, shift_trajectory
from sitl_plant.params import plant_params
from offboard.model.state import VehicleState
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

VEHICLE = load_vehicle(PAPER_VEHICLE_FILE)
G = 9.81


def belief():
    """What every controller believes here: the paper's vehicle, PX4-like limits, Table I's gains."""
    return load_controller(PAPER_CONTROLLER_FILE).with_changes(
        mass_kg=VEHICLE.mass_kg, inertia_kg_m2=VEHICLE.inertia_kg_m2, euler_rate_form="zyx", yaw_aware=True,
        limits=ActionLimits(thrust_min_n=0.0, thrust_max_n=19.6, tilt_max_rad=math.radians(35.0)),
    )  # fmt: skip


@functools.cache
def designed():
    """The design takes a second: once for the module (ControllerParams is frozen)."""
    table = plant_params(VEHICLE)
    values = vehicle_values({name: table[name] for name in table})
    params = belief()
    return tuned_params(params, design_for_vehicle(values, sample_time_s=params.sample_time_s), values)


#: Every controller the project has, as the interface builds them (the law with Table I's and
#: with designed gains).
CONTROLLERS = {
    "paper": lambda: make_controller("paper", belief()),
    "paper-designed": lambda: make_controller("paper", designed()),
    "se3": lambda: make_controller("se3", belief()),
    "px4": lambda: make_controller("px4", belief()),
}


def hovering_state(pos=(1.0, -2.0, -5.0), yaw=0.3) -> VehicleState:
    from offboard.model.rotations import quat_from_euler

    return VehicleState(0.0, np.array(pos), np.zeros(3), np.zeros(3), np.array([0.0, 0.0, yaw]), np.zeros(3),
                        np.zeros(3), quat_from_euler(0.0, 0.0, yaw))  # fmt: skip


def test_every_kind_is_covered():
    assert set(CONTROLLER_KINDS) == {name.split("-")[0] for name in CONTROLLERS}
    assert isinstance(TRAJECTORIES["ShiftedTrajectory"](), ShiftedTrajectory)


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_a_controller_is_the_interface(name):
    controller = CONTROLLERS[name]()
    assert isinstance(controller, Controller)
    assert controller.name in CONTROLLER_KINDS and controller.sample_time_s == pytest.approx(0.05)


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_at_the_reference_it_asks_for_hover(name):
    """At rest on the reference: thrust m g, level, the reference's heading, every number finite."""
    controller = CONTROLLERS[name]()
    state = hovering_state()
    ref = Reference(state.pos_ned_m.copy(), yaw_rad=0.3)
    for _ in range(3):
        command = controller.step(state, ref, ref)
    assert isinstance(command, Command) and command.is_finite()
    assert command.thrust_n == pytest.approx(VEHICLE.mass_kg * G, rel=1e-6)
    roll, pitch, yaw = command.attitude_ref_euler_rad
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9 and yaw == pytest.approx(0.3)
    q = np.array(command.attitude_wxyz)
    assert np.linalg.norm(q) == pytest.approx(1.0) and abs(q[1]) < 1e-9 and abs(q[2]) < 1e-9


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_a_position_error_tilts_the_thrust_towards_the_reference(name):
    """5 m north of the reference: the thrust axis leans south (NED: the body z axis's north part
    is positive when the thrust, along -z, points south)."""
    from offboard.model.rotations import rotation_matrix

    controller = CONTROLLERS[name]()
    state = hovering_state(pos=(5.0, 0.0, -5.0), yaw=0.0)
    ref = Reference(np.array([0.0, 0.0, -5.0]))
    command = controller.step(state, ref, ref)
    body_z = rotation_matrix(np.array(command.attitude_wxyz))[:, 2]
    assert body_z[0] > 0.05 and abs(body_z[1]) < 1e-9


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_reset_forgets_everything(name):
    controller = CONTROLLERS[name]()
    state = hovering_state(pos=(0.5, 0.2, -4.0))
    ref = Reference(np.array([0.0, 0.0, -5.0]), vel_ned_m_s=np.array([1.0, 0.0, 0.0]))
    first = controller.step(state, ref, ref)
    for _ in range(5):
        controller.step(hovering_state(pos=(2.0, -1.0, -3.0)), ref, ref)
    controller.reset()
    again = controller.step(state, ref, ref)
    assert dataclasses.replace(again, law=None) == dataclasses.replace(first, law=None)
    if first.law is not None:
        assert again.law.law == first.law.law and np.array_equal(again.law.rotor_forces_n, first.law.rotor_forces_n)


def test_the_forms_each_controller_gives():
    state, ref = hovering_state(), Reference(np.array([0.0, 0.0, -5.0]))
    paper = CONTROLLERS["paper"]().step(state, ref, ref)
    assert None not in (paper.body_rate_frd_rad_s, paper.torque_nm, paper.euler_accel_rad_s2, paper.generalized_torque_nm)
    assert paper.law is not None and paper.thrust_n == paper.law.thrust_n
    se3 = CONTROLLERS["se3"]().step(state, ref, ref)
    assert se3.torque_nm is not None and se3.body_rate_frd_rad_s is None and se3.euler_accel_rad_s2 is None
    px4 = CONTROLLERS["px4"]().step(state, ref, ref)
    assert px4.torque_nm is None and px4.body_rate_frd_rad_s is None


def test_a_drive_the_controller_cannot_feed_is_refused_by_name():
    with pytest.raises(ValueError, match="the se3 controller gives no tau~"):
        vehicle_loop(Drive.INNER_LOOP, CONTROLLERS["se3"](), VEHICLE)
    with pytest.raises(ValueError, match="the px4 controller has no attitude law of its own"):
        vehicle_loop(Drive.ATTITUDE_LAW, CONTROLLERS["px4"](), VEHICLE)
    loop = vehicle_loop(Drive.HELD_TORQUE, CONTROLLERS["px4"](), VEHICLE)
    command = CONTROLLERS["px4"]().step(hovering_state(), Reference(np.zeros(3)), Reference(np.zeros(3)))
    with pytest.raises(MissingCommand, match="px4 controller gives no eq. 16 torque command"):
        loop.actuation(command, None)  # type: ignore[arg-type]


def test_baselines_fly_rigid_bodies_only():
    with pytest.raises(ValueError, match="the se3 controller flies a rigid body"):
        make_controller("se3", belief(), vehicle_model="paper")
    with pytest.raises(ValueError, match="controller must be one of"):
        make_controller("pid", belief())


#: One instance of every trajectory class, each starting at 5 m up (NED down -5).
TRAJECTORIES = {
    "Hold": lambda: Hold((0.0, 0.0, -5.0), 0.3, 2.0),
    "Line": lambda: Line((0.0, 0.0, -5.0), (2.0, 1.0, -6.0), 1.0),
    "Helix": lambda: Helix((0.0, 0.0, -5.0), 1.0, 0.5, 0.2, 3.0, yaw_mode="along-path"),
    "Lissajous": lambda: Lissajous((0.0, 0.0, -5.0), (2.0, 1.0, 0.0), (0.4, 0.8, 0.0), (0.0, 0.0, 0.0), 3.0),
    "Polygon": lambda: Polygon([(0.0, 0.0, -5.0), (2.0, 0.0, -5.0), (2.0, 2.0, -5.0)], 1.0),
    "WaypointLegs": lambda: WaypointLegs((0.0, 0.0, -5.0), [Waypoint((2.0, 0.0, -5.0)), Waypoint((2.0, 1.0, -4.0))], 1.0, 1.0),
    "VerticalMove": lambda: VerticalMove((0.0, 0.0, -5.0), -6.0, 0.5, 1.0),
    "Sequence": lambda: Sequence([Hold((0.0, 0.0, -5.0), 0.0, 1.0), Line((0.0, 0.0, -5.0), (1.0, 0.0, -5.0), 1.0)]),
    "ShiftedTrajectory": lambda: shift_trajectory(Line((0.0, 0.0, -5.0), (1.0, 0.0, -5.0), 0.5), (3.0, -2.0, 0.0)),
}


@pytest.mark.parametrize("trajectory", sorted(TRAJECTORIES))
@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_every_controller_flies_every_trajectory_class(name, trajectory):
    """Through PX4's attitude loop (the drive every controller can feed), from the start at rest."""
    path = TRAJECTORIES[trajectory]()
    start = path.reference(0.0)
    result = simulate(VEHICLE, CONTROLLERS[name](), path, drive=Drive.PX4, duration_s=min(path.duration_s, 3.0),
                      initial_pos_ned_m=start.pos_ned_m, initial_yaw_rad=start.yaw_rad, hovering=True, fast=True)  # fmt: skip
    record = result.record
    assert result.status is FlightStatus.COMPLETE, record.status_detail
    assert len(record) == round(min(path.duration_s, 3.0) / 0.05) + 1
    error = np.linalg.norm(record.error_ned_m, axis=1)
    assert np.all(np.isfinite(error)) and float(np.max(error)) < 1.5
    assert record.meta["controller"] == CONTROLLERS[name]().name and len(result.step_cost_s) == len(record)


@pytest.mark.parametrize("mission", ["paper-helix.toml", "paper-square.toml", "figure-eight.toml", "px4-sitl-box.waypoints"])
def test_the_loop_flies_every_controller_on_the_bundled_missions(mission):
    """A second the same for all: the helix's first 2 s through PX4's attitude loop, each tracks."""
    trajectory = load_mission(MISSIONS_DIR / mission).trajectory
    start = trajectory.reference(0.0)
    for name in sorted(CONTROLLERS):
        result = simulate(VEHICLE, CONTROLLERS[name](), trajectory, drive=Drive.PX4, duration_s=2.0,
                          initial_pos_ned_m=start.pos_ned_m, initial_yaw_rad=start.yaw_rad, hovering=True, fast=True)  # fmt: skip
        assert result.status is FlightStatus.COMPLETE, f"{name}: {result.record.status_detail}"
