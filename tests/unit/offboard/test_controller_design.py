"""The gain design of docs/controller-design.md: the inner-loop model, the closed loop, the search.

Pure tests (no processes): the discretisation against a fine simulation, the law's state space
against ``law_step`` itself, Table I's margins through an autopilot's attitude loop (the limit
cycle the issue measured), and the designed gains' margins.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.controller import PAPER_CONTROLLER_FILE, LawMemory, TrackingReference, law_step, load_controller
from offboard.controller.design import (
    _search,
    GRAVITY_M_S2,
    RATE_STATE,
    TILT_STATE,
    AxisGains,
    MarginSpec,
    TiltLoop,
    analyse_axis,
    angle_stage_plants,
    axis_plants,
    closed_loop,
    design_gains,
    discretise,
    distinct_plants,
    inner_loop_from_params,
    search_gains,
    law_state_space,
    rate_axis_plant,
    rate_output_plant,
    rate_plants,
    reference_response,
    tilt_axis_plant,
    vertical_plant,
)
from offboard.controller.params import ActionLimits
from offboard.controller.tuning import vehicle_values
from sitl_plant.params import plant_params
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from helpers import sih_params

TO = 0.05


def plant_vehicle_params() -> dict[str, float]:
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    return {name: table[name] for name in table}


def simulate(a: np.ndarray, b: np.ndarray, inputs: np.ndarray, to: float, latency: float, steps: int = 2000) -> np.ndarray:
    """x(n) of dx/dt = A x + B u with u(n) acting from n To + latency, by fine RK4."""
    h = to / steps
    x = np.zeros(a.shape[0])
    out = [x.copy()]
    for n in range(len(inputs)):
        for k in range(steps):
            t = n * to + k * h
            idx = math.floor((t - latency) / to + 1e-9)
            u = inputs[idx] if idx >= 0 else 0.0
            f = lambda s: a @ s + b[:, 0] * u  # noqa: E731
            k1 = f(x); k2 = f(x + h / 2 * k1); k3 = f(x + h / 2 * k2); k4 = f(x + h * k3)  # noqa: E702
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x.copy())
    return np.array(out)


@pytest.mark.parametrize("latency", [0.0, 0.013, 0.05, 0.071])
def test_discretisation_with_latency_matches_a_fine_simulation(latency):
    a, b = tilt_axis_plant(TiltLoop(torque_per_unit_nm=1.18, motor_time_constant_s=0.02))
    plant = discretise(a, b, TO, latency, tilt_state=2)
    rng = np.random.default_rng(3)
    u = rng.normal(size=12)
    fine = simulate(a, b, u, TO, latency, steps=200)
    x = np.zeros(plant.phi.shape[0])
    for n in range(len(u)):
        x = plant.phi @ x + plant.gamma[:, 0] * u[n]
        assert_allclose(x[:6], fine[n + 1], rtol=1e-6, atol=1e-9)
    assert_allclose(plant.c @ x, fine[-1][[0, 1, 2]], rtol=1e-6, atol=1e-9)


def test_the_drag_slows_the_modelled_axis_as_a_fine_simulation_does():
    """v_dot = g theta - delta v (PX4 SIH's -SIH_KDV v / SIH_MASS), discretised with latency."""
    a, b = tilt_axis_plant(TiltLoop(torque_per_unit_nm=2.83, inertia_kg_m2=0.025, motor_time_constant_s=0.05), drag_per_s=1.0)
    assert a[1, 1] == -1.0
    plant = discretise(a, b, TO, 0.03, tilt_state=2, drag_per_s=1.0)
    assert plant.drag_per_s == 1.0
    u = np.random.default_rng(5).normal(size=10)
    fine = simulate(a, b, u, TO, 0.03, steps=200)
    x = np.zeros(plant.phi.shape[0])
    for n in range(len(u)):
        x = plant.phi @ x + plant.gamma[:, 0] * u[n]
    assert_allclose(x[:6], fine[-1], rtol=1e-6, atol=1e-9)
    av, _ = vertical_plant(0.05, 1.0)
    assert av[1, 1] == -1.0


def test_the_model_takes_the_vehicles_drag_from_its_parameters():
    """SIH_KDV over SIH_MASS (under the plant's names too); none published: none modelled."""
    sih = {**sih_params(), "SIH_KDV": 1.0, "SIH_MASS": 1.0}
    assert inner_loop_from_params(vehicle_values(sih)).drag_per_s == 1.0
    assert inner_loop_from_params(vehicle_values({**sih, "SIH_MASS": 2.0})).drag_per_s == 0.5
    assert inner_loop_from_params(plant_vehicle_params()).drag_per_s == 0.0  # the paper's quad: no drag
    north, east, up = axis_plants(inner_loop_from_params(vehicle_values(sih)), TO)
    assert north.drag_per_s == east.drag_per_s == up.drag_per_s == 1.0


def test_the_reference_lead_flattens_the_designed_loops_response_where_references_live():
    """With the velocity integral, the Taylor c2 of T about 0 holds only below the integral's
    zero; the lead is the proportional loop's (``tracking_lead_s2``), which keeps |T (1 + c2 w^2)|
    (a circle's radius flown over its radius) within 1 % up to 1 rad/s (the helix's rate) on PX4
    SIH's loop with its drag, where the integral loop's own c2 leaves 3 % or more at 1 rad/s;
    what remains is a phase lag of under 3 deg (along the track)."""
    from offboard.controller.tuning import vehicle_values

    sih = {**sih_params(), "SIH_KDV": 1.0, "SIH_MASS": 1.0}
    design = design_gains(inner_loop_from_params(vehicle_values(sih), 0.03), TO, velocity_integral=True)
    north, _, up = axis_plants(design.model, TO)
    w = np.linspace(0.05, 1.0, 20)
    for plant, analysis, c2 in ((north, design.north, design.reference_lead_s2[0]), (up, design.up, design.reference_lead_s2[1])):
        assert float(np.asarray(analysis.gains.velocity_integral_per_s2)) > 0
        led = reference_response(plant, analysis.gains, TO, w) * (1 + c2 * w**2)
        assert np.max(np.abs(np.abs(led) - 1.0)) < 0.01
        assert np.max(np.abs(np.degrees(np.angle(led)))) < 3.0
    # the integral loop's own low-frequency c2, for contrast
    t = reference_response(north, design.north.gains, TO, np.array([0.01, 1.0]))
    c2_integral = float(((t[0] - 1.0) / (1j * 0.01) ** 2).real)
    assert abs(t[1] * (1 + c2_integral)) - 1.0 > 0.03


def test_vertical_plant_is_a_double_integrator_behind_the_motor_lag():
    plant = discretise(*vertical_plant(1e-6), TO, 0.0)  # no lag: the exact ZOH double integrator
    assert_allclose(plant.phi[:2, :2], [[1.0, TO], [0.0, 1.0]], atol=1e-9)
    x = plant.phi @ np.zeros(plant.phi.shape[0]) + plant.gamma[:, 0]
    assert_allclose(x[:2], [TO**2 / 2, TO], rtol=5e-3)  # the model floors the lag at 0.1 ms


@pytest.mark.parametrize("lead,drag", [(0.0, 0.0), (0.75, 0.0), (0.75, 0.4)])
def test_the_state_space_is_the_law_itself_on_one_axis(lead, drag):
    """law_state_space (linear, one axis) gives the acceleration law_step asks for (small signals),
    with the believed linear drag the law makes up (delta = d / m)."""
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(tilt_lead=lead, linear_drag_n_s_m=drag)
    g, to = params.gravity_m_s2, params.sample_time_s
    p, v, vd_prev, pitch = 1e-3, -2e-3, 5e-4, 1e-4  # north position, speed, memory x2d(n), pitch
    x = (p, v, 0, 0, 0, 0, 0, 0, pitch, 0, 0, 0)
    memory = LawMemory(vd_prev, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, pitch)
    ref = TrackingReference(0.0, 0.0, 0.0, 0.0)
    out, mem = law_step(params, memory, x, ref, ref)
    # paper pitch accelerates towards -x: a = -g tan(pitch); the model's tilt is v_dot / g = -pitch
    a_law = -g * math.tan(out.pitch_setpoint_rad)
    ss = law_state_space(AxisGains(params.gains.kx1, params.gains.kx2, lead), to, g, drag_per_s=drag / params.mass_kg)
    y = np.array([p, v, -pitch])
    a_ss = float(ss["c"][0] @ np.array([vd_prev]) + ss["d"][0] @ y)
    vd_next = float(ss["a"][0] @ np.array([vd_prev]) + ss["b"][0] @ y)
    assert a_law == pytest.approx(a_ss, rel=1e-4)
    assert mem.x2d == pytest.approx(vd_next, rel=1e-9)


def test_table_one_rings_through_an_autopilot_attitude_loop():
    """Table I through the plant's PX4 loop has almost no margin (the demo's +-30 deg limit
    cycle), and through PX4 SIH's slower rate loop and motors it is unstable (PX4's)."""
    table1 = AxisGains(0.78, 0.8)
    north, _, up = axis_plants(inner_loop_from_params(plant_vehicle_params()), TO)
    a = analyse_axis(north, table1, TO)
    assert a.spectral_radius < 1.0 and a.gain_margin < 1.3 and a.phase_margin_deg < 10.0
    north_sih, _, _ = axis_plants(inner_loop_from_params(sih_params()), TO)
    assert analyse_axis(north_sih, table1, TO).spectral_radius > 1.0
    # the vertical loop (thrust lag only) is not the problem
    assert analyse_axis(up, AxisGains(0.9, 0.95), TO).phase_margin_deg > 45.0


@pytest.mark.parametrize("params", ["plant", "sih"])
@pytest.mark.parametrize("to, latency", [(0.05, 0.0), (0.05, 0.07), (0.02, 0.01)])
def test_designed_gains_keep_the_stated_margins(params, to, latency):
    spec = MarginSpec()
    values = plant_vehicle_params() if params == "plant" else sih_params()
    design = design_gains(inner_loop_from_params(values, latency), to, spec)
    for axis in (design.north, design.east, design.up):
        assert axis.meets(spec), axis
        g = axis.gains
        assert 0.0 < float(g.k_pos) < 1.0 and 0.0 < float(g.k_vel) < 1.0  # Appendix A's range
    # the same gains a second time (a pure function of the model)
    assert design_gains(inner_loop_from_params(values, latency), to, spec).horizontal == design.horizontal


def test_the_sensitivity_peak_bounds_the_design():
    """Ms = max |1/(1+L)| <= 1.6 by default; gain margin 2 and phase margin 45 deg alone let PX4
    SIH's loop with its drag reach Ms 2.0 (+6 dB near 8 rad/s, where the PX4 hold rang)."""
    from offboard.controller.design import SENSITIVITY_PEAK, loop_response
    from offboard.controller.tuning import vehicle_values

    assert SENSITIVITY_PEAK == MarginSpec().sensitivity_peak == 1.6
    model = inner_loop_from_params(vehicle_values({**sih_params(), "SIH_KDV": 1.0, "SIH_MASS": 1.0}), 0.02)
    bounded = design_gains(model, TO, velocity_integral=True)
    free = design_gains(model, TO, MarginSpec(sensitivity_peak=math.inf), velocity_integral=True)
    north, _, _ = axis_plants(model, TO)
    for design, low, high in ((bounded, 1.0, 1.6), (free, 1.9, math.inf)):
        w, loop = loop_response(north, design.north.gains, TO)
        ms = float(np.max(np.abs(1.0 / (1.0 + loop))))
        assert low < ms <= high and design.north.sensitivity_peak == pytest.approx(ms)
    assert float(bounded.north.gains.k_pos) > float(free.north.gains.k_pos)  # the bound slows the loop


def test_a_margin_the_loop_cannot_keep_is_one_clear_error():
    with pytest.raises(ValueError, match="no gains .* keep gain margin 50"):
        design_gains(inner_loop_from_params(plant_vehicle_params()), TO, MarginSpec(gain_margin=50.0))


def test_reference_response_passes_position_and_velocity_exactly():
    """T(1) = 1 and T'(0) = 0: eq. 32 hands the reference's velocity on; what is left at low
    frequency is c2 s^2 (``reference_lead_s2``), and handing the law r - c2 r'' removes it."""
    north, _, _ = axis_plants(inner_loop_from_params(plant_vehicle_params()), TO)
    design = design_gains(inner_loop_from_params(plant_vehicle_params()), TO)
    w = np.array([1e-4, 0.05])
    t = reference_response(north, design.horizontal, TO, w)
    assert abs(t[0] - 1.0) < 1e-6
    c2 = design.north.reference_lead_s2
    assert t[1] == pytest.approx(1.0 + c2 * (1j * w[1]) ** 2, abs=1e-5)
    s = 1j * 0.3
    lead_on = reference_response(north, design.horizontal, TO, np.array([0.3]))[0] * (1.0 - c2 * s**2)
    assert abs(lead_on - 1.0) < abs(t[1] - 1.0) * 40 and abs(lead_on - 1.0) < 1e-3


def test_the_integral_state_removes_a_constant_disturbance():
    """With integral action the closed loop's position returns to the reference under a
    constant acceleration disturbance (modelled as a constant input offset)."""
    north, _, _ = axis_plants(inner_loop_from_params(plant_vehicle_params()), TO)
    for ki, settles in ((0.0, False), (0.3, True)):
        m, _ = closed_loop(north, AxisGains(0.93, 0.93, 0.0, ki), TO)
        x = np.zeros(m.shape[0])
        n = north.phi.shape[0]
        for _ in range(2000):
            x = m @ x
            x[:n] += north.gamma[:, 0] * 0.5  # 0.5 m/s^2 of disturbance each sample
        assert bool(abs(x[0]) < 1e-3) is settles


def test_inner_loop_from_sih_params_uses_px4s_allocation_scale():
    m = inner_loop_from_params(sih_params())
    # 4 rotors at L_ROLL 0.2 m, T_MAX 5 N, each taking 1/sqrt(2) of a unit roll command
    assert m.roll.torque_per_unit_nm == pytest.approx(0.2 * 5.0 * 4 / math.sqrt(2), rel=1e-6)
    assert m.roll.inertia_kg_m2 == pytest.approx(0.025) and m.thrust_time_constant_s == pytest.approx(0.05)
    with pytest.raises(KeyError, match="SIM_TQ_RP_MAX nor SIH_T_MAX"):
        inner_loop_from_params({"MC_ROLL_P": 6.5})


# --- the law's extensions the design uses ---------------------------------------------------------


def hover_state(**kw: float) -> tuple[float, ...]:
    x = [0.0] * 12
    for i, v in kw.items():
        x[int(i[1:]) - 1] = v
    return tuple(x)


def test_tilt_cone_bounds_the_thrust_axis_not_each_angle():
    base = load_controller(PAPER_CONTROLLER_FILE)
    x = hover_state(x5=5.0)
    far = TrackingReference(30.0, 30.0, 5.0, 0.0)
    tilt = lambda out: math.degrees(math.acos(math.cos(out.roll_ref_rad) * math.cos(out.pitch_ref_rad)))  # noqa: E731
    per_axis = base.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(35)))
    out, _ = law_step(per_axis, LawMemory.from_state(x), x, far, far)
    assert tilt(out) == pytest.approx(47.8, abs=0.2)  # 35 deg on both angles
    cone = base.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(35), tilt_cone=True))
    out_c, _ = law_step(cone, LawMemory.from_state(x), x, far, far)
    assert tilt(out_c) == pytest.approx(35.0, abs=1e-9)
    # the horizontal direction of the thrust axis is kept: (-sin theta, cos theta sin phi)
    d = lambda o: math.atan2(math.cos(o.pitch_ref_rad) * math.sin(o.roll_ref_rad), -math.sin(o.pitch_ref_rad))  # noqa: E731
    unbounded, _ = law_step(base.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(89), tilt_cone=True)),
                            LawMemory.from_state(x), x, far, far)  # fmt: skip
    assert d(out_c) == pytest.approx(d(unbounded), abs=1e-9)


