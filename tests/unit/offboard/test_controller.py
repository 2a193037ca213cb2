"""The law of eq. 28-42: closed form against the pseudo-inverse, Appendix A recursions, options."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.controller import (
    PAPER_CONTROLLER_FILE,
    ActionLimits,
    LawMemory,
    RosalesController,
    TrackingReference,
    law_step,
    load_controller,
)
from offboard.controller.law import NUMPY_OPS
from offboard.errors import ParameterFileError

PARAMS = load_controller(PAPER_CONTROLLER_FILE)


def random_case(rng: np.random.Generator):
    x = rng.uniform(-1, 1, 12)
    x[[6, 8]] = rng.uniform(-0.5, 0.5, 2)  # moderate roll/pitch
    memory = LawMemory(*rng.uniform(-1, 1, 8))
    ref_n = TrackingReference(*rng.uniform(-2, 2, 3), rng.uniform(-math.pi, math.pi))
    ref_n1 = TrackingReference(*(np.array(ref_n[:3]) + rng.uniform(-0.1, 0.1, 3)), ref_n.yaw_rad + 0.01)
    return tuple(x), memory, ref_n, ref_n1


def increments(params, memory, x, ref_n, ref_n1):
    """Eq. 31-34 written out independently of law_step: (dx2, dx4, dx6, x8ref-x8, x10ref-x10, x12ref-x12)."""
    k, to = params.gains, params.sample_time_s
    x2d = (ref_n1.x_m - k.kx1 * (ref_n.x_m - x[0]) - x[0]) / to
    x4d = (ref_n1.y_m - k.kx3 * (ref_n.y_m - x[2]) - x[2]) / to
    x6d = (ref_n1.z_up_m - k.kx5 * (ref_n.z_up_m - x[4]) - x[4]) / to
    dx2 = x2d - k.kx2 * (memory.x2d - x[1]) - x[1]
    dx4 = x4d - k.kx4 * (memory.x4d - x[3]) - x[3]
    dx6 = x6d - k.kx6 * (memory.x6d - x[5]) - x[5]
    return dx2, dx4, dx6


@pytest.mark.parametrize("seed", range(200))
def test_closed_form_equals_pseudo_inverse_of_eq34(seed):
    rng = np.random.default_rng(seed)
    x, memory, ref_n, ref_n1 = random_case(rng)
    out, _ = law_step(PARAMS, memory, x, ref_n, ref_n1)
    to, m, g = PARAMS.sample_time_s, PARAMS.mass_kg, PARAMS.gravity_m_s2
    dx2, dx4, dx6 = increments(PARAMS, memory, x, ref_n, ref_n1)
    phi, theta = out.roll_ref_rad, out.pitch_ref_rad
    a = np.zeros((6, 4))  # eq. 34 with the angles of eq. 28-29
    a[:3, 0] = [-math.sin(theta) / m, math.cos(theta) * math.sin(phi) / m, math.cos(theta) * math.cos(phi) / m]
    a[3:, 1:] = np.eye(3)
    rates = np.array(out.euler_rate_ref_rad_s) - np.array([x[7], x[9], x[11]])
    b = np.concatenate([[dx2, dx4, dx6 + g * to], rates]) / to
    w = np.linalg.pinv(a) @ b  # eq. 35
    assert_allclose([out.thrust_n, *out.tau_tilde], w, rtol=1e-9, atol=1e-9)
    # eq. 28-29 make eq. 27 exactly solvable: no residual
    assert_allclose(a @ w, b, rtol=1e-9, atol=1e-9)


def test_eq29_has_no_singularity_without_sideways_motion():
    """Eq. 29 as printed divides by dx4; rows 1 and 3 of eq. 27 give the pitch without it."""
    x = (0.0,) * 12
    memory = LawMemory.from_state(x)
    out, _ = law_step(PARAMS, memory, x, TrackingReference(0, 0, 0, 0), TrackingReference(1.0, 0, 0, 0))
    assert math.isfinite(out.pitch_ref_rad) and out.pitch_ref_rad < 0  # pitch down to go north
    assert out.roll_ref_rad == 0.0


def test_downward_step_keeps_principal_angles_and_reverses_thrust():
    """dx6 + g To < 0: the principal branch, u < 0, not an upside-down attitude."""
    x = (0.0,) * 12
    out, _ = law_step(PARAMS, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, 0), TrackingReference(0.3, 0.2, -2.0, 0))
    assert abs(out.roll_ref_rad) < math.pi / 2 and abs(out.pitch_ref_rad) < math.pi / 2
    assert out.thrust_n < 0


@pytest.mark.parametrize("yaw_aware", [False, True])
def test_downward_step_with_a_thrust_floor_tilts_for_the_thrust_flown(yaw_aware):
    """With rotors that cannot push down (thrust_min_n > 0) the floor flies u > 0: the angles must
    point that positive thrust towards the horizontal demand (north: pitch down, east: roll
    right), not take the negative-u branch, which would push the other way."""
    floor = 0.12 * 19.6
    params = replace(PARAMS, yaw_aware=yaw_aware, limits=ActionLimits(floor, 19.6, math.radians(35)))
    x = (0.0,) * 12
    ref_n, ref_n1 = TrackingReference(0, 0, 0, 0), TrackingReference(0.3, 0.2, -2.0, 0)
    out, _ = law_step(params, LawMemory.from_state(x), x, ref_n, ref_n1)
    assert out.thrust_n == floor
    assert out.pitch_ref_rad < 0 and out.roll_ref_rad > 0
    unbounded, _ = law_step(PARAMS, LawMemory.from_state(x), x, ref_n, ref_n1)
    assert unbounded.pitch_ref_rad > 0 and unbounded.roll_ref_rad < 0  # the negative-u branch
    # above the floor nothing changes
    up = TrackingReference(0.3, 0.2, 0.5, 0)
    with_floor, _ = law_step(params, LawMemory.from_state(x), x, ref_n, up)
    without, _ = law_step(replace(params, limits=ActionLimits(None, 19.6, math.radians(35))), LawMemory.from_state(x), x, ref_n, up)
    assert with_floor == without


def discrete_model_step(x, u, tau_tilde, params):
    """Eq. 23 with the angles at n+1 in the translational rows, as Appendix A (A.3, A.11, A.20) uses."""
    to, m, g = params.sample_time_s, params.mass_kg, params.gravity_m_s2
    x = np.array(x, dtype=float)
    x[[7, 9, 11]] += to * np.asarray(tau_tilde)
    x[[6, 8, 10]] += to * x[[7, 9, 11]]
    phi, theta = x[6], x[8]
    x[1] += -u / m * math.sin(theta) * to
    x[3] += u / m * math.cos(theta) * math.sin(phi) * to
    x[5] += (u / m * math.cos(theta) * math.cos(phi) - g) * to
    x[[0, 2, 4]] += to * x[[1, 3, 5]]
    return x


def test_appendix_a_recursions_on_the_discretised_model():
    """A.1: e12(n+1) = kx12 e12(n); likewise the roll and pitch rates (kx8, kx10)."""
    controller = RosalesController(PARAMS)
    x = np.zeros(12)
    k = PARAMS.gains
    previous = None
    for n in range(40):
        t = n * PARAMS.sample_time_s
        ref = lambda tt: TrackingReference(math.cos(tt), math.sin(tt), 1 + 0.5 * tt, 0.3 * tt)  # noqa: E731
        out = controller.step(x, ref(t), ref(t + PARAMS.sample_time_s))
        memory = controller.memory
        x = discrete_model_step(x, out.thrust_n, out.tau_tilde, PARAMS)
        # errors of the rates at n+1 against the desired values at n+1, which the memory now holds
        errors = np.array([memory.x8d - x[7], memory.x10d - x[9], memory.x12d - x[11]])
        if previous is not None:
            assert_allclose(errors, np.array([k.kx8, k.kx10, k.kx12]) * previous, atol=1e-9)
        previous = errors


def test_position_errors_vanish_on_the_discretised_model():
    """Appendix A's conclusion: on eq. 23 the tracking error of a helix tends to zero."""
    controller = RosalesController(PARAMS)
    x = np.zeros(12)
    x[0], x[4] = 2.0, 2.0  # start on the helix
    to = PARAMS.sample_time_s

    def ref(t):
        return TrackingReference(2 * math.cos(t), 2 * math.sin(t), 2 + 0.8 * t, math.pi / 2)

    for n in range(400):
        out = controller.step(x, ref(n * to), ref((n + 1) * to))
        x = discrete_model_step(x, out.thrust_n, out.tau_tilde, PARAMS)
    final = ref(400 * to)
    assert_allclose([x[0], x[2], x[4]], final[:3], atol=1e-3)


