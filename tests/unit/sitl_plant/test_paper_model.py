"""The paper's model: eq. 13-18, the Coriolis term from first principles, and the simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.model import euler_lagrange as el
from sitl_plant.dynamics.integrate import rk4_step, steps_per_period
from sitl_plant.simulation import EulerAccelActuation, HeldActuation, PaperModel, VehicleSim
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

VEHICLE = load_vehicle(PAPER_VEHICLE_FILE)
INERTIA = VEHICLE.inertia_matrix
FORMS = ("castillo", "printed", "zyx")


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("seed", range(10))
def test_coriolis_equals_finite_difference_of_the_lagrangian(form, seed):
    """C eta_dot = d/dt dT/d eta_dot - dT/d eta (eq. 13-14) along a path with eta_ddot = 0."""
    rng = np.random.default_rng(seed)
    eta = rng.uniform(-0.6, 0.6, 3)
    eta_dot = rng.uniform(-3, 3, 3)
    h = 1e-6
    j = lambda e: el.generalized_inertia(e, INERTIA, form)  # noqa: E731
    d_dt = (j(eta + h * eta_dot) - j(eta - h * eta_dot)) @ eta_dot / (2 * h)
    grad = np.array(
        [
            (el.rotational_lagrangian(eta + h * e, eta_dot, INERTIA, form)
             - el.rotational_lagrangian(eta - h * e, eta_dot, INERTIA, form)) / (2 * h)
            for e in np.eye(3)
        ]
    )
    assert_allclose(el.coriolis_vector(eta, eta_dot, INERTIA, form), d_dt - grad, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("form", FORMS)
def test_eq16_cancels_the_dynamics_of_eq13(form):
    """tau = C eta_dot + J tau~ (eq. 16) gives eta_ddot = tau~ (eq. 17)."""
    rng = np.random.default_rng(1)
    for _ in range(50):
        eta, eta_dot, tau_tilde = rng.uniform(-0.7, 0.7, 3), rng.uniform(-5, 5, 3), rng.uniform(-50, 50, 3)
        tau = el.real_torques(eta, eta_dot, tau_tilde, INERTIA, form)
        assert_allclose(el.euler_acceleration(eta, eta_dot, tau, INERTIA, form), tau_tilde, rtol=1e-9, atol=1e-9)


def test_printed_eq4_is_singular_at_psi_pi_over_4_and_castillo_is_not():
    eta = np.array([0.0, 0.2, math.pi / 4])
    assert abs(np.linalg.det(el.euler_rate_matrix(eta, "printed"))) < 1e-12
    assert np.linalg.det(el.euler_rate_matrix(eta, "castillo")) == pytest.approx(math.cos(0.2))
    # a milli-newton-metre asks for an unbounded acceleration there
    blown = el.euler_acceleration(eta, np.zeros(3), np.ones(3) * 1e-3, INERTIA, "printed")
    assert np.max(np.abs(blown)) > 1e8
    sane = el.euler_acceleration(eta, np.zeros(3), np.ones(3) * 1e-3, INERTIA, "castillo")
    assert np.max(np.abs(sane)) < 1.0


def test_torque_free_rotation_conserves_kinetic_energy():
    model = PaperModel(VEHICLE)
    x = np.zeros(12)
    x[[6, 8, 10]] = [0.2, -0.3, 0.5]
    x[[7, 9, 11]] = [1.5, -2.0, 3.0]
    energy0 = el.rotational_lagrangian(x[[6, 8, 10]], x[[7, 9, 11]], INERTIA)
    for _ in range(2000):
        x = rk4_step(lambda s: model.derivative(s, 0.0, np.zeros(3), np.zeros(3)), x, 1e-4)
    energy = el.rotational_lagrangian(x[[6, 8, 10]], x[[7, 9, 11]], INERTIA)
    assert energy == pytest.approx(energy0, rel=1e-7)
    assert not np.allclose(x[[7, 9, 11]], [1.5, -2.0, 3.0])  # the rates did change (Coriolis at work)


def test_hover_holds_with_u_equal_m_g():
    sim = VehicleSim(PaperModel(VEHICLE), initial_pos_ned_m=np.array([0.0, 0.0, -5.0]))
    sim.actuation = HeldActuation(VEHICLE.mass_kg * VEHICLE.gravity_m_s2, np.zeros(3))
    sim.step(2000)
    assert_allclose(sim.truth().pos_ned_m, [0.0, 0.0, -5.0], atol=1e-12)


@pytest.mark.parametrize(
    "angles, direction",
    [((0.0, 0.1), np.array([-1.0, 0.0])), ((0.1, 0.0), np.array([0.0, 1.0]))],
    ids=["positive pitch -> south", "positive roll -> east"],
)
def test_frame_signs_at_zero_yaw(angles, direction):
    """Positive pitch accelerates towards -x (south in NED), positive roll towards +y (east)."""
    model = PaperModel(VEHICLE)
    x = model.initial_state(np.array([0.0, 0.0, -10.0]), 0.0)
    x[6], x[8] = angles
    xdot = model.derivative(x, VEHICLE.mass_kg * VEHICLE.gravity_m_s2, np.zeros(3), np.zeros(3))
    state = model.vehicle_state(x, 0.0, xdot)
    horizontal = state.acc_ned_m_s2[:2]
    assert horizontal @ direction > 0.5
    assert abs(horizontal @ np.array([direction[1], -direction[0]])) < 1e-12


def test_paper_model_ignores_yaw_in_translation():
    """Eq. 18: thrust does not turn with psi; the same pitch at psi = 90 deg still goes south."""
    model = PaperModel(VEHICLE)
    x = model.initial_state(np.array([0.0, 0.0, -10.0]), math.pi / 2)
    x[8] = 0.1
    xdot = model.derivative(x, 5.0, np.zeros(3), np.zeros(3))
    assert xdot[1] < 0 and xdot[3] == 0


def test_inner_loop_makes_euler_accelerations_equal_tau_tilde():
    sim = VehicleSim(PaperModel(VEHICLE), initial_pos_ned_m=np.array([0.0, 0.0, -10.0]), ground=False)
    tau_tilde = np.array([2.0, -1.0, 3.0])
    sim.actuation = EulerAccelActuation(VEHICLE.mass_kg * 9.81, tau_tilde, INERTIA, "castillo")
    sim.step(100)
    t = sim.time_s
    # eq. 16 is evaluated once per physics step (1 ms) and held over it: exact to O(dt)
    assert_allclose(sim.truth().euler_rate_rad_s, tau_tilde * t, rtol=1e-3)
    assert_allclose(sim.truth().euler_rad, 0.5 * tau_tilde * t**2, rtol=1e-3)


def test_believed_inertia_error_is_felt_by_the_inner_loop():
    """Table II: the autopilot's inertia differs from the vehicle's, so eta_ddot != tau~."""
    sim = VehicleSim(PaperModel(VEHICLE), initial_pos_ned_m=np.array([0.0, 0.0, -10.0]), ground=False)
    believed = np.diag([2.7e-3, 4.8e-3, 8.9e-3])
    sim.actuation = EulerAccelActuation(5.0, np.array([1.0, 1.0, 1.0]), believed, "castillo")
    sim.step(10)
    rates = sim.truth().euler_rate_rad_s / sim.time_s
    assert_allclose(rates, [2.7 / 3.8, 4.8 / 3.8, 8.9 / 7.1], rtol=1e-3)


def test_ground_is_a_contact_not_a_floor_to_fall_through():
    sim = VehicleSim(PaperModel(VEHICLE))
    sim.step(500)  # no thrust, on the ground
    state = sim.truth()
    assert state.pos_ned_m[2] == 0.0 and state.on_ground
    sim.actuation = HeldActuation(2 * VEHICLE.mass_kg * VEHICLE.gravity_m_s2, np.zeros(3))
    sim.step(100)
    assert sim.truth().pos_ned_m[2] < 0 and not sim.truth().on_ground


def test_control_period_must_be_an_integer_multiple_of_the_physics_step():
    assert steps_per_period(0.05, 0.001) == 50
    with pytest.raises(ValueError, match="integer multiple"):
        steps_per_period(0.05, 0.003)