def test_speed_limits_bound_the_desired_speeds_of_eq_32():
    limits = ActionLimits(speed_xy_max_m_s=2.0, speed_up_max_m_s=3.0, speed_down_max_m_s=1.5)
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(limits=limits)
    x = hover_state(x5=12.0)
    for ref, check in (
        (TrackingReference(40.0, -30.0, 12.0, 0.0), lambda m: math.hypot(m.x2d, m.x4d) == pytest.approx(2.0)),
        (TrackingReference(0.0, 0.0, 0.0, 0.0), lambda m: m.x6d == pytest.approx(-1.5)),
        (TrackingReference(0.0, 0.0, 40.0, 0.0), lambda m: m.x6d == pytest.approx(3.0)),
    ):
        _, memory = law_step(params, LawMemory.from_state(x), x, ref, ref)
        assert check(memory)
    # inside the bounds nothing changes
    near = TrackingReference(0.01, 0.0, 12.0, 0.0)
    free, _ = law_step(load_controller(PAPER_CONTROLLER_FILE), LawMemory.from_state(x), x, near, near)
    bounded, _ = law_step(params, LawMemory.from_state(x), x, near, near)
    assert free == bounded


def test_the_believed_drag_is_made_up_by_the_thrust():
    params = load_controller(PAPER_CONTROLLER_FILE)
    x = hover_state(x2=2.0, x5=5.0)  # flying north at 2 m/s
    ref_n, ref_n1 = TrackingReference(0.0, 0.0, 5.0, 0.0), TrackingReference(0.1, 0.0, 5.0, 0.0)
    memory = LawMemory.from_state(x)
    plain, _ = law_step(params, memory, x, ref_n, ref_n1)
    dragged, _ = law_step(params.with_changes(linear_drag_n_s_m=1.0), memory, x, ref_n, ref_n1)
    # tan(pitch) (dx6 + g To) = -dx2: the drag adds To d/m x2 = 0.05 * 1 / 0.5 * 2 = 0.2 m/s to dx2
    vertical = params.gravity_m_s2 * params.sample_time_s
    assert -math.tan(dragged.pitch_ref_rad) * vertical == pytest.approx(-math.tan(plain.pitch_ref_rad) * vertical + 0.2)