def test_hover_at_the_reference_needs_m_g():
    x = (0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    ref = TrackingReference(0.0, 0.0, 5.0, 0.0)
    out = RosalesController(PARAMS).step(x, ref, ref)
    assert out.thrust_n == pytest.approx(PARAMS.mass_kg * PARAMS.gravity_m_s2)
    assert_allclose(out.tau_tilde, 0.0, atol=1e-12)
    assert_allclose(out.torques_nm, 0.0, atol=1e-12)


def test_rotor_forces_give_back_u_and_the_torques_by_eq_9_to_11():
    x = (0.1, 0.2, -0.3, 0.1, 2.0, 0.0, 0.05, 0.3, -0.04, 0.2, 0.7, 0.5)
    out = RosalesController(PARAMS).step(x, TrackingReference(0.5, 0, 2.5, 1.0), TrackingReference(0.55, 0.0, 2.6, 1.0))
    f1, f2, f3, f4 = out.rotor_forces_n
    l, c = PARAMS.arm_length_m, PARAMS.drag_to_thrust_m
    assert f1 + f2 + f3 + f4 == pytest.approx(out.thrust_n)  # eq. 9
    assert_allclose([(f3 - f1) * l, (f2 - f4) * l, c * (f2 + f4 - f1 - f3)], out.torques_nm, rtol=1e-12, atol=1e-12)


def test_startup_memory_is_the_measured_state():
    controller = RosalesController(PARAMS)
    x = np.arange(12, dtype=float) / 10
    controller.step(x, TrackingReference(0, 0, 0, 0), TrackingReference(0, 0, 0, 0))
    controller.reset()
    assert controller.memory is None
    memory = LawMemory.from_state(tuple(x))
    assert memory.x2d == x[1] and memory.x7ez == x[6] and memory.x9ez == x[8] and memory.x12d == x[11]


def test_yaw_aware_law_rotates_the_horizontal_part_into_the_heading_frame():
    """At psi = 90 deg, going north is a move to the vehicle's left: a roll, not a pitch."""
    params = PARAMS.with_changes(yaw_aware=True)
    x = (0.0,) * 10 + (math.pi / 2, 0.0)
    out, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, math.pi / 2),
                      TrackingReference(0.5, 0, 0, math.pi / 2))
    assert out.roll_ref_rad < -0.1  # roll left (towards north when facing east)
    assert abs(out.pitch_ref_rad) < 1e-12
    plain, _ = law_step(PARAMS, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, math.pi / 2),
                        TrackingReference(0.5, 0, 0, math.pi / 2))
    assert plain.pitch_ref_rad < -0.1 and abs(plain.roll_ref_rad) < 1e-12


