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


def _march(a, b, x0, inputs, offset_s, stops_s, dt=1e-4):
    """The continuous model from x0 at t = 0, u(j) acting over [j To + offset, (j+1) To + offset):
    the state at each of ``stops_s`` (ascending, on dt's grid)."""
    phi, gamma = D._zoh(a, b, dt)
    x, t, k, out = np.array(x0, dtype=float), 0.0, 0, {}
    for stop in stops_s:
        while k < int(round(stop / dt)):
            t = (k + 0.5) * dt
            x = phi @ x + gamma[:, 0] * inputs.get(math.floor((t - offset_s) / TO), 0.0)
            k += 1
        out[stop] = x.copy()
    return out


def _observed_prediction_errors(latency_s: float, x0, observe: bool, memory_s: float | None, samples: int = 30) -> np.ndarray:
    """Each sample's prediction against the continuous model's state at the instant its setpoint
    acts (position, velocity, tilt and rate forward, in units of 1 mm, 1 cm/s, 1 mrad and
    1 crad/s: the largest), from ``x0`` (p, v, tilt, rate, the rate loop's integral, torque), the
    setpoints changing every sample and the measurements 2 and 8 ms old by turns. NaN for the
    first two samples (the first measurement has no interval before it; the first setpoint acts
    after the next)."""
    base = _plant_model(latency_s)
    a, b = D.tilt_axis_plant(base.pitch, 9.81, base.drag_per_s)
    rng = np.random.default_rng(11)
    inputs = {j: float(rng.normal(scale=1.5)) for j in range(1, samples + 10)}  # a_c (m/s^2) of sample j; hover's before 1
    ages = [math.nan, 0.005] + [0.002, 0.008] * samples  # the first is the usual age: the average starts there
    p = LatencyPredictor(replace(base, observe=observe, observer_memory_s=memory_s), TO, mass_kg=0.5, gravity_m_s2=9.81)
    offset = latency_s - 0.005  # the setpoint of sample j acts over [j To + L - usual age, ...)
    stops = sorted({round(n * TO - ages[n], 4) for n in range(1, samples)} | {round(n * TO + offset, 4) for n in range(1, samples)})
    truth = _march(a, b, np.array(x0, dtype=float), inputs, offset, [s for s in stops if s >= 0])
    errors = np.full(samples, np.nan)
    for n in range(1, samples):
        x = truth[round(n * TO - ages[n], 4)]
        state = replace_age(_state([x[0], 0.0, -5.0], [x[1], 0.0, 0.0], [0.0, -x[2], 0.0], [0.0, -x[3], 0.0]), ages[n])
        ahead = p.predict(state)
        p.record(0.5 * 9.81, 0.0, -inputs[n] / 9.81)  # forward's input is -g pitch_sp
        then = truth[round(n * TO + offset, 4)]
        got = np.array([ahead.pos_ned_m[0], ahead.vel_ned_m_s[0], -ahead.euler_rad[1], -ahead.body_rate_frd_rad_s[1]])
        if n >= 3:
            errors[n] = float(np.max(np.abs(got - then[:4]) / np.array([1e-3, 1e-2, 1e-3, 1e-2])))
    return errors


#: p, v, tilt, rate, and the rate loop's integral and torque far from hover's
FAR_FROM_HOVER = (0.3, 0.5, 0.04, 0.2, 0.05, 0.004)


@pytest.mark.parametrize("latency_s", [0.03, 0.11])
def test_the_deadbeat_observer_makes_the_prediction_the_models_truth(latency_s):
    """docs/controller-design.md, "The rate loop observed": with the rate loop's integral and the
    motors' torque observed by the deadbeat observer (memory 0, as flights observed before the
    memory), the state handed the law is the model's own state at the instant the setpoint acts,
    from the second measurement on, though the integral and torque start far from hover, the
    setpoints change every sample and the measurements come 2 and 8 ms old by turns. Taken at
    hover (the prediction without the observer) it is not."""
    observed = np.nanmax(_observed_prediction_errors(latency_s, FAR_FROM_HOVER, True, 0.0))
    at_hover = np.nanmax(_observed_prediction_errors(latency_s, FAR_FROM_HOVER, False, None))
    # observed: to rounding (the march is exact for inputs held over its steps); at hover, centimetres off
    assert observed < 1e-6 and at_hover > 1.0, (observed, at_hover)