def test_yaw_rate_feed_forward_is_the_references_own():
    params = load_controller(PAPER_CONTROLLER_FILE)
    x = hover_state(x5=2.0)
    out, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 2, 0.0), TrackingReference(0, 0, 2, math.pi, 0.0))
    assert out.yaw_rate_ff_rad_s == 0.0 and abs(out.euler_rate_ref_rad_s[2]) > 50.0  # the pi step: 63 rad/s of x12ref
    out, _ = law_step(params, LawMemory.from_state(x), x, TrackingReference(0, 0, 2, 0.0, 0.5), TrackingReference(0, 0, 2, 0.025, 0.5))
    assert out.yaw_rate_ff_rad_s == 0.5


def test_the_tilt_lead_leads_the_setpoint_past_the_measured_angle():
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(tilt_lead=1.5)
    x = hover_state(x5=5.0, x7=0.05)
    ref = TrackingReference(0.0, 0.3, 5.0, 0.0)
    out, _ = law_step(params, LawMemory.from_state(x), x, ref, ref)
    assert out.roll_setpoint_rad == pytest.approx(out.roll_ref_rad + 1.5 * (out.roll_ref_rad - 0.05))
    plain, _ = law_step(params.with_changes(tilt_lead=0.0), LawMemory.from_state(x), x, ref, ref)
    assert plain.roll_setpoint_rad == plain.roll_ref_rad and plain.pitch_setpoint_rad == plain.pitch_ref_rad
    assert plain.thrust_n == out.thrust_n and plain.roll_ref_rad == out.roll_ref_rad  # the law itself is unchanged