def test_yaw_aware_equals_the_paper_at_zero_yaw():
    rng = np.random.default_rng(7)
    for _ in range(20):
        x, memory, ref_n, ref_n1 = random_case(rng)
        x = x[:10] + (0.0, x[11])
        a, _ = law_step(PARAMS, memory, x, ref_n, ref_n1)
        b, _ = law_step(PARAMS.with_changes(yaw_aware=True), memory, x, ref_n, ref_n1)
        flat = lambda o: [o.thrust_n, *o.tau_tilde, o.roll_ref_rad, o.pitch_ref_rad, *o.euler_rate_ref_rad_s]  # noqa: E731
        assert flat(a) == flat(b)


def test_limits_bound_thrust_and_tilt():
    limits = ActionLimits(thrust_min_n=0.0, thrust_max_n=8.0, tilt_max_rad=math.radians(30))
    params = PARAMS.with_changes(limits=limits)
    x = (0.0,) * 12
    up, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, 0), TrackingReference(3, -3, 5, 0))
    down, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, 0), TrackingReference(0, 0, -5, 0))
    assert up.thrust_n == 8.0 and down.thrust_n == 0.0
    assert abs(up.roll_ref_rad) == pytest.approx(math.radians(30))
    assert 0.1 < abs(up.pitch_ref_rad) <= math.radians(30) + 1e-12


