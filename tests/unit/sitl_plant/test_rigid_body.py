"""The rigid-body quadrotor (Newton-Euler, NED/FRD), its mixer and its VehicleSim adapter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from sitl_plant.dynamics import rigid_body as rb
from offboard.model.euler_lagrange import (
    body_torque_from_generalized,
    euler_rate_matrix,
    euler_rates_from_body_rates,
    zyx_body_torque_from_generalized,
    zyx_euler_rates_from_body_rates,
)
from sitl_plant.dynamics.integrate import rk4_step
from offboard.model.rotations import euler_from_quat, quat_from_euler, rotation_matrix
from sitl_plant.simulation import EulerAccelActuation, HeldActuation, VehicleSim
from offboard.model.vehicle import PAPER_VEHICLE_FILE, VehicleParams, load_vehicle

PAPER = load_vehicle(PAPER_VEHICLE_FILE)
WEIGHT_N = PAPER.mass_kg * PAPER.gravity_m_s2
NO_WIND = np.zeros(3)


def state(
    params: VehicleParams = PAPER,
    pos=(0.0, 0.0, -10.0),
    euler=(0.0, 0.0, 0.0),
    rates=(0.0, 0.0, 0.0),
    rotors: float | None = None,
) -> np.ndarray:
    x = np.zeros(rb.STATE_SIZE)
    x[rb.POS] = pos
    x[rb.QUAT] = quat_from_euler(*euler)
    x[rb.RATES] = rates
    x[rb.ROTORS] = rb.hover_rotor_speed(params) if rotors is None else rotors
    return x


def flying_sim(params: VehicleParams = PAPER, x0: np.ndarray | None = None, **kwargs) -> VehicleSim:
    sim = VehicleSim(rb.RigidBodyModel(params), ground=False, **kwargs)
    sim.x = state(params) if x0 is None else x0
    return sim


# --- hover and frame signs ------------------------------------------------------------------


def test_hover_rotor_speed_is_sqrt_mg_over_4k() -> None:
    expected = math.sqrt(0.5 * 9.81 / (4 * 1.0e-5))
    assert rb.hover_rotor_speed(PAPER) == pytest.approx(expected)
    assert_allclose(rb.rotor_speeds_for(WEIGHT_N, np.zeros(3), PAPER), np.full(4, expected), rtol=1e-12)


@pytest.mark.parametrize("yaw_rad", [0.0, 1.0, -2.5])
def test_hover_holds(yaw_rad: float) -> None:
    x0 = state(euler=(0.0, 0.0, yaw_rad))
    sim = flying_sim(x0=x0)
    sim.actuation = HeldActuation(WEIGHT_N, np.zeros(3))
    sim.step(3000)
    truth = sim.truth()
    assert_allclose(truth.pos_ned_m, [0.0, 0.0, -10.0], atol=1e-9)
    assert_allclose(truth.vel_ned_m_s, 0.0, atol=1e-9)
    assert_allclose(truth.euler_rad, [0.0, 0.0, yaw_rad], atol=1e-12)
    assert_allclose(truth.motor_speeds_rad_s, rb.hover_rotor_speed(PAPER), rtol=1e-12)


def test_more_thrust_climbs_less_thrust_sinks() -> None:
    for factor, sign in ((1.1, -1.0), (0.9, 1.0)):
        sim = flying_sim()
        sim.actuation = HeldActuation(factor * WEIGHT_N, np.zeros(3))
        sim.step(500)
        assert sign * sim.truth().vel_ned_m_s[2] > 0.01


@pytest.mark.parametrize(
    ("euler", "direction"),
    [
        ((0.0, 0.1, 0.0), (-1.0, 0.0)),  # pitch up at yaw 0: towards -north (south)
        ((0.1, 0.0, 0.0), (0.0, 1.0)),  # roll right at yaw 0: towards +east
        ((0.0, 0.1, math.pi / 2), (0.0, -1.0)),  # pitch up heading east: towards -east (west)
        ((0.1, 0.0, math.pi / 2), (-1.0, 0.0)),  # roll right heading east: towards south
        ((0.0, 0.1, math.pi), (1.0, 0.0)),  # pitch up heading south: towards north
    ],
)
def test_tilt_accelerates_the_way_the_thrust_points(euler, direction) -> None:
    x = state(euler=euler)
    xdot = rb.derivative(x, x[rb.ROTORS], NO_WIND, PAPER)
    horizontal = xdot[3:5]
    tilt = max(abs(euler[0]), abs(euler[1]))
    assert_allclose(horizontal, np.array(direction) * PAPER.gravity_m_s2 * math.sin(tilt), atol=1e-12)


@pytest.mark.parametrize(
    ("torque", "axis", "sign"),
    [((0.0, 0.01, 0.0), 0, -1.0), ((0.01, 0.0, 0.0), 1, 1.0)],
)
def test_positive_pitch_and_roll_torque_move_south_and_east(torque, axis, sign) -> None:
    sim = flying_sim()
    sim.actuation = HeldActuation(WEIGHT_N, np.array(torque))
    sim.step(400)
    truth = sim.truth()
    assert sign * truth.vel_ned_m_s[axis] > 0.01
    # only a trace sideways: the lagging rotor pair's sum of f = k w^2 dips, a tiny yaw torque
    assert abs(truth.vel_ned_m_s[1 - axis]) < 1e-4 * abs(truth.vel_ned_m_s[axis])


def test_positive_yaw_torque_turns_clockwise_seen_from_above() -> None:
    sim = flying_sim()
    sim.actuation = HeldActuation(WEIGHT_N, np.array([0.0, 0.0, 0.002]))
    sim.step(300)
    assert sim.truth().euler_rad[2] > 0.01  # NED yaw grows: north towards east


# --- rotational dynamics ------------------------------------------------------------------------


def test_torque_free_body_conserves_energy_and_angular_momentum() -> None:
    params = PAPER.with_changes(inertia_kg_m2=(3.0e-3, 4.5e-3, 7.1e-3))
    inertia = np.array(params.inertia_kg_m2)
    x = state(params, euler=(0.3, -0.2, 1.0), rates=(3.0, -2.0, 5.0), rotors=0.0)
    cmd = np.zeros(4)

    def invariants(x: np.ndarray) -> tuple[float, np.ndarray]:
        omega = x[rb.RATES]
        return 0.5 * float(omega @ (inertia * omega)), rotation_matrix(x[rb.QUAT]) @ (inertia * omega)

    energy0, momentum0 = invariants(x)
    for _ in range(4000):
        x = rk4_step(lambda s: rb.derivative(s, cmd, NO_WIND, params), x, 1e-3)
    energy, momentum = invariants(x)
    assert not np.allclose(x[rb.RATES], [3.0, -2.0, 5.0], atol=0.1)  # the body really tumbles
    assert energy == pytest.approx(energy0, rel=1e-8)
    assert_allclose(momentum, momentum0, rtol=0, atol=1e-8 * np.linalg.norm(momentum0))
    assert np.linalg.norm(x[rb.QUAT]) == pytest.approx(1.0, abs=1e-9)


def test_euler_accelerations_equal_tau_tilde_through_the_generalized_torque() -> None:
    """eq. 16-17 on the rigid body: tau_body = W_zyx^-T (C eta_dot + J tau_tilde) gives eta_ddot = tau_tilde."""
    params = PAPER.with_changes(motor_time_constant_s=0.0, rotor_speed_max_rad_s=2000.0)
    model = rb.RigidBodyModel(params)
    eta0 = np.array([0.2, -0.1, 0.5])
    eta_dot0 = np.array([0.5, -0.3, 0.8])
    x0 = state(params, euler=eta0, rates=euler_rate_matrix(eta0, "zyx") @ eta_dot0)
    tau_tilde = np.array([1.0, -0.5, 0.7])
    sim = flying_sim(params, x0=x0, physics_dt_s=1e-4)
    sim.actuation = EulerAccelActuation(WEIGHT_N, tau_tilde, params.inertia_matrix, form="zyx")
    sim.step(2000)
    t = sim.time_s
    eta, eta_dot = model.euler(sim.x)
    assert_allclose(eta_dot, eta_dot0 + tau_tilde * t, atol=2e-4)
    assert_allclose(eta, eta0 + eta_dot0 * t + 0.5 * tau_tilde * t * t, atol=2e-5)


def test_generalized_torque_is_the_transpose_map() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        eta = rng.uniform([-1.0, -1.2, -3.0], [1.0, 1.2, 3.0])
        tau = rng.normal(size=3)
        body = zyx_body_torque_from_generalized(eta, tau)
        assert_allclose(euler_rate_matrix(eta, "zyx").T @ body, tau, atol=1e-12)
        omega = rng.normal(size=3)
        assert_allclose(euler_rate_matrix(eta, "zyx") @ zyx_euler_rates_from_body_rates(eta, omega), omega, atol=1e-12)



def test_the_zyx_closed_forms_are_the_general_maps_with_the_zyx_form() -> None:
    """The physics step's closed forms and the controller's W_eta solve are one map for form "zyx"."""
    rng = np.random.default_rng(2)
    for _ in range(200):
        eta = rng.uniform([-1.5, -1.5, -3.0], [1.5, 1.5, 3.0])
        v = rng.normal(size=3) * 3.0
        assert_allclose(zyx_euler_rates_from_body_rates(eta, v), euler_rates_from_body_rates(eta, v, "zyx"), rtol=1e-12, atol=1e-12)
        assert_allclose(zyx_body_torque_from_generalized(eta, v), body_torque_from_generalized(v, eta, "zyx"), rtol=1e-12, atol=1e-12)


# --- motors -----------------------------------------------------------------------------------


def test_motor_lag_reaches_63_percent_at_the_time_constant() -> None:
    tau = PAPER.motor_time_constant_s
    x = state(rotors=0.0)
    cmd = np.full(4, 400.0)
    dt = tau / 200
    for _ in range(200):
        x = rk4_step(lambda s: rb.derivative(s, cmd, NO_WIND, PAPER), x, dt)
    assert_allclose(x[rb.ROTORS], 400.0 * (1.0 - math.exp(-1.0)), rtol=1e-8)


def test_motor_commands_are_clipped_to_the_speed_limits() -> None:
    params = PAPER.with_changes(rotor_speed_min_rad_s=100.0)
    x = state(params, rotors=300.0)
    xdot = rb.derivative(x, np.array([1000.0, 50.0, 300.0, 700.0]), NO_WIND, params)
    assert_allclose(xdot[rb.ROTORS], (np.array([700.0, 100.0, 300.0, 700.0]) - 300.0) / params.motor_time_constant_s)


def test_instant_motors_take_thrust_from_the_command() -> None:
    params = PAPER.with_changes(motor_time_constant_s=0.0)
    x = state(params, rotors=0.0)
    xdot = rb.derivative(x, np.full(4, rb.hover_rotor_speed(params)), NO_WIND, params)
    assert_allclose(xdot[3:6], 0.0, atol=1e-12)
    assert_allclose(xdot[rb.ROTORS], 0.0)


# --- eq. 9-11 and the mixer -------------------------------------------------------------------


def test_rotor_forces_and_their_inverse_are_eq_9_to_11() -> None:
    arm, drag = PAPER.arm_length_m, PAPER.drag_to_thrust_m
    forces = np.array([1.0, 2.0, 3.5, 0.5])
    thrust, torque = rb.thrust_torque_from_rotor_forces(forces, arm, drag)
    assert thrust == pytest.approx(7.0)
    assert_allclose(torque, [(3.5 - 1.0) * arm, (2.0 - 0.5) * arm, drag * (2.0 + 0.5 - 1.0 - 3.5)])
    rng = np.random.default_rng(2)
    for _ in range(50):
        u, tau = rng.uniform(-5, 20), rng.normal(scale=0.5, size=3)
        back = rb.thrust_torque_from_rotor_forces(rb.rotor_forces(u, tau, arm, drag), arm, drag)
        assert back[0] == pytest.approx(u)
        assert_allclose(back[1], tau, atol=1e-12)


def test_mixer_is_exact_when_feasible() -> None:
    rng = np.random.default_rng(3)
    for _ in range(100):
        wanted = rng.uniform(0.01, 0.99, size=4) * PAPER.max_rotor_thrust_n
        u, tau = rb.thrust_torque_from_rotor_forces(wanted, PAPER.arm_length_m, PAPER.drag_to_thrust_m)
        forces = rb.mix_rotor_forces(u, tau, PAPER)
        assert_allclose(forces, wanted, atol=1e-12)
        speeds = rb.rotor_speeds_for(u, tau, PAPER)
        assert_allclose(PAPER.thrust_coeff_n_s2 * speeds**2, forces, rtol=1e-12)


F_MAX = PAPER.max_rotor_thrust_n
ARM, DRAG = PAPER.arm_length_m, PAPER.drag_to_thrust_m


def mixed(u: float, tau) -> tuple[np.ndarray, float, np.ndarray]:
    forces = rb.mix_rotor_forces(u, np.array(tau, dtype=float), PAPER)
    return (forces, *rb.thrust_torque_from_rotor_forces(forces, ARM, DRAG))


def test_mixer_scales_roll_and_pitch_together_when_a_pair_cannot_give_them() -> None:
    forces, thrust, torque = mixed(2.0 * F_MAX, [3.0 * ARM * F_MAX, 1.5 * ARM * F_MAX, 0.0])
    assert torque[0] == pytest.approx(ARM * F_MAX)  # a full pair: one rotor off, one at full speed
    assert torque[1] / torque[0] == pytest.approx(0.5)  # the direction of the tilt torque is kept
    assert thrust == pytest.approx(2.0 * F_MAX)


def test_mixer_lowers_thrust_for_roll_pitch_at_the_top() -> None:
    tau = [0.5 * ARM * F_MAX, 0.0, 0.0]
    forces, thrust, torque = mixed(3.8 * F_MAX, tau)
    assert_allclose(torque, tau, atol=1e-12)
    assert max(forces) == pytest.approx(F_MAX)
    assert thrust < 3.8 * F_MAX


def test_mixer_never_raises_thrust_airmode_off() -> None:
    forces, thrust, torque = mixed(0.4 * F_MAX, [0.5 * ARM * F_MAX, 0.0, 0.01])
    assert thrust == pytest.approx(0.4 * F_MAX)
    assert torque[0] == pytest.approx(ARM * 0.2 * F_MAX)  # the pair's rotor at zero: the most there is
    assert min(forces) == pytest.approx(0.0, abs=1e-12)
    assert torque[2] == pytest.approx(0.0, abs=1e-12)  # no room left for yaw at that end


def test_mixer_gives_yaw_only_the_room_left() -> None:
    hover = WEIGHT_N / 4
    tau = [0.02, 0.0, 10.0 * DRAG * hover]
    forces, thrust, torque = mixed(WEIGHT_N, tau)
    assert thrust == pytest.approx(WEIGHT_N)
    assert_allclose(torque[:2], tau[:2], atol=1e-12)
    assert 0 < torque[2] < tau[2]
    assert min(forces) == pytest.approx(0.0, abs=1e-12)


def test_mixer_negative_thrust_gives_idle() -> None:
    params = PAPER.with_changes(rotor_speed_min_rad_s=100.0)
    forces = rb.mix_rotor_forces(-50.0, np.array([0.3, -0.2, 0.1]), params)
    assert_allclose(forces, params.thrust_coeff_n_s2 * 100.0**2)


def test_mixer_uses_the_requested_yaw_to_reach_a_roll_torque() -> None:
    """A request that is feasible only thanks to its yaw part is met exactly (PX4's would cut roll)."""
    wanted = np.array([4.55, 2.63, 0.09, 0.36])
    u, tau = rb.thrust_torque_from_rotor_forces(wanted, ARM, DRAG)
    assert_allclose(rb.mix_rotor_forces(u, tau, PAPER), wanted, atol=1e-12)


@pytest.mark.parametrize("thrust_factor", [0.3, 1.0, 3.5])
def test_mixer_forces_vary_continuously_across_saturation(thrust_factor: float) -> None:
    step = 1e-3 * ARM * F_MAX
    previous = None
    for roll in np.arange(0.0, 3.0 * ARM * F_MAX, step):
        forces = rb.mix_rotor_forces(thrust_factor * F_MAX, np.array([roll, 0.4 * roll, 0.05 * roll]), PAPER)
        if previous is not None:
            assert np.max(np.abs(forces - previous)) < 5.0 * step / ARM
        previous = forces


def test_mixer_respects_its_priorities() -> None:
    rng = np.random.default_rng(6)
    for _ in range(300):
        u = rng.uniform(0.0, 25.0)
        tau = rng.normal(scale=[1.0, 1.0, 0.1])
        _, thrust, torque = mixed(u, tau)
        assert thrust <= max(u, 0.0) + 1e-9  # never raised (airmode off)
        assert torque[0] * tau[1] == pytest.approx(torque[1] * tau[0], abs=1e-12)  # tilt direction kept
        assert abs(torque[0]) <= abs(tau[0]) + 1e-12
        assert -1e-12 <= torque[2] * np.sign(tau[2]) <= abs(tau[2]) + 1e-12  # yaw reduced, never reversed


def test_mixer_output_is_always_within_limits() -> None:
    params = PAPER.with_changes(rotor_speed_min_rad_s=80.0)
    f_min, f_max = params.thrust_coeff_n_s2 * 80.0**2, params.max_rotor_thrust_n
    rng = np.random.default_rng(4)
    for _ in range(500):
        u = rng.uniform(-10, 30)
        tau = rng.normal(scale=[1.0, 1.0, 0.1])
        speeds = rb.rotor_speeds_for(u, tau, params)
        assert np.all(speeds >= 80.0 - 1e-9) and np.all(speeds <= 700.0 + 1e-9)
        forces = rb.mix_rotor_forces(u, tau, params)
        assert np.all(forces >= f_min - 1e-12) and np.all(forces <= f_max + 1e-12)


# --- ground contact -------------------------------------------------------------------------


def ground_sim(**kwargs) -> VehicleSim:
    return VehicleSim(rb.RigidBodyModel(PAPER), ground=True, **kwargs)


@pytest.mark.parametrize("thrust_factor", [0.0, 0.9])
def test_vehicle_resting_on_the_ground_stays(thrust_factor: float) -> None:
    sim = ground_sim(initial_yaw_rad=0.7)
    sim.actuation = HeldActuation(thrust_factor * WEIGHT_N, np.zeros(3))
    sim.step(1000)
    truth = sim.truth()
    assert truth.on_ground
    assert_allclose(truth.pos_ned_m, 0.0, atol=0.0)
    assert_allclose(truth.vel_ned_m_s, 0.0, atol=0.0)
    assert_allclose(truth.euler_rad, [0.0, 0.0, 0.7], atol=1e-12)


def test_vehicle_lifts_off_with_thrust_above_weight() -> None:
    sim = ground_sim()
    sim.actuation = HeldActuation(1.2 * WEIGHT_N, np.zeros(3))
    sim.step(1000)
    truth = sim.truth()
    assert not truth.on_ground
    assert truth.pos_ned_m[2] < -0.5 * 0.15 * PAPER.gravity_m_s2  # a climb near 0.2 g, less motor lag
    assert truth.vel_ned_m_s[2] < 0.0


def test_landing_does_not_go_through_the_floor() -> None:
    sim = ground_sim(initial_pos_ned_m=np.array([1.0, 2.0, -2.0]), initial_yaw_rad=-1.0)
    sim.x[rb.QUAT] = quat_from_euler(0.2, -0.1, -1.0)
    sim.x[rb.VEL] = [1.0, 0.0, 0.0]
    sim.actuation = HeldActuation(0.0, np.zeros(3))
    lowest = -2.0
    for _ in range(1000):
        sim.step()
        lowest = max(lowest, sim.x[2])
        if sim.on_ground:
            break
    assert sim.on_ground
    assert lowest == 0.0
    sim.step(200)
    truth = sim.truth()
    assert truth.pos_ned_m[2] == 0.0
    assert_allclose(truth.vel_ned_m_s, 0.0, atol=0.0)
    assert_allclose(truth.euler_rad[:2], 0.0, atol=1e-12)  # levelled on touchdown
    assert truth.euler_rad[2] == pytest.approx(-1.0, abs=1e-9)  # heading kept


# --- the adapter --------------------------------------------------------------------------------


def test_vehicle_state_is_consistent_with_the_state_vector() -> None:
    model = rb.RigidBodyModel(PAPER)
    eta = np.array([0.3, -0.4, 2.0])
    x = state(pos=(1.0, 2.0, -3.0), euler=eta, rates=(0.2, -0.5, 1.0), rotors=333.0)
    x[rb.VEL] = [0.5, -0.5, 0.1]
    xdot = model.derivative(x, WEIGHT_N, np.zeros(3), NO_WIND)
    vs = model.vehicle_state(x, 1.5, xdot)
    assert vs.time_s == 1.5
    assert_allclose(vs.pos_ned_m, [1.0, 2.0, -3.0])
    assert_allclose(vs.vel_ned_m_s, [0.5, -0.5, 0.1])
    assert_allclose(vs.acc_ned_m_s2, xdot[rb.VEL])
    assert_allclose(vs.euler_rad, eta, atol=1e-12)
    assert_allclose(euler_rate_matrix(vs.euler_rad, "zyx") @ vs.euler_rate_rad_s, [0.2, -0.5, 1.0], atol=1e-12)
    assert_allclose(vs.motor_speeds_rad_s, 333.0)
    assert_allclose(euler_from_quat(vs.quat_wxyz), eta, atol=1e-12)


def test_initial_state_is_level_at_rest_with_rotors_stopped() -> None:
    x = rb.RigidBodyModel(PAPER).initial_state(np.array([1.0, -2.0, -3.0]), 0.4)
    assert x.shape == (rb.STATE_SIZE,)
    assert_allclose(x[rb.POS], [1.0, -2.0, -3.0])
    assert_allclose(euler_from_quat(x[rb.QUAT]), [0.0, 0.0, 0.4], atol=1e-12)
    assert_allclose(np.concatenate([x[rb.VEL], x[rb.RATES], x[rb.ROTORS]]), 0.0)


def test_batched_derivative_equals_one_vehicle_at_a_time() -> None:
    params = PAPER.with_changes(linear_drag_n_s_m=(0.1, 0.2, 0.3))
    rng = np.random.default_rng(5)
    xs = np.stack([state(params, pos=rng.normal(size=3), euler=rng.normal(size=3), rates=rng.normal(size=3),
                         rotors=rng.uniform(0, 700)) for _ in range(6)])  # fmt: skip
    xs[:, rb.VEL] = rng.normal(size=(6, 3))
    cmds = rng.uniform(-100, 900, size=(6, 4))
    winds = rng.normal(size=(6, 3))
    batched = rb.derivative(xs, cmds, winds, params)
    for i in range(6):
        assert_allclose(batched[i], rb.derivative(xs[i], cmds[i], winds[i], params), rtol=1e-13, atol=1e-13)


def test_linear_drag_opposes_air_relative_velocity_in_body_axes() -> None:
    params = PAPER.with_changes(linear_drag_n_s_m=(0.2, 0.4, 0.6))
    x = state(params, euler=(0.0, 0.0, math.pi / 2))  # nose east: body x = east, body y = south
    x[rb.VEL] = [1.0, 1.0, 0.0]
    wind = np.array([0.0, 3.0, 0.0])  # air-relative velocity: 1 north, -2 east
    xdot = rb.derivative(x, x[rb.ROTORS], wind, params)
    # north is body -y (drag 0.4), east is body +x (drag 0.2)
    assert_allclose(xdot[3:5], [-0.4 * 1.0 / params.mass_kg, 0.2 * 2.0 / params.mass_kg], atol=1e-12)


def test_normalize_gives_a_unit_quaternion_and_leaves_the_rest() -> None:
    x = state(euler=(0.1, 0.2, 0.3))
    y = x.copy()
    y[rb.QUAT] *= 1.01
    z = rb.normalize(y)
    assert_allclose(z, x, atol=1e-15)
    assert y[6] != z[6]  # a copy, not in place