@pytest.mark.parametrize("latency_s", [0.03, 0.11])
def test_the_observer_forgets_its_error_within_its_memory_and_is_exact_when_it_starts_right(latency_s):
    """The observer as flown (``OBSERVER_MEMORY_SAMPLES`` of memory: 1 s at 50 ms): from the
    integral and torque far from hover its prediction starts as far off as at hover, and the error
    falls by e within about the memory (the slowest mode of e^(-h/T) Phi_uu: 0.925 a sample for
    the paper quad), under a tenth of itself within 3 s; started at the model's state (level and
    at rest: the integral and torque at hover's zero when first measured) it is the model's truth
    from the start, every sample."""
    samples = 100
    far = _observed_prediction_errors(latency_s, FAR_FROM_HOVER, True, None, samples)
    early, late = np.nanmax(far[3:8]), np.nanmax(far[60:])
    assert early > 1.0 and late < 0.1 * early, (early, late)
    memory = D.OBSERVER_MEMORY_SAMPLES * TO
    at_memory = np.nanmax(far[int(memory / TO) : int(memory / TO) + 5])
    assert at_memory < 0.6 * early, (early, at_memory)  # e^-1 = 0.37 of it, with the torque's and the rounding's share
    started_right = _observed_prediction_errors(latency_s, (0.3, 0.5, 0.0, 0.0, 0.0, 0.0), True, None, samples)  # level, at rest
    assert np.nanmax(started_right) < 1e-6, np.nanmax(started_right)


def test_with_the_rate_loop_observed_the_design_for_a_latency_is_the_design_for_none():
    """The observer (``design.observed_plant``) gives the law what knowing the integral and the
    torque gave it (``test_the_unmeasured_rate_integral_is_what_slows_the_predicted_design``): at
    every latency the design's gains, slowest pole and sensitivity peak are those for no latency,
    and the closed loop's poles are the undelayed loop's with the rest at the origin (deadbeat) or,
    with the memory flown, the estimates' error modes (e^(-h/T) times Phi_uu's) inside the
    slowest of them: the memory costs the design nothing."""
    spec = D.MarginSpec()
    none = D.design_gains(_plant_model(0.0), TO, spec, velocity_integral=True)
    for latency in (0.03, 0.11, 0.15):
        observed = D.design_gains(replace(_plant_model(latency), predict=True, observe=True), TO, spec, velocity_integral=True)
        hover = D.design_gains(replace(_plant_model(latency), predict=True), TO, spec, velocity_integral=True)
        assert observed.north.gains == none.north.gains and observed.east.gains == none.east.gains
        assert observed.north.spectral_radius == pytest.approx(none.north.spectral_radius, abs=1e-9)
        assert observed.north.sensitivity_peak == pytest.approx(none.north.sensitivity_peak, abs=1e-6)
        assert hover.north.spectral_radius > none.north.spectral_radius + 4e-4  # without it, slower
    model = _plant_model(0.11)
    a, b = D.tilt_axis_plant(model.pitch, drag_per_s=model.drag_per_s)
    plant = D.observed_plant(a, b, TO, 0.11, drag_per_s=model.drag_per_s)
    undelayed = D.discretise(a, b, TO, 0.0, tilt_state=D.TILT_STATE, drag_per_s=model.drag_per_s)
    p_obs = np.sort(np.abs(np.linalg.eigvals(D.closed_loop_matrix(plant, none.north.gains, TO))))
    p_none = np.sort(np.abs(np.linalg.eigvals(D.closed_loop_matrix(undelayed, none.north.gains, TO))))
    extra = len(p_obs) - len(p_none)  # two delay slots and the two estimates: at the origin
    assert extra == 4 and np.all(p_obs[:extra] < 1e-3)
    assert np.allclose(p_obs[extra:], p_none, atol=1e-3)  # (zeros of high multiplicity come out near 1e-4)
    memory = model.observer_memory_at(TO)
    assert memory == pytest.approx(D.OBSERVER_MEMORY_SAMPLES * TO)
    remembering = D.observed_plant(a, b, TO, 0.11, drag_per_s=model.drag_per_s, memory_s=memory)
    poles = np.linalg.eigvals(D.closed_loop_matrix(remembering, none.north.gains, TO))
    phi, _, gain = D.attitude_observer(a, b, TO, memory)
    modes = np.linalg.eigvals(phi[2:, 2:] - gain @ phi[:2, 2:])
    assert np.allclose(modes, math.exp(-TO / memory) * np.linalg.eigvals(phi[2:, 2:]))
    expected = np.concatenate([p_none, np.abs(modes), [0.0, 0.0]])
    assert np.allclose(np.sort(np.abs(poles)), np.sort(expected), atol=1e-3)
    assert np.max(np.abs(modes)) < none.north.spectral_radius  # 0.925 against 0.9488
    # the figures docs/controller-design.md quotes ("The rate loop observed")
    from helpers import REPO

    doc = " ".join((REPO / "docs" / "controller-design.md").read_text().split())

    def quoted(values: np.ndarray) -> str:
        first, second = sorted(np.real(values), reverse=True)
        return f"{first:.3f} and {second:.3f}".replace("-", "\u2212")

    assert f"Φ_uu over 50 ms has eigenvalues {quoted(np.linalg.eigvals(phi[2:, 2:]))}," in doc
    assert f"Φ_uu's eigenvalues ({quoted(modes)})," in doc
    assert f"the error then goes by {np.max(np.abs(modes)):.3f} a sample" in doc