def test_bounded_tilt_keeps_altitude_first():
    """With a tilt bound, u solves the vertical row of eq. 27: u cos(x9ez) cos(x7ez) = m (dx6 + g To)/To."""
    params = PARAMS.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(20)))
    x = (0.0,) * 4 + (5.0,) + (0.0,) * 7
    ref = TrackingReference(4.0, 3.0, 5.0, 0.0)  # far sideways, same height
    out, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 5.0, 0), ref)
    vertical_force = out.thrust_n * math.cos(out.pitch_ref_rad) * math.cos(out.roll_ref_rad)
    _, _, dx6 = increments(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 5.0, 0), ref)
    assert vertical_force == pytest.approx(params.mass_kg * (dx6 + 9.81 * 0.05) / 0.05)
    unbounded, _ = law_step(PARAMS, LawMemory.from_state(x), x, TrackingReference(0, 0, 5.0, 0), ref)
    assert out.thrust_n < unbounded.thrust_n  # eq. 39 would have asked for far more


def test_yaw_difference_is_wrapped():
    """A reference 2 pi away from the measured yaw is the same heading: no spin."""
    x = (0.0,) * 10 + (0.1, 0.0)
    out, _ = law_step(PARAMS, LawMemory.from_state(x), x, TrackingReference(0, 0, 0, 0.1 + 2 * math.pi),
                      TrackingReference(0, 0, 0, 0.1 + 2 * math.pi))
    assert abs(out.tau_tilde[2]) < 1e-9


def test_batched_law_matches_scalar_law():
    rng = np.random.default_rng(3)
    cases = [random_case(rng) for _ in range(16)]
    scalar = [law_step(PARAMS, m, x, r0, r1)[0] for x, m, r0, r1 in cases]
    xs = tuple(np.array([c[0][i] for c in cases]) for i in range(12))
    memory = LawMemory(*(np.array([c[1][i] for c in cases]) for i in range(8)))
    ref_n = TrackingReference(*(np.array([c[2][i] for c in cases]) for i in range(4)))
    ref_n1 = TrackingReference(*(np.array([c[3][i] for c in cases]) for i in range(4)))
    batched, _ = law_step(PARAMS, memory, xs, ref_n, ref_n1, ops=NUMPY_OPS)
    assert_allclose(batched.thrust_n, [s.thrust_n for s in scalar], rtol=1e-12)
    assert_allclose(np.array(batched.tau_tilde).T, [s.tau_tilde for s in scalar], rtol=1e-12, atol=1e-12)


def test_nan_state_gives_non_finite_output_that_is_flagged():
    x = (math.nan,) + (0.0,) * 11
    out = RosalesController(PARAMS).step(x, TrackingReference(0, 0, 0, 0), TrackingReference(0, 0, 0, 0))
    assert not out.is_finite()


# --- the parameter file ------------------------------------------------------------------


def test_paper_file_holds_table_one():
    g = PARAMS.gains
    assert (g.kx1, g.kx6, g.kx8, g.kx12) == (0.78, 0.95, 0.67, 0.85)
    assert PARAMS.sample_time_s == 0.05 and PARAMS.mass_kg == 0.5
    assert PARAMS.inertia_kg_m2 == (3.8e-3, 3.8e-3, 7.1e-3)
    assert not PARAMS.yaw_aware and not PARAMS.limits.any


@pytest.mark.parametrize(
    "edit, message",
    [
        (("kx3 = 0.77", "kx3 = 1.2"), "paper.toml: gains.kx3: must lie in (0, 1), got 1.2"),
        (("kx3 = 0.77", "kx3 = 0"), "paper.toml: gains.kx3: must lie in (0, 1), got 0"),
        (("kx3 = 0.77\n", ""), "paper.toml: gains.kx3: missing"),
        (("kx3 = 0.77", 'kx3 = "fast"'), "paper.toml: gains.kx3: expected a number, got 'fast'"),
        (("sample_time_s = 0.05", "sample_time_s = -0.05"), "paper.toml: law.sample_time_s: must be > 0, got -0.05"),
        (("mass_kg = 0.5", "mass_kg = 0"), "paper.toml: model.mass_kg: must be > 0, got 0"),
        (("inertia_kg_m2 = [3.8e-3, 3.8e-3, 7.1e-3]", "inertia_kg_m2 = [3.8e-3, 3.8e-3]"),
         "paper.toml: model.inertia_kg_m2: expected 3 numbers, got 2"),
        (("kx12 = 0.85", "kx12 = 0.85\nkx13 = 0.5"), "paper.toml: gains.kx13: unknown field"),
        (("[law]", "[law"), "paper.toml: not valid TOML"),
        (("euler_rate_form = \"castillo\"", "euler_rate_form = \"xyz\""),
         "paper.toml: model.euler_rate_form: expected one of castillo, printed, zyx, got 'xyz'"),
    ],
)
def test_bad_parameter_files_give_one_line_naming_file_and_field(tmp_path, edit, message):
    text = PAPER_CONTROLLER_FILE.read_text()
    old, new = edit
    assert old in text
    path = tmp_path / "paper.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ParameterFileError) as info:
        load_controller(path)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