def test_the_batch_law_gives_the_same_extensions():
    from offboard.controller.law import NUMPY_OPS

    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(
        tilt_lead=0.5, linear_drag_n_s_m=0.3,
        limits=ActionLimits(tilt_max_rad=math.radians(30), tilt_cone=True, speed_xy_max_m_s=2.0, speed_down_max_m_s=1.0),
    )  # fmt: skip
    rng = np.random.default_rng(5)
    xs = rng.normal(scale=0.3, size=(12, 6))
    refs = [TrackingReference(*rng.normal(scale=3, size=3), 0.0) for _ in range(2)]
    batch_ref = [TrackingReference(*(np.full(6, v) for v in r)) for r in refs]
    out_b, _ = law_step(params, LawMemory.from_state(xs), xs, *batch_ref, ops=NUMPY_OPS)
    for k in range(6):
        x = tuple(float(v) for v in xs[:, k])
        out, _ = law_step(params, LawMemory.from_state(x), x, *refs)
        assert out_b.roll_setpoint_rad[k] == pytest.approx(out.roll_setpoint_rad, abs=1e-12)
        assert out_b.thrust_n[k] == pytest.approx(out.thrust_n, abs=1e-9)


def test_a_bounded_yaw_rate_slews_the_yaw_reference():
    """A pi step under yaw_rate_max: the reference turns at the bound, its rate is the
    feed-forward, and it arrives; without the bound the step passes in one sample (the paper)."""
    rate = math.radians(45.0)
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(limits=ActionLimits(yaw_rate_max_rad_s=rate))
    x = hover_state(x5=5.0)
    ref = TrackingReference(0.0, 0.0, 5.0, math.pi - 1e-9)
    memory = LawMemory.from_state(x)
    yaws = []
    for _ in range(90):
        out, memory = law_step(params, memory, x, ref, ref)
        yaws.append(out.yaw_ref_rad)
        if len(yaws) == 1:
            assert out.yaw_rate_ff_rad_s == pytest.approx(rate) and abs(out.euler_rate_ref_rad_s[2]) < 5.0
    steps = np.diff([0.0, *yaws])
    assert np.all(steps <= rate * 0.05 + 1e-12) and yaws[-1] == pytest.approx(math.pi - 1e-9)
    assert sum(s > 0 for s in steps) == math.ceil(math.pi / (rate * 0.05))  # 80 samples: 4 s
    unbounded, _ = law_step(load_controller(PAPER_CONTROLLER_FILE), LawMemory.from_state(x), x, ref, ref)
    assert unbounded.yaw_ref_rad == ref.yaw_rad


# --- the velocity integral --------------------------------------------------------------------------


def test_the_velocity_integral_state_space_is_the_law_itself_on_one_axis():
    """law_state_space with the velocity integral gives law_step's acceleration and next memory."""
    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(velocity_integral_gain_per_s2=1.3)
    g, to = params.gravity_m_s2, params.sample_time_s
    p, v, vd_prev, a_prev, pitch = 1e-3, -2e-3, 5e-4, 2e-4, 1e-4
    x = (p, v, 0, 0, 0, 0, 0, 0, pitch, 0, 0, 0)
    memory = LawMemory(vd_prev, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, pitch, a1=a_prev)
    ref = TrackingReference(0.0, 0.0, 0.0, 0.0)
    out, mem = law_step(params, memory, x, ref, ref)
    a_law = -g * math.tan(out.pitch_setpoint_rad)
    ss = law_state_space(AxisGains(params.gains.kx1, params.gains.kx2, 0.0, 0.0, 1.3), to, g)
    y, s = np.array([p, v, -pitch]), np.array([vd_prev, a_prev])
    assert a_law == pytest.approx(float(ss["c"][0] @ s + ss["d"][0] @ y), rel=1e-4)
    nxt = ss["a"] @ s + ss["b"] @ y
    assert mem.x2d == pytest.approx(float(nxt[0]), rel=1e-9) and mem.a1 == pytest.approx(float(nxt[1]), rel=1e-9)


