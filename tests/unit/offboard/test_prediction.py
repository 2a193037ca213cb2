"""The state predicted over the latency (offboard.controller.prediction, design.latency_predictor)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from offboard.controller import design as D
from offboard.controller.prediction import LatencyPredictor
from offboard.model.rotations import quat_from_euler
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from sitl_plant.params import plant_params

TO = 0.05


def _plant_model(latency_s: float) -> D.InnerLoopModel:
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    return D.inner_loop_from_params({name: table[name] for name in table}, latency_s)


def _simulate(a, b, x0, inputs, latency_s, t_end_s, dt=1e-4):
    """The continuous model from x0 at t = 0 to t_end, the input u(j) acting over [j To + L, (j+1) To + L)
    (and u(j) for j < 0 given by ``inputs``' negative keys)."""
    phi, gamma = D._zoh(a, b, dt)
    x = np.array(x0, dtype=float)
    for k in range(int(round(t_end_s / dt))):
        t = (k + 0.5) * dt
        j = math.floor((t - latency_s) / TO)
        x = phi @ x + gamma[:, 0] * inputs.get(j, 0.0)
    return x


@pytest.mark.parametrize("latency_s", [0.03, 0.05, 0.114, 0.17])
def test_with_every_state_measured_the_prediction_is_the_model_latency_ahead(latency_s):
    """Mx x + Mu u is the state the continuous model reaches L after the measurement, with the
    setpoints in flight acting when the latency says (the design's timing, ``discretise``)."""
    model = _plant_model(latency_s)
    a, b = D.tilt_axis_plant(model.pitch, drag_per_s=0.1)
    mx, mu = D.latency_predictor(a, b, TO, latency_s, tuple(range(a.shape[0])))
    rng = np.random.default_rng(3)
    x0 = rng.normal(size=a.shape[0]) * np.array([1.0, 0.5, 0.05, 0.3, 0.01, 0.02])
    m = mu.shape[1] - 1
    past = {-1 - k: float(rng.normal()) for k in range(m + 1)}  # u(n-1) ... u(n-m-1), with n = 0
    predicted = mx @ x0 + mu @ np.array([past[-1 - k] for k in range(m + 1)])
    truth = _simulate(a, b, x0, past, latency_s, latency_s)
    assert np.allclose(predicted, truth, rtol=1e-6, atol=1e-9), (predicted, truth)


def test_the_design_with_prediction_keeps_the_bandwidth_of_no_latency_and_the_margins():
    """At the 114 ms a 50 +- 20 ms link measures, the measured-state design settles in 8.6 s; the
    design for the predicted state (p, v, tilt, rate measured; the torque and the rate integral
    taken at hover) comes within 10 % of the design for no latency, with the same margins."""
    spec = D.MarginSpec()
    none = D.design_gains(_plant_model(0.0), TO, spec, velocity_integral=True)
    late = D.design_gains(_plant_model(0.114), TO, spec, velocity_integral=True)
    ahead = D.design_gains(replace(_plant_model(0.114), predict=True), TO, spec, velocity_integral=True)
    assert late.north.settling_time_s > 2.0 * none.north.settling_time_s
    assert ahead.north.settling_time_s < 1.1 * none.north.settling_time_s
    for axis in (ahead.north, ahead.east, ahead.up):
        assert axis.meets(spec), axis


def test_a_predicted_plant_with_every_state_known_is_the_plant_without_latency():
    """The closed loop on the predicted state (every state measured) has the poles of the loop
    without latency, and as many at the origin as the delay line is long: Smith's result."""
    model = _plant_model(0.114)
    a, b = D.tilt_axis_plant(model.pitch)
    gains = D.AxisGains(0.9, 0.9, 0.5, velocity_integral_per_s2=1.0)
    plant = D.predicted_plant(a, b, TO, 0.114, tuple(range(6)), tilt_state=D.TILT_STATE)
    undelayed = D.discretise(a, b, TO, 0.0, tilt_state=D.TILT_STATE)
    p_pred = np.sort(np.abs(np.linalg.eigvals(D.closed_loop_matrix(plant, gains, TO))))
    p_none = np.sort(np.abs(np.linalg.eigvals(D.closed_loop_matrix(undelayed, gains, TO))))
    extra = len(p_pred) - len(p_none)
    # the two more delay slots: at the origin (a double eigenvalue, computed to about sqrt(eps))
    assert extra == 2 and np.all(p_pred[:extra] < 1e-4)
    assert np.allclose(p_pred[extra:], p_none, atol=1e-4)  # (the loop has a pole at the origin of its own)


def _state(pos, vel, euler, rates):
    class State:
        pos_ned_m = np.asarray(pos, dtype=float)
        vel_ned_m_s = np.asarray(vel, dtype=float)
        euler_rad = np.asarray(euler, dtype=float)
        body_rate_frd_rad_s = np.asarray(rates, dtype=float)
        quat_wxyz = quat_from_euler(*euler)

    return State()


def test_a_level_vehicle_coasting_is_carried_along_its_velocity_whatever_its_heading():
    """Level, no body rates, hover's thrust in flight: the position moves by v L (no drag in the
    model), the velocity and the attitude stay; the same at any heading (the heading frame)."""
    model = _plant_model(0.12)
    for yaw in (0.0, 0.7, -2.5):
        p = LatencyPredictor(model, TO, mass_kg=0.5, gravity_m_s2=9.81)
        for _ in range(4):
            p.record(0.5 * 9.81, 0.0, 0.0)
        ahead = p.predict(_state([1.0, -2.0, -5.0], [0.8, -0.3, -0.2], [0.0, 0.0, yaw], [0.0, 0.0, 0.1]))
        assert np.allclose(ahead.pos_ned_m, [1.0 + 0.8 * 0.12, -2.0 - 0.3 * 0.12, -5.0 - 0.2 * 0.12], atol=1e-9)
        assert np.allclose(ahead.vel_ned_m_s, [0.8, -0.3, -0.2], atol=1e-9)
        assert np.allclose(ahead.euler_rad, [0.0, 0.0, yaw], atol=1e-12)
        assert ahead.body_rate_frd_rad_s[2] == 0.1


def test_a_tilt_held_by_its_setpoint_accelerates_the_vehicle_that_way():
    """Pitched 5 deg nose down facing east, the setpoint holding it: it accelerates east at
    g tan(5 deg) ~ 0.86 m/s^2 over the latency; rolled right it goes south when facing east."""
    model = _plant_model(0.1)
    tilt = math.radians(5.0)
    for roll, pitch, towards in ((0.0, -tilt, np.array([0.0, 1.0])), (tilt, 0.0, np.array([-1.0, 0.0]))):
        p = LatencyPredictor(model, TO, mass_kg=0.5)
        for _ in range(4):
            p.record(0.5 * 9.81, roll, pitch)
        ahead = p.predict(_state([0.0, 0.0, -5.0], [0.0, 0.0, 0.0], [roll, pitch, math.pi / 2], [0.0, 0.0, 0.0]))
        gained = ahead.vel_ned_m_s[:2] @ towards
        assert gained == pytest.approx(9.81 * tilt * 0.1, rel=0.02)
        assert abs(ahead.vel_ned_m_s[:2] @ np.array([-towards[1], towards[0]])) < 1e-9
        assert np.allclose(ahead.euler_rad, [roll, pitch, math.pi / 2], atol=1e-4)  # held: the tilt stays


def test_a_prediction_needs_a_latency():
    with pytest.raises(ValueError, match="latency > 0"):
        LatencyPredictor(_plant_model(0.0), TO, mass_kg=0.5)


def test_the_design_doc_quotes_the_latency_designs_as_they_come_out():
    """docs/controller-design.md, "Latency": the settling times and margins it quotes for 114 ms
    (measured state, predicted state) and for none are the design's, to the digits quoted."""
    import re

    from helpers import REPO

    text = " ".join((REPO / "docs" / "controller-design.md").read_text().split())
    spec = D.MarginSpec()
    measured = D.design_gains(_plant_model(0.114), TO, spec, velocity_integral=True).north
    none = D.design_gains(_plant_model(0.0), TO, spec, velocity_integral=True).north
    ahead = D.design_gains(replace(_plant_model(0.114), predict=True), TO, spec, velocity_integral=True).north
    quoted = re.search(r"the design for the measured state settles in ([0-9.]+) s \(\|pole\| max ([0-9.]+)\) where the "
                       r"design for no latency settles in ([0-9.]+) s \(([0-9.]+)\)", text)  # fmt: skip
    assert quoted, "the sentence on the measured state's design is gone from docs/controller-design.md"
    assert quoted.groups() == (f"{measured.settling_time_s:.2f}", f"{measured.spectral_radius:.3f}",
                               f"{none.settling_time_s:.2f}", f"{none.spectral_radius:.3f}")  # fmt: skip
    quoted = re.search(r"at 114 ms the design for the predicted state settles in ([0-9.]+) s: \|pole\| max ([0-9.]+), gain "
                       r"margin ([0-9.]+), phase margin ([0-9.]+)°, and a delay margin of ([0-9]+) ms", text)  # fmt: skip
    assert quoted, "the sentence on the predicted state's design is gone from docs/controller-design.md"
    assert quoted.groups() == (f"{ahead.settling_time_s:.2f}", f"{ahead.spectral_radius:.3f}", f"{ahead.gain_margin:.2f}",
                               f"{ahead.phase_margin_deg:.1f}", f"{ahead.delay_margin_s * 1000:.0f}")  # fmt: skip


def test_a_measurement_some_milliseconds_older_is_carried_to_the_same_instant():
    """On our own clock a sample reads telemetry 0 or 10 ms old by turns (a real-time flight's
    position stamps stepped 40, 60, 40 ms apart): each is predicted over L + its age less the
    usual age, so both land on the same instant after the sample, where a fixed L left every
    other state 10 ms short (and the law's setpoints alternated by 6 deg)."""
    model = _plant_model(0.011)
    p = LatencyPredictor(model, TO, mass_kg=0.5, gravity_m_s2=9.81)
    v = np.array([2.0, -1.0, 0.0])
    for k in range(200):  # hover's thrust in flight; ages 0, 10, 0, 10 ms: usual age 5 ms
        p.record(0.5 * 9.81, 0.0, 0.0)
        p.horizon_s(0.010 * (k % 2))
    fresh = replace_age(_state([1.0, 1.0, -5.0], v, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0]), 0.0)
    older = replace_age(_state(np.array([1.0, 1.0, -5.0]) - 0.010 * v, v, [0.0, 0.0, 0.3], [0.0, 0.0, 0.0]), 0.010)
    a, b = p.predict(fresh).pos_ned_m, p.predict(older).pos_ned_m
    assert np.allclose(a, b, atol=np.linalg.norm(v) * 0.0011)  # within the horizons' 1 ms grid
    assert np.allclose(a, [1.0, 1.0, -5.0] + v * (0.011 - 0.005), atol=np.linalg.norm(v) * 0.0011)
    # without an age: the latency itself, as in lockstep and in process
    assert p.horizon_s(None) == pytest.approx(0.011)