# --- the optional integral action (issue: remove the steady-state error of model errors) ---


def _hover_with_mass_error(integral_gain_per_s: float):
    from offboard.inprocess import Scenario, run_scenario
    from offboard.trajectory import Hold, Sequence
    from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

    params = PARAMS.with_changes(mass_kg=0.6, integral_gain_per_s=integral_gain_per_s)  # Table II's mass
    scenario = Scenario("hover", Sequence([Hold([0, 0, -2], 0.0, 30.0, "hold")]), load_vehicle(PAPER_VEHICLE_FILE),
                        params, initial_pos_ned_m=(0.0, 0.0, -2.0))
    record = run_scenario(scenario)
    late = record["t_s"] > 25.0
    return float(np.mean(record.error_ned_m[late, 2]))


@pytest.mark.slow
def test_without_integral_the_mass_error_leaves_the_closed_form_offset():
    k = PARAMS.gains
    expected_down = -9.81 * 0.05**2 * (0.5 / 0.6 - 1) / ((1 - k.kx5) * (1 - k.kx6))  # +0.8175 m (down error)
    assert _hover_with_mass_error(0.0) == pytest.approx(expected_down, rel=1e-3)


@pytest.mark.slow
def test_integral_action_removes_the_steady_state_error():
    assert abs(_hover_with_mass_error(1.0)) < 1e-3


def test_integral_contribution_is_clamped():
    params = PARAMS.with_changes(integral_gain_per_s=10.0, integral_limit_m_s=0.5)
    x = (0.0,) * 12
    memory = LawMemory.from_state(x)
    for _ in range(50):
        _, memory = law_step(params, memory, x, TrackingReference(0, 0, 100.0, 0), TrackingReference(0, 0, 100.0, 0))
    assert memory.i5 == pytest.approx(0.5) and memory.i1 == 0.0


def test_integral_off_by_default_and_validated():
    assert PARAMS.integral_gain_per_s == 0.0
    with pytest.raises(ValueError, match="integral_gain_per_s"):
        PARAMS.with_changes(integral_gain_per_s=-1.0)


@pytest.mark.parametrize("form", ["castillo", "printed", "zyx"])
def test_euler_rates_from_body_rates_inverts_w_eta(form):
    """The closed-form W_eta^-1 (offboard.frames) is the inverse of eq. 3's W_eta."""
    from offboard.model.euler_lagrange import body_rates_from_euler_rates
    from offboard.model.euler_lagrange import euler_rates_from_body_rates
    from offboard.model.euler_lagrange import euler_rate_matrix

    rng = np.random.default_rng(7)
    for _ in range(200):
        eta, omega = rng.uniform(-1.2, 1.2, 3), rng.normal(size=3)
        eta_dot = euler_rates_from_body_rates(eta, omega, form)
        np.testing.assert_allclose(euler_rate_matrix(eta, form) @ eta_dot, omega, atol=1e-9)
        np.testing.assert_allclose(body_rates_from_euler_rates(eta, eta_dot, form), omega, atol=1e-9)


# --- [law] velocity_from_position_s: the velocity read, consistent with the position ------------


def _kinematic(t: float) -> tuple[np.ndarray, np.ndarray]:
    """A smooth 3-D motion and its exact velocity."""
    pos = np.array([2 * math.cos(t), 2 * math.sin(t), -0.8 * t])
    vel = np.array([-2 * math.sin(t), 2 * math.cos(t), -0.8])
    return pos, vel


def test_consistent_estimates_pass_the_velocity_filter_unchanged():
    from offboard.controller.velocity import ConsistentVelocity

    f = ConsistentVelocity(0.5, 0.05)
    for n in range(200):
        pos, vel = _kinematic(n * 0.05)
        out = f.update(pos, vel)
        assert_allclose(out, vel, atol=5e-4)  # the trapezoidal rule's error: h^2/12 |v''| = 4e-4 m/s