def test_the_velocity_integral_removes_a_constant_disturbance():
    north, _, _ = axis_plants(inner_loop_from_params(plant_vehicle_params()), TO)
    for kiv, settles in ((0.0, False), (1.3, True)):
        m, _ = closed_loop(north, AxisGains(0.93, 0.93, 0.0, 0.0, kiv), TO)
        assert np.max(np.abs(np.linalg.eigvals(m))) < 1.0
        x = np.zeros(m.shape[0])
        n = north.phi.shape[0]
        for _ in range(3000):
            x = m @ x
            x[:n] += north.gamma[:, 0] * 0.5
        assert bool(abs(x[0]) < 1e-3) is settles


def test_the_designed_velocity_integral_keeps_the_margins():
    model = inner_loop_from_params(plant_vehicle_params())
    design = design_gains(model, TO, velocity_integral=True)
    for axis in (design.north, design.east, design.up):
        assert axis.meets(design.spec)
        assert float(axis.gains.velocity_integral_per_s2) > 0.0 and float(axis.gains.integral_per_s) == 0.0
    with pytest.raises(ValueError, match="one integral"):
        law_state_space(AxisGains(0.9, 0.9, 0.0, 0.1, 1.0), TO)


@pytest.mark.parametrize("latency", [0.0, 0.06, 0.11, 0.15])
def test_the_designed_velocity_integral_does_not_jump_with_the_latency(latency):
    """The largest integral fraction first, then the fastest loop: ranked the other way, the
    fastest proportional loop kept only q = 0.05 at 60 ms (0.1 at 110 ms) and its integral's mode
    took 34 s (16 s) to settle to 2 %, where at 0 and 150 ms the design settles in 3.7-4.1 s."""
    from offboard.controller.tuning import design_for_vehicle

    design = design_for_vehicle(plant_vehicle_params(), sample_time_s=TO, latency_s=latency, predict=latency > 0)
    h = design.horizontal
    rv = (1.0 - float(h.k_vel)) / TO
    assert float(h.velocity_integral_per_s2) == pytest.approx(0.3 * rv * rv, rel=1e-3)
    for axis in (design.north, design.up):
        assert axis.meets(design.spec) and axis.settling_time_s < 5.0, (latency, axis.gains, axis.settling_time_s)


@pytest.mark.parametrize("params", [plant_vehicle_params, sih_params])
def test_the_vertical_axis_designs_its_own_velocity_integral(params):
    """Sharing the horizontal axes' integral the vertical loop's slowest pole was that integral's
    (2 % in 14 s on sitl-plant, 15 s on PX4 SIH); its own, designed with it, settles in under 3 s
    with the same margins, and a tuned controller carries it."""
    from offboard.controller.tuning import tuned_params

    values = params()
    design = design_gains(inner_loop_from_params(values, 0.01), TO, velocity_integral=True)
    up, north = design.up, design.north
    assert up.meets(design.spec) and up.settling_time_s < 3.0
    assert float(up.gains.velocity_integral_per_s2) != float(north.gains.velocity_integral_per_s2)
    shared = analyse_axis(axis_plants(design.model, TO)[2], dataclasses.replace(
        up.gains, velocity_integral_per_s2=north.gains.velocity_integral_per_s2), TO)  # fmt: skip
    assert shared.settling_time_s > 2.0 * up.settling_time_s
    tuned = tuned_params(load_controller(PAPER_CONTROLLER_FILE), design, values)
    assert tuned.velocity_integral_gain_per_s2 == float(north.gains.velocity_integral_per_s2)
    assert tuned.vertical_velocity_integral_gain_per_s2 == float(up.gains.velocity_integral_per_s2)


def test_the_vertical_velocity_integral_acts_on_the_vertical_axis_only():
    """``vertical_velocity_integral_gain_per_s2`` moves a5 alone; None (a file without the key)
    is the horizontal gain on every axis, to the last bit."""
    base = load_controller(PAPER_CONTROLLER_FILE).with_changes(velocity_integral_gain_per_s2=1.3)
    x = hover_state(x5=5.0, x2=-0.1, x6=0.2)
    start = LawMemory.from_state(x)._replace(x2d=0.0, x6d=0.0)
    ref = TrackingReference(0.0, 0.0, 5.0, 0.0)
    out_none, mem_none = law_step(base, start, x, ref, ref)
    out_same, mem_same = law_step(base.with_changes(vertical_velocity_integral_gain_per_s2=1.3), start, x, ref, ref)
    assert out_none == out_same and mem_none == mem_same
    _, mem_own = law_step(base.with_changes(vertical_velocity_integral_gain_per_s2=5.0), start, x, ref, ref)
    assert mem_own.a1 == mem_none.a1 == pytest.approx(1.3 * base.sample_time_s * 0.1)
    assert mem_own.a5 == pytest.approx(5.0 * base.sample_time_s * -0.2) and mem_none.a5 == pytest.approx(1.3 * base.sample_time_s * -0.2)
    _, mem_off = law_step(base.with_changes(vertical_velocity_integral_gain_per_s2=0.0), start, x, ref, ref)
    assert mem_off.a5 == 0.0 and mem_off.a1 == mem_none.a1
    with pytest.raises(ValueError, match="vertical_velocity_integral_gain_per_s2"):
        base.with_changes(vertical_velocity_integral_gain_per_s2=-1.0)