#: docs/controller-design.md's model errors: the vehicle's pitch loop against the one believed
MODEL_ERRORS = (("as modelled", {}), ("motor lag x 2", {"motor_time_constant_s": 2.0}), ("motor lag x 0.5", {"motor_time_constant_s": 0.5}),
                ("inertia x 1.3", {"inertia_kg_m2": 1.3}), ("inertia x 0.7", {"inertia_kg_m2": 0.7}),
                ("torque x 0.7", {"torque_per_unit_nm": 0.7}), ("torque x 1.4", {"torque_per_unit_nm": 1.4}),
                ("rate P x 0.7", {"rate_p": 0.7}), ("rate I x 2", {"rate_i": 2.0}), ("attitude P x 0.7", {"attitude_p_per_s": 0.7}))  # fmt: skip


def test_the_doc_quotes_what_a_model_error_costs_the_observed_and_the_hover_prediction():
    """docs/controller-design.md, "The rate loop observed": the 110 ms designs (the rate loop taken
    at hover, and observed with the memory flown) flown on a pitch loop other than the one they believe (paper quad): the
    slowest pole and the sensitivity peak of each, as the doc's table quotes them. Every case stays
    stable with a peak under 2.5."""

    from helpers import REPO

    spec = D.MarginSpec()
    model = _plant_model(0.110)
    drag, loop = model.drag_per_s, model.pitch
    believed = D.tilt_axis_plant(loop, drag_per_s=drag)
    hover = D.design_gains(replace(model, predict=True), TO, spec, velocity_integral=True).north.gains
    observed = D.design_gains(replace(model, predict=True, observe=True), TO, spec, velocity_integral=True).north.gains
    doc = " ".join((REPO / "docs" / "controller-design.md").read_text().split())
    memory = model.observer_memory_at(TO)  # as flown
    deadbeat, spread = (np.max(np.abs(D.attitude_observer(*believed, TO, m)[2])) for m in (0.0, memory))
    assert f"with factors of up to {deadbeat:.1f} (the paper quad, a 50 ms interval" in doc
    assert f"its factors are up to {spread:.2f}" in doc
    for name, scale in MODEL_ERRORS:
        truth = D.tilt_axis_plant(replace(loop, **{k: getattr(loop, k) * f for k, f in scale.items()}), drag_per_s=drag)
        at_hover = D.analyse_axis(D.predicted_plant(*truth, TO, 0.110, D.HORIZONTAL_MEASURED, tilt_state=D.TILT_STATE, drag_per_s=drag,
                                                    believed=believed), hover, TO)  # fmt: skip
        seen = D.analyse_axis(D.observed_plant(*truth, TO, 0.110, drag_per_s=drag, believed=believed, memory_s=memory), observed, TO)
        assert seen.spectral_radius < 1.0 and seen.sensitivity_peak < 2.5, (name, seen)
        row = (f"| {name} | {at_hover.spectral_radius:.4f} | {at_hover.sensitivity_peak:.3f} | {seen.spectral_radius:.4f} | "
               f"{seen.sensitivity_peak:.3f} |")  # fmt: skip
        assert row in doc, f"docs/controller-design.md lacks the row {row}"


def test_a_flight_observes_the_rate_loop_unless_told_not_to_and_designs_for_what_it_does():
    """``offboard fly``'s choice (``observe``, by default on; ``--no-observe``: the rate loop taken
    at hover): predicting over 110 ms with it, it designs the observed loop's gains (those for no
    latency) and says so; without, the gains for the rate loop at hover; in lockstep (no latency)
    there is nothing to predict or observe."""
    from offboard.codec import Scaling
    from offboard.controller.params import PAPER_CONTROLLER_FILE, load_controller
    from offboard.flight.choice import ControllerChoice, resolve_controller

    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    vehicle = {name: table[name] for name in table}
    base = load_controller(PAPER_CONTROLLER_FILE)
    scaling = Scaling(vehicle["SIM_THR_MAX"])
    flown = {}
    assert ControllerChoice(base=base, tuned=True, latency_s=0.11).observes  # the default: observed
    for observe, latency in ((True, 0.11), (False, 0.11), (True, 0.0)):
        choice = ControllerChoice(base=base, tuned=True, latency_s=latency, observe=observe)
        assert choice.observes == (observe and latency > 0)
        params, notes = resolve_controller(choice, "rigid-body", vehicle, scaling)
        flown[observe, latency] = params.gains
        assert any("the rate loop observed" in n for n in notes) == choice.observes, notes
    horizontal = [(g.kx1, g.kx2, g.kx3, g.kx4) for g in (flown[True, 0.11], flown[False, 0.11], flown[True, 0.0])]
    assert horizontal[0] == horizontal[2] != horizontal[1]  # observed: the undelayed loop's; at hover: slower