def test_the_velocity_filter_removes_a_bias_the_position_does_not_show():
    """PX4 SIH's EKF2: a velocity 0.3 m/s off while the position stands still (docs/controller-design.md)."""
    from offboard.controller.velocity import ConsistentVelocity

    t_const, h = 0.5, 0.05
    f = ConsistentVelocity(t_const, h)
    bias = np.array([0.3, -0.2, 0.25])
    outs = []
    for n in range(100):
        pos, vel = _kinematic(n * h)
        outs.append(f.update(pos, vel + bias) - vel)
    outs = np.array(outs)
    assert_allclose(outs[0], bias)  # the first sample is handed on as measured
    k = int(round(3 * t_const / h))  # three time constants: e^-3 of the bias left
    assert np.all(np.abs(outs[k]) <= np.abs(bias) * 0.06)
    assert np.all(np.abs(outs[-1]) < 1e-3)
    f.reset()
    assert_allclose(f.update(*_kinematic(0.0)), _kinematic(0.0)[1])


def test_the_paper_law_reads_the_filtered_velocity_only_when_asked():
    from offboard.controller.paper import PaperController
    from offboard.trajectory.base import Reference

    params = load_controller(PAPER_CONTROLLER_FILE)
    assert params.velocity_from_position_s == 0.0  # the paper's law: as measured

    class Estimate:
        def __init__(self, pos, vel):
            self.pos_ned_m, self.vel_ned_m_s = np.asarray(pos, float), np.asarray(vel, float)
            self.euler_rad = np.zeros(3)
            self.body_rate_frd_rad_s = np.zeros(3)
            self.quat_wxyz = np.array([1.0, 0.0, 0.0, 0.0])

    ref = Reference(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0)
    bias = np.array([0.3, 0.0, 0.0])
    plain, filtered, truth = (PaperController(params), PaperController(params.with_changes(velocity_from_position_s=0.5)),
                              PaperController(params))  # fmt: skip
    for _ in range(80):  # standing still at 1 m, the velocity estimate 0.3 m/s north
        a = plain.step(Estimate([0, 0, -1], bias), ref, ref)
        b = filtered.step(Estimate([0, 0, -1], bias), ref, ref)
        c = truth.step(Estimate([0, 0, -1], np.zeros(3)), ref, ref)
    assert abs(a.attitude_ref_euler_rad[1] - c.attitude_ref_euler_rad[1]) > 1e-2  # the bias tilts the plain law
    assert_allclose(b.attitude_ref_euler_rad, c.attitude_ref_euler_rad, atol=1e-3)  # the filtered one ignores it (its transient: e^-8)
    assert_allclose(b.thrust_n, c.thrust_n, atol=1e-3)


def test_the_velocity_filter_is_read_from_a_controller_file_and_checked(tmp_path):
    text = PAPER_CONTROLLER_FILE.read_text().replace("[law]\n", "[law]\nvelocity_from_position_s = 0.5\n", 1)
    (tmp_path / "c.toml").write_text(text)
    assert load_controller(tmp_path / "c.toml").velocity_from_position_s == 0.5
    (tmp_path / "bad.toml").write_text(text.replace("velocity_from_position_s = 0.5", "velocity_from_position_s = -1"))
    with pytest.raises(ParameterFileError, match="velocity_from_position_s"):
        load_controller(tmp_path / "bad.toml")


def test_the_velocity_filter_reads_the_positions_own_stamps():
    """Over MAVLink a sample reads the latest position, whose age varies (and which may be the
    last sample's): with the stamps, consistent estimates still pass unchanged."""
    from offboard.controller.velocity import ConsistentVelocity

    rng = np.random.default_rng(4)
    stamped, nominal = ConsistentVelocity(0.5, 0.05), ConsistentVelocity(0.5, 0.05)
    worst_stamped = worst_nominal = 0.0
    for n in range(200):
        t = n * 0.05 - rng.uniform(0.0, 0.02)  # the position message 0-20 ms old
        if n % 7 == 3:
            t = last  # noqa: F821  (no newer position this sample)
        pos, vel = _kinematic(t)
        worst_stamped = max(worst_stamped, float(np.max(np.abs(stamped.update(pos, vel, t) - vel))))
        worst_nominal = max(worst_nominal, float(np.max(np.abs(nominal.update(pos, vel) - vel))))
        last = t  # noqa: F841  (read by the next turn)
    assert worst_stamped < 2e-3  # the trapezoidal rule's error, whatever the ages
    assert worst_nominal > 0.05  # taking To for the interval reads the age jitter as velocity