def test_the_velocity_integral_holds_while_the_tilt_or_thrust_is_bounded():
    """Conditional integration: a sample whose tilt is bounded leaves the velocity integral as it
    was; an unbounded one moves it."""
    base = load_controller(PAPER_CONTROLLER_FILE).with_changes(velocity_integral_gain_per_s2=1.3)
    x = hover_state(x5=5.0, x2=-0.1)  # 0.1 m/s off the desired speed of the memory
    start = LawMemory.from_state(x)._replace(x2d=0.0, a1=0.25)
    bounded = base.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(5), tilt_cone=True))
    far = TrackingReference(30.0, 0.0, 5.0, 0.0)
    out, mem = law_step(bounded, start, x, far, far)
    assert math.degrees(abs(out.pitch_ref_rad)) == pytest.approx(5.0) and mem.a1 == 0.25
    free = base.with_changes(limits=ActionLimits(tilt_max_rad=math.radians(35), tilt_cone=True))
    near = TrackingReference(0.0, 0.0, 5.0, 0.0)
    out, mem = law_step(free, start, x, near, near)
    assert math.degrees(abs(out.pitch_ref_rad)) < 35.0
    assert mem.a1 == pytest.approx(0.25 + 1.3 * base.sample_time_s * 0.1)
    # the paper's law (no integral) keeps it at zero whatever the bounds
    _, mem = law_step(load_controller(PAPER_CONTROLLER_FILE), LawMemory.from_state(x), x, far, far)
    assert mem.a1 == 0.0


def test_the_velocity_integral_holds_over_a_steps_transient():
    """After a reference step (the error jumps by more than STEP_M) the integral holds until the
    error is below SETTLED_M, or for velocity_integral_hold_s at most; without a step, or with no
    hold time, it integrates."""
    from offboard.controller.law import SETTLED_M, STEP_M

    params = load_controller(PAPER_CONTROLLER_FILE).with_changes(velocity_integral_gain_per_s2=1.3,
                                                                  velocity_integral_hold_s=0.2)  # fmt: skip
    x = hover_state(x5=5.0, x2=-0.1)
    memory = LawMemory.from_state(x)._replace(x2d=0.0)
    step = TrackingReference(STEP_M + 0.5, 0.0, 5.0, 0.0)  # 1.5 m away at the first sample: a step
    a1 = []
    for _ in range(6):
        _, memory = law_step(params, memory, x, step, step)
        a1.append(memory.a1)
    # held for 0.2 s (4 samples: 0.2, 0.15, 0.1, 0.05 s left), then integrating though still 1.5 m off
    assert a1[:4] == [0.0] * 4 and a1[4] > 0.0 and a1[5] > a1[4]
    assert memory.error_m == pytest.approx(STEP_M + 0.5) and memory.settling == 0.0
    # settled: the hold ends at once (0.05 m off, within SETTLED_M)
    near = TrackingReference(0.5 * SETTLED_M, 0.0, 5.0, 0.0)
    m0 = LawMemory.from_state(x)._replace(x2d=0.0, settling=1.0, error_m=0.06)
    _, m1 = law_step(params, m0, x, near, near)
    assert m1.settling == 0.0 and m1.a1 != 0.0
    # no step (the error moves by less than STEP_M): integrating from the first sample
    small = TrackingReference(0.5, 0.0, 5.0, 0.0)
    _, m2 = law_step(params, LawMemory.from_state(x)._replace(x2d=0.0), x, small, small)
    assert m2.settling == 0.0 and m2.a1 != 0.0
    # velocity_integral_hold_s = 0: the hold of earlier controller files (the bounds only)
    _, m3 = law_step(params.with_changes(velocity_integral_hold_s=0.0), LawMemory.from_state(x)._replace(x2d=0.0), x, step, step)
    assert m3.a1 != 0.0


# --- the body-rate output: the law closes the attitude loop around the autopilot's rate loop -------


def test_the_rate_loop_alone_holds_the_body_rate_it_is_asked_for():
    """rate_axis_plant: PX4's rate PID, the motors and the inertia, no attitude P: a constant rate
    setpoint is flown exactly once settled (the rate integral), the tilt growing at that rate."""
    a, b = rate_axis_plant(inner_loop_from_params(plant_vehicle_params()).pitch)
    x = simulate(a, b, np.full(40, 0.2), TO, 0.0)  # 2 s of 0.2 rad/s
    assert x[-1, RATE_STATE] == pytest.approx(0.2, abs=1e-3)
    assert x[-1, TILT_STATE] - x[-11, TILT_STATE] == pytest.approx(0.2 * 10 * TO, rel=1e-2)


def test_the_rate_output_plant_is_the_law_on_the_angles_flown_by_the_rate_loop():
    """rate_output_plant's algebra against the law stepped by hand on the discretised rate loop:
    x7ez = a_c / g, x8d and x8ref by eq. 32-33 on the angle (law.py), x8ref held as the rate
    setpoint; and angle_stage_plant's against omega_sp = omega + To tau~."""
    model = inner_loop_from_params(plant_vehicle_params(), 0.02)
    rates = rate_plants(model, TO)[0]
    k7, k8 = 0.75, 0.1
    composed = rate_output_plant(rates, AxisGains(k7, k8), TO)
    stage = angle_stage_plants(model, TO)[0]
    u = np.random.default_rng(1).normal(size=60)
    x, xc, xs = np.zeros(rates.phi.shape[0]), np.zeros(composed.phi.shape[0]), np.zeros(stage.phi.shape[0])
    x2 = np.zeros(rates.phi.shape[0])
    prev_ref = prev_x8d = 0.0
    for n in range(len(u)):
        theta, omega = x[TILT_STATE], x[RATE_STATE]
        ref = u[n] / GRAVITY_M_S2
        x8d = (ref - k7 * (prev_ref - theta) - theta) / TO
        x8ref = x8d - k8 * (prev_x8d - omega)
        x = rates.phi @ x + rates.gamma[:, 0] * x8ref
        prev_ref, prev_x8d = ref, x8d
        xc = composed.phi @ xc + composed.gamma[:, 0] * u[n]
        assert_allclose(composed.c @ xc, rates.c @ x, atol=1e-9)
        # the angle stage: input tau~ = u (rad/s^2 here), omega_sp = omega + To tau~
        x2 = rates.phi @ x2 + rates.gamma[:, 0] * (x2[RATE_STATE] + TO * u[n])
        xs = stage.phi @ xs + stage.gamma[:, 0] * u[n]
        assert_allclose(stage.c[:2] @ xs, (x2[TILT_STATE], x2[RATE_STATE]), atol=1e-9)


