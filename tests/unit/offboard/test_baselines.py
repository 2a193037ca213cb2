"""The baseline controllers: equations, frame signs, hover, step response, and RotorPy's SE3Control."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offboard.baselines import AttitudeTarget, Px4Gains, Px4PositionController, SE3Controller, SE3Gains
from offboard.trajectory.base import Reference
from sitl_plant.dynamics.batch import FastRigidBodySim
from sitl_plant.dynamics.rigid_body import ROTORS, RigidBodyModel, hover_rotor_speed
from offboard.model.rotations import euler_from_quat, quat_from_euler, rotation_matrix
from sitl_plant.inner_loops import Px4Loop
from sitl_plant.params import plant_params
from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams

VEHICLE = VehicleParams()
MASS, INERTIA, G = 0.5, (3.8e-3, 3.8e-3, 7.1e-3), 9.81


def state(pos=(0.0, 0.0, -5.0), vel=(0.0, 0.0, 0.0), euler=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0)) -> VehicleState:
    q = quat_from_euler(*euler)
    return VehicleState(
        time_s=0.0, pos_ned_m=np.array(pos, float), vel_ned_m_s=np.array(vel, float), acc_ned_m_s2=np.zeros(3),
        euler_rad=np.array(euler, float), euler_rate_rad_s=np.array(rates, float),
        body_rate_frd_rad_s=np.array(rates, float), quat_wxyz=q,
    )  # fmt: skip


def make(kind: str) -> SE3Controller | Px4PositionController:
    return SE3Controller(MASS, INERTIA) if kind == "se3" else Px4PositionController(MASS, 0.05)


@pytest.mark.parametrize("kind", ["se3", "px4"])
@pytest.mark.parametrize("yaw", [0.0, 1.2, -2.5])
def test_hover_at_the_reference_asks_for_weight_and_level(kind: str, yaw: float) -> None:
    target = make(kind).target(state(euler=(0.0, 0.0, yaw)), Reference(np.array([0.0, 0.0, -5.0]), yaw_rad=yaw))
    assert target.thrust_n == pytest.approx(MASS * G, rel=1e-12)
    np.testing.assert_allclose(euler_from_quat(np.array(target.quat_wxyz)), [0.0, 0.0, yaw], atol=1e-12)
    np.testing.assert_allclose(target.force_ned_n, [0.0, 0.0, -MASS * G], atol=1e-12)


@pytest.mark.parametrize("kind", ["se3", "px4"])
@pytest.mark.parametrize(
    ("offset_ned", "expect"),
    [
        ((1.0, 0.0, 0.0), "pitch<0"),  # north of us: nose down (FRD pitch negative) to accelerate north
        ((0.0, 1.0, 0.0), "roll>0"),  # east of us: roll right
        ((0.0, 0.0, -1.0), "thrust>mg"),  # above us (down negative): more thrust
        ((0.0, 0.0, 1.0), "thrust<mg"),
    ],
)
def test_frame_signs(kind: str, offset_ned: tuple[float, float, float], expect: str) -> None:
    here = state()
    ref = Reference(here.pos_ned_m + np.array(offset_ned))
    target = make(kind).target(here, ref)
    roll, pitch, _ = euler_from_quat(np.array(target.quat_wxyz))
    checks = {
        "pitch<0": pitch < -0.01 and abs(roll) < 1e-9,
        "roll>0": roll > 0.01 and abs(pitch) < 1e-9,
        "thrust>mg": target.thrust_n > MASS * G + 0.1,
        "thrust<mg": target.thrust_n < MASS * G - 0.1,
    }
    assert checks[expect], (roll, pitch, target.thrust_n)


def test_se3_thrust_is_the_force_along_the_body_axis() -> None:
    """f = -F . R e3 (Lee eq. 15): tilted 30 deg, the thrust is |F| cos 30."""
    ctrl = SE3Controller(MASS, INERTIA)
    target = ctrl.target(state(euler=(math.radians(30), 0.0, 0.0)), Reference(np.array([0.0, 0.0, -5.0])))
    assert target.thrust_n == pytest.approx(MASS * G * math.cos(math.radians(30)), rel=1e-12)


def test_se3_attitude_law_is_lee_eq_16() -> None:
    """M = J(-k_R e_R - k_W e_W) + W x J W, e_R = vee(R_d^T R - R^T R_d)/2, checked with matrices."""
    ctrl = SE3Controller(MASS, INERTIA, SE3Gains(k_r=300.0, k_w=40.0))
    target = AttitudeTarget(6.0, tuple(quat_from_euler(0.1, -0.2, 0.5)), (0.0, 0.0, 0.3), (0.5, -0.4, -6.0))
    q = quat_from_euler(-0.05, 0.12, 0.4)
    w = np.array([0.3, -0.2, 0.1])
    thrust, torque = ctrl.thrust_and_torque(q, w, target)
    r, rd = rotation_matrix(q), rotation_matrix(np.array(target.quat_wxyz))
    s = 0.5 * (rd.T @ r - r.T @ rd)
    e_r = np.array([s[2, 1], s[0, 2], s[1, 0]])
    j = np.diag(INERTIA)
    want = j @ (-300.0 * e_r - 40.0 * (w - np.array([0.0, 0.0, 0.3]))) + np.cross(w, j @ w)
    np.testing.assert_allclose(torque, want, rtol=1e-12, atol=1e-15)
    assert thrust == pytest.approx(-np.array(target.force_ned_n) @ r[:, 2], rel=1e-12)


def test_limits_bound_tilt_and_thrust() -> None:
    far = Reference(np.array([100.0, 0.0, -5.0]))
    se3 = SE3Controller(MASS, INERTIA, thrust_min_n=0.0, thrust_max_n=8.0, tilt_max_rad=math.radians(30))
    px4 = Px4PositionController(MASS, 0.05, Px4Gains(tilt_max_rad=math.radians(30)), thrust_max_n=8.0)
    for ctrl in (se3, px4):
        target = ctrl.target(state(), far)
        roll, pitch, _ = euler_from_quat(np.array(target.quat_wxyz))
        tilt = math.acos(math.cos(roll) * math.cos(pitch))
        assert tilt == pytest.approx(math.radians(30), abs=1e-9)
        assert target.thrust_n <= 8.0


def test_px4_integral_freezes_while_thrust_saturates_and_resets() -> None:
    ctrl = Px4PositionController(MASS, 0.05, thrust_max_n=5.0)
    below = Reference(np.array([0.0, 0.0, -50.0]))  # far above: thrust saturates
    for _ in range(10):
        ctrl.target(state(), below)
    assert ctrl._int == [0.0, 0.0, 0.0]
    ctrl = Px4PositionController(MASS, 0.05)
    for _ in range(10):
        ctrl.target(state(), Reference(np.array([0.0, 0.0, -5.3])))
    assert ctrl._int[2] < 0.0
    ctrl.reset()
    assert ctrl._int == [0.0, 0.0, 0.0]


def _fly(kind: str, reference: Reference, seconds: float) -> np.ndarray:
    """Closed loop at 20 Hz on the rigid body from hover at (0, 0, -5); returns final position."""
    model = RigidBodyModel(VEHICLE)
    sim = FastRigidBodySim(model, initial_pos_ned_m=np.array([0.0, 0.0, -5.0]))
    sim.x[ROTORS] = hover_rotor_speed(VEHICLE)
    if kind == "se3":
        ctrl = SE3Controller(MASS, INERTIA, thrust_min_n=0.0, thrust_max_n=19.6, tilt_max_rad=math.radians(35))
    else:
        ctrl = Px4PositionController(MASS, 0.05, thrust_max_n=19.6)
        loop = Px4Loop(plant_params(VEHICLE), model, 1e-3)
        loop.landed = False
    for _ in range(int(round(seconds / 0.05))):
        target = ctrl.target(sim.truth(), reference)
        if kind == "se3":
            sim.actuation = ctrl.actuation(target)
        else:
            loop.fly_attitude(target.quat_wxyz, target.thrust_n, target.yaw_rate_ff_rad_s)
            sim.actuation = loop
        sim.step(50)
    return sim.truth().pos_ned_m


@pytest.mark.parametrize("kind", ["se3", "px4"])
def test_hover_holds(kind: str) -> None:
    pos = _fly(kind, Reference(np.array([0.0, 0.0, -5.0])), 3.0)
    np.testing.assert_allclose(pos, [0.0, 0.0, -5.0], atol=0.01)


@pytest.mark.parametrize("kind", ["se3", "px4"])
def test_a_step_converges(kind: str) -> None:
    goal = np.array([2.0, -1.0, -6.0])
    pos = _fly(kind, Reference(goal, yaw_rad=0.7), 12.0)
    np.testing.assert_allclose(pos, goal, atol=0.05)


# --- against RotorPy's own SE3Control (NED/FRD <-> ENU/FLU) ----------------------------------

T_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # also ENU -> NED
B_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def test_se3_equals_rotorpy_se3control() -> None:
    rotorpy_control = pytest.importorskip("rotorpy.controllers.quadrotor_control")
    from rotorpy.vehicles.hummingbird_params import quad_params
    from scipy.spatial.transform import Rotation

    params = dict(quad_params, mass=MASS, Ixx=INERTIA[0], Iyy=INERTIA[1], Izz=INERTIA[2])
    theirs = rotorpy_control.SE3Control(params)
    ours = SE3Controller(MASS, INERTIA, SE3Gains(kx=tuple(theirs.kp_pos), kv=tuple(theirs.kd_pos),
                                                 k_r=theirs.kp_att, k_w=theirs.kd_att))  # fmt: skip
    rng = np.random.default_rng(4)
    for _ in range(20):
        euler = rng.uniform(-0.5, 0.5, 3) * np.array([1, 1, 6])
        here = state(pos=rng.normal(size=3), vel=rng.normal(size=3), euler=tuple(euler), rates=tuple(rng.normal(size=3)))
        ref = Reference(rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), float(rng.uniform(-3, 3)), float(rng.normal()))
        target = ours.target(here, ref)
        thrust, torque = ours.thrust_and_torque(here.quat_wxyz, here.body_rate_frd_rad_s, target)
        r_enu_flu = T_NED_ENU @ rotation_matrix(here.quat_wxyz) @ B_FRD_FLU
        out = theirs.update(
            0.0,
            {"x": T_NED_ENU @ here.pos_ned_m, "v": T_NED_ENU @ here.vel_ned_m_s,
             "q": Rotation.from_matrix(r_enu_flu).as_quat(), "w": B_FRD_FLU @ here.body_rate_frd_rad_s},
            {"x": T_NED_ENU @ ref.pos_ned_m, "x_dot": T_NED_ENU @ ref.vel_ned_m_s,
             "x_ddot": T_NED_ENU @ ref.acc_ned_m_s2, "yaw": math.pi / 2 - ref.yaw_rad, "yaw_dot": -ref.yaw_rate_rad_s},
        )  # fmt: skip
        assert thrust == pytest.approx(out["cmd_thrust"], rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(torque, B_FRD_FLU @ out["cmd_moment"], rtol=1e-9, atol=1e-12)
        r_des_theirs = Rotation.from_quat(out["cmd_q"]).as_matrix()
        np.testing.assert_allclose(T_NED_ENU @ r_des_theirs @ B_FRD_FLU, rotation_matrix(np.array(target.quat_wxyz)),
                                   atol=1e-9)  # fmt: skip