def test_the_horizon_stays_within_a_sample_of_the_latency_and_a_reset_forgets_the_age():
    p = LatencyPredictor(_plant_model(0.02), TO, mass_kg=0.5)
    assert p.horizon_s(0.004) == pytest.approx(0.02)  # the first age is the usual one
    assert p.horizon_s(5.0) == pytest.approx(0.02 + TO)  # an age past a sample: the longest horizon
    assert p.horizon_s(math.nan) == pytest.approx(0.02)
    p.reset()
    assert p.horizon_s(0.5) == pytest.approx(0.02)


def replace_age(state, age_s):
    state.age_s = age_s
    return state


def test_the_unmeasured_rate_integral_is_what_slows_the_predicted_design():
    """docs/controller-design.md, "How close it comes": at 110 ms the gains designed for no latency
    pass the sensitivity peak the design keeps once handed the predicted plant (the rate loop's
    integral and the motors' torque taken at hover); with the torque known they still do; with both
    known the design for 110 ms is the design for none (Smith's result). The figures are the doc's."""
    import re

    from helpers import REPO

    spec = D.MarginSpec()
    none = D.design_gains(_plant_model(0.0), TO, spec, velocity_integral=True)
    model = _plant_model(0.110)
    drag = model.drag_per_s
    found = {}
    for name, measured in (("hover", D.HORIZONTAL_MEASURED), ("torque", (0, 1, 2, 3, 5)), ("all", (0, 1, 2, 3, 4, 5))):
        plants = tuple(D.predicted_plant(*D.tilt_axis_plant(loop, drag_per_s=drag), TO, 0.110, measured, tilt_state=D.TILT_STATE,
                                         drag_per_s=drag) for loop in (model.pitch, model.roll))  # fmt: skip
        undelayed = D.analyse_axis(plants[0], none.horizontal, TO)
        designed = D.analyse_axis(plants[0], D.search_gains(plants, TO, spec, leads=D.LEAD_GRID, velocity_integral=True), TO)
        found[name] = (undelayed.sensitivity_peak, designed.spectral_radius)
    assert found["hover"][0] > spec.sensitivity_peak and found["torque"][0] > spec.sensitivity_peak
    assert found["all"][0] == pytest.approx(none.north.sensitivity_peak, abs=1e-6)
    assert found["all"][1] == pytest.approx(none.north.spectral_radius, abs=1e-9)
    assert found["all"][1] < found["torque"][1] < found["hover"][1]
    doc = " ".join((REPO / "docs" / "controller-design.md").read_text().split())
    quoted = re.search(r"gains designed for no latency reach a sensitivity peak of ([0-9.]+) \(([0-9.]+) with no latency\): past "
                       r"the ([0-9.]+) the design keeps, so it slows, to a slowest pole of ([0-9.]+)\. Were the torque known the "
                       r"peak would be ([0-9.]+) \(the design ([0-9.]+)\); with the integral known too, ([0-9.]+), and the design "
                       r"for 110 ms is the design for none, ([0-9.]+)", doc)  # fmt: skip
    assert quoted, "the paragraph on what slows the predicted design is gone from docs/controller-design.md"
    assert quoted.groups() == (f"{found['hover'][0]:.3f}", f"{none.north.sensitivity_peak:.3f}", f"{spec.sensitivity_peak:g}",
                               f"{found['hover'][1]:.4f}", f"{found['torque'][0]:.3f}", f"{found['torque'][1]:.4f}",
                               f"{found['all'][0]:.3f}", f"{found['all'][1]:.4f}")  # fmt: skip