@pytest.mark.parametrize("params", [plant_vehicle_params, sih_params])
def test_a_body_rate_design_keeps_the_margins_on_the_angles_and_on_the_position(params):
    """design_gains(body_rates=True): the angle stage (kx7, kx8) designed first, on the rate loop,
    then the position and velocity gains on the loop it closes (no tilt lead: a rate setpoint
    carries no attitude to lead); every loop keeps the spec. Table I's gains on the same loop keep
    a phase margin of 13 deg on the plant's quad (unstable on PX4 SIH's): --output rates with
    Table I diverged in the paper helix's 2 m step."""
    values = params()
    model = inner_loop_from_params(vehicle_values(values), 0.01)
    design = design_gains(model, TO, velocity_integral=True, body_rates=True)
    angle = design.model.angle_gains
    assert angle is not None and 0.0 < float(angle.k_pos) < 1.0 and 0.0 < float(angle.k_vel) < 1.0
    for plant in angle_stage_plants(design.model, TO):
        assert analyse_axis(plant, angle, TO).meets(design.spec)
    assert all(a.meets(design.spec) for a in (design.north, design.east, design.up))
    assert float(design.horizontal.lead) == 0.0
    assert design_gains(model, TO).model.angle_gains is None  # the attitude output: the autopilot closes it
    table1 = axis_plants(dataclasses.replace(model, angle_gains=AxisGains(0.7, 0.67)), TO)[0]
    assert analyse_axis(table1, AxisGains(0.78, 0.8), TO).phase_margin_deg < 20.0


def test_the_vertical_velocity_integral_is_a_controller_file_key_written_by_tune(tmp_path):
    """Absent, the horizontal gain on every axis (every file written before it); present, read as
    written; a negative one named in one line; and a designed file carries it and reads back."""
    from offboard.model.errors import ParameterFileError
    from offboard.controller.tuning import controller_file_text, design_for_vehicle, tuned_params

    assert load_controller(PAPER_CONTROLLER_FILE).vertical_velocity_integral_gain_per_s2 is None
    text = PAPER_CONTROLLER_FILE.read_text().replace("[law]\n", "[law]\nvertical_velocity_integral_gain_per_s2 = 2.5\n", 1)
    (tmp_path / "c.toml").write_text(text)
    assert load_controller(tmp_path / "c.toml").vertical_velocity_integral_gain_per_s2 == 2.5
    (tmp_path / "bad.toml").write_text(text.replace("= 2.5", "= -2.5"))
    with pytest.raises(ParameterFileError, match="vertical_velocity_integral_gain_per_s2"):
        load_controller(tmp_path / "bad.toml")
    values = plant_vehicle_params()
    design = design_for_vehicle(values, sample_time_s=TO)
    params = tuned_params(load_controller(PAPER_CONTROLLER_FILE), design, values)
    (tmp_path / "designed.toml").write_text(controller_file_text(params, design, source="test"))
    assert load_controller(tmp_path / "designed.toml") == params


def test_a_symmetric_vehicles_two_horizontal_plants_are_searched_once_with_the_same_gains():
    """The paper's quad (Ixx = Iyy, the same roll and pitch loops) has one horizontal plant twice:
    the search drops the repeat, and what it finds is what it finds over both; an asymmetric
    vehicle keeps both (and the design over both is the stricter one)."""
    to = 0.05
    model = inner_loop_from_params(plant_vehicle_params(), 0.011)
    north, east, up = axis_plants(model, to)
    assert distinct_plants((north, east)) == (north,) and distinct_plants((north, east, up)) == (north, up)
    spec = MarginSpec()
    assert search_gains((north, east), to, spec) == search_gains((north,), to, spec)
    lopsided = inner_loop_from_params({**plant_vehicle_params(), "SIM_IXX": 2 * plant_vehicle_params()["SIM_IXX"]}, 0.011)
    n2, e2, _ = axis_plants(lopsided, to)
    assert len(distinct_plants((n2, e2))) == 2


def test_the_search_checks_margins_of_stable_candidates_alone_and_finds_the_same():
    """``_search`` computes the frequency responses only of the candidates whose loop is stable:
    a candidate's figure is the same to the bit beside unstable ones as among stable ones alone,
    and an unstable one is out (inf)."""
    to = 0.05
    north, east, _ = axis_plants(inner_loop_from_params(plant_vehicle_params(), 0.011), to)
    rates = np.geomspace(0.2, 40.0, 12)
    a, b = (g.ravel() for g in np.meshgrid(rates, rates, indexing="ij"))
    kp, kv = np.round(np.exp(-a * to), 4), np.round(np.exp(-b * to), 4)
    lead = np.full(kp.size, 0.5)
    spec = MarginSpec()
    every = _search((north, east), AxisGains(kp, kv, lead), to, spec)
    finite = np.isfinite(every)
    assert 0 < finite.sum() < kp.size  # some pass, some do not
    alone = _search((north, east), AxisGains(kp[finite], kv[finite], lead[finite]), to, spec)
    assert np.array_equal(alone, every[finite])
    unstable = [i for i in range(0, kp.size, 3) if analyse_axis(north, AxisGains(kp[i], kv[i], lead[i]), to).spectral_radius >= 1.0]
    assert unstable and np.all(np.isinf(every[unstable]))


# --- the body-rate output's tilt bound --------------------------------------------------------------


def _carried_s(loop, seconds: float = 1.0, steps: int = 20000) -> float:
    """The most of the area of 1 - y, y the rate loop's step response, by fine RK4 of
    ``rate_axis_plant``'s rate states (an independent integration of what ``rate_carry_s`` reads)."""
    a, b = rate_axis_plant(loop)
    sa, sb = a[3:, 3:], b[3:, 0]
    h = seconds / steps
    x = np.zeros(3)
    area = best = 0.0
    f = lambda x: sa @ x + sb  # noqa: E731 - the step input held at 1
    for _ in range(steps):
        k1 = f(x); k2 = f(x + h / 2 * k1); k3 = f(x + h / 2 * k2); k4 = f(x + h * k3)  # noqa: E702
        nxt = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        area += (1.0 - 0.5 * (x[0] + nxt[0])) * h
        best = max(best, area)
        x = nxt
    return best


def test_the_rate_carry_is_the_most_area_over_the_rate_loops_step_response():
    """How far the rate loop carries a body rate once its setpoint drops to zero, as a time: the
    paper's quad 38.5 ms, PX4 SIH's 78 ms (its motors' 50 ms lag); slower motors carry further.
    Not the mean response time -G'(0): the rate integral makes the response overshoot until the
    area is paid back, so that is 0 while the angle still runs on."""
    from offboard.controller.design import rate_carry_s

    plant = inner_loop_from_params(plant_vehicle_params())
    sih = inner_loop_from_params(vehicle_values(sih_params()))
    for loop in (plant.roll, sih.roll):
        assert rate_carry_s(loop) == pytest.approx(_carried_s(loop), rel=2e-3)
        a, b = rate_axis_plant(loop)
        inv = np.linalg.inv(a[3:, 3:])
        assert (inv @ inv @ b[3:])[0, 0] == pytest.approx(0.0, abs=1e-12)  # -G'(0) = 0
    assert rate_carry_s(plant.roll) == pytest.approx(0.0385, abs=5e-4)
    assert rate_carry_s(sih.roll) == pytest.approx(0.0783, abs=5e-4)
    slower = dataclasses.replace(plant.roll, motor_time_constant_s=2 * plant.roll.motor_time_constant_s)
    assert rate_carry_s(slower) > rate_carry_s(plant.roll)


def test_a_body_rate_design_writes_the_carry_with_its_latency_and_an_attitude_one_none():
    from offboard.controller.design import rate_carry_s
    from offboard.controller.tuning import controller_file_text, design_for_vehicle, tuned_params

    values = plant_vehicle_params()
    base = load_controller(PAPER_CONTROLLER_FILE)
    rates = design_for_vehicle(values, sample_time_s=TO, latency_s=0.02, body_rates=True)
    params = tuned_params(base, rates, values)
    assert params.limits.rate_carry_s == pytest.approx(rate_carry_s(rates.model.roll) + 0.02, abs=1e-4)
    assert tuned_params(base, design_for_vehicle(values, sample_time_s=TO), values).limits.rate_carry_s == 0.0
    text = controller_file_text(params, rates, source="test")
    assert "rate_carry_s = " in text
    assert controller_from_text(text).limits.rate_carry_s == params.limits.rate_carry_s


def controller_from_text(text: str):  # noqa: ANN201
    import tomllib

    from offboard.controller.params import controller_from_table
    from offboard.model.tomlfile import Fields

    return controller_from_table(Fields(tomllib.loads(text), "test.toml"))


def test_the_rate_carry_is_a_limits_key_that_must_not_be_negative():
    from offboard.model.errors import ParameterFileError

    text = PAPER_CONTROLLER_FILE.read_text() + "\n[limits]\ntilt_max_deg = 35\nrate_carry_s = 0.05\n"
    assert controller_from_text(text).limits.rate_carry_s == 0.05
    assert load_controller(PAPER_CONTROLLER_FILE).limits.rate_carry_s == 0.0  # the paper's law: none
    with pytest.raises(ParameterFileError, match="rate_carry_s"):
        controller_from_text(text.replace("0.05", "-0.05"))
    with pytest.raises(ValueError, match="rate_carry_s"):
        ActionLimits(rate_carry_s=math.nan)


def test_the_body_rates_handed_on_carry_neither_angle_past_the_tilt_bound():
    """(x8ref, x10ref) within ((-b - phi - C phi_dot) / To, (b - phi - C phi_dot) / To); the yaw rate
    untouched; inside the bound with room to spare, the rates as the law gave them."""
    from offboard.controller.paper import tilt_bounded_rates

    b, to = math.radians(35.0), 0.05
    free = tilt_bounded_rates(np.radians([5.0, -5.0, 0.0]), (0.0, 0.0, 0.0), (0.5, -0.5, 2.0), b, to, 0.04)
    assert free == (0.5, -0.5, 2.0)
    # 28 deg of roll turning at 4 rad/s towards the bound: asked for +18 rad/s (the helix's jump),
    # handed a rate that brakes: 28 deg + 0.04 s x 4 rad/s is past 35 deg already
    roll, pitch, yaw = tilt_bounded_rates(np.radians([28.0, -10.0, 1.0]), (4.0, 0.0, 0.3), (18.0, -30.0, 0.3), b, to, 0.04)
    assert roll == pytest.approx((b - math.radians(28.0) - 0.04 * 4.0) / to) and roll < 0.0
    assert pitch == pytest.approx((-b - math.radians(-10.0)) / to)  # the other side of the bound
    assert yaw == 0.3
    # without a carry: the angle the held rate reaches at the sample's end
    assert tilt_bounded_rates(np.radians([28.0, 0.0, 0.0]), (4.0, 0.0, 0.0), (18.0, 0.0, 0.0), b, to)[0] == pytest.approx(
        (b - math.radians(28.0)) / to)
    # beyond the bound: back to it within the sample
    assert tilt_bounded_rates(np.radians([40.0, 0.0, 0.0]), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), b, to)[0] == pytest.approx(
        (b - math.radians(40.0)) / to)
