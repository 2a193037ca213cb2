"""What an estimator's errors make of the closed loop (``design.noise_transfer``,
``design.noise_response``): checked against the discrete loop run sample by sample, and the
velocity filter's part against ``ConsistentVelocity`` itself."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offboard.controller.design import (
    EstimateErrorSpectra,
    axis_plants,
    closed_loop,
    law_state_space,
    noise_response,
    noise_transfer,
    velocity_read_transfer,
)
from offboard.controller.tuning import design_for_vehicle
from offboard.controller.velocity import ConsistentVelocity
from helpers import sih_params

TO = 0.05


def sih_design():
    params = {**sih_params(), "SIH_KDV": 1.0}  # its drag (params.json has it; the README's list without the file does not)
    design = design_for_vehicle(params, sample_time_s=TO, latency_s=0.011, predict=True)
    return axis_plants(design.model, TO)[0], design.north.gains


def steady_amplitude(signal: np.ndarray, w: float, start: int) -> complex:
    """The complex amplitude of ``signal``'s component at w (rad/s) over samples from ``start`` on,
    whole periods."""
    n = np.arange(len(signal))
    period = 2 * math.pi / (w * TO)
    count = int((len(signal) - start) // period * period)
    k = n[start:start + count]
    return 2.0 * np.mean(signal[start:start + count] * np.exp(-1j * w * TO * k))


@pytest.mark.parametrize("w", [0.7, 3.0, 10.0])
def test_the_tilt_and_the_error_follow_a_position_error_as_the_loop_run_sample_by_sample(w):
    """The loop of plant and law (``closed_loop``'s matrices) run with the law reading p + n_p,
    n_p a sinusoid: the tilt's and the estimate error's amplitudes are |H(w)| of noise_transfer."""
    plant, gains = sih_design()
    m, _ = closed_loop(plant, gains, TO)
    law = law_state_space(gains, TO, drag_per_s=plant.drag_per_s)
    noise_in = np.concatenate([plant.gamma @ law["d"], law["b"]], axis=0)[:, 0]
    n = plant.phi.shape[0]
    x = np.zeros(m.shape[0])
    steps = 4000
    tilt, error = np.zeros(steps), np.zeros(steps)
    for k in range(steps):
        n_p = 1e-3 * math.cos(w * TO * k)
        tilt[k] = plant.c[2] @ x[:n]
        error[k] = plant.c[0] @ x[:n] + n_p
        x = m @ x + noise_in * n_p
    h = noise_transfer(plant, gains, TO, np.array([w]))
    assert abs(steady_amplitude(tilt, w, 2000)) == pytest.approx(1e-3 * abs(h["tilt_p"][0]), rel=1e-3)
    assert abs(steady_amplitude(error, w, 2000)) == pytest.approx(1e-3 * abs(h["error_p"][0]), rel=1e-3)
    assert abs(h["tilt_p"][0]) > 0.0


@pytest.mark.parametrize("time_constant_s", [0.05, 0.5])
@pytest.mark.parametrize("w", [0.5, 5.0])
def test_the_velocity_read_is_consistent_velocitys_own(time_constant_s, w):
    """ConsistentVelocity fed the errors alone (the true state standing still) reads what
    velocity_read_transfer says of a position error and of a velocity error."""
    per_p, per_v = velocity_read_transfer(TO, np.array([w]), time_constant_s)
    for which, expected in (("p", per_p[0]), ("v", per_v[0])):
        filt = ConsistentVelocity(time_constant_s, TO)
        read = []
        for k in range(3000):
            e = math.cos(w * TO * k)
            pos = np.array([e if which == "p" else 0.0, 0.0, 0.0])
            vel = np.array([e if which == "v" else 0.0, 0.0, 0.0])
            read.append(filt.update(pos, vel)[0])
        assert steady_amplitude(np.array(read), w, 1500) == pytest.approx(expected, rel=1e-3, abs=1e-6)


def test_the_rms_integrates_the_spectra_through_the_responses():
    """A spectrum of one line, amplitude a at w: RMS a/sqrt(2) |H(w)|; a position error and an
    equal, in-phase velocity error add as H_p + H_v (their cross spectrum)."""
    plant, gains = sih_design()
    f = np.array([0.5, 1.0, 1.5])  # Hz; only the middle one carries power
    df = 0.5
    amplitude = 0.01
    line = np.array([0.0, amplitude**2 / 2 / df, 0.0])
    none = np.zeros(3)
    h = noise_transfer(plant, gains, TO, 2 * math.pi * f[1:2], 0.5)
    alone = noise_response(plant, gains, TO, EstimateErrorSpectra(f, line, none, none), 0.5)
    assert alone.tilt_rms_deg == pytest.approx(math.degrees(amplitude / math.sqrt(2) * abs(h["tilt_p"][0])), rel=1e-9)
    assert alone.estimate_error_rms_m == pytest.approx(amplitude / math.sqrt(2) * abs(h["error_p"][0]), rel=1e-9)
    both = noise_response(plant, gains, TO, EstimateErrorSpectra(f, line, line, line.astype(complex)), 0.5)
    assert both.tilt_rms_deg == pytest.approx(math.degrees(amplitude / math.sqrt(2) * abs(h["tilt_p"][0] + h["tilt_v"][0])), rel=1e-9)
    assert both.tilt_from_position_deg == pytest.approx(alone.tilt_rms_deg, rel=1e-12)


def test_a_velocity_error_in_quadrature_adds_with_its_phase():
    """n_p = Re(A e^{jwt}), n_v = Re(B e^{jwt}) with B = j A w (a velocity error that is the position
    error's own derivative): their cross spectrum conj(A) B / 2 is imaginary, and the RMS is
    |H_p A + H_v B| / sqrt(2), which the wrong conjugate would not give."""
    plant, gains = sih_design()
    f = np.array([0.5, 1.0, 1.5])
    df = 0.5
    w = 2 * math.pi * f[1]
    a, b = 0.01, 0.01j * w
    spectra = EstimateErrorSpectra(f, np.array([0, abs(a) ** 2 / 2 / df, 0]), np.array([0, abs(b) ** 2 / 2 / df, 0]),
                                   np.array([0, np.conj(a) * b / 2 / df, 0]))  # fmt: skip
    h = noise_transfer(plant, gains, TO, np.array([w]), 0.5)
    got = noise_response(plant, gains, TO, spectra, 0.5)
    assert got.tilt_rms_deg == pytest.approx(math.degrees(abs(h["tilt_p"][0] * a + h["tilt_v"][0] * b) / math.sqrt(2)), rel=1e-9)
    assert got.estimate_error_rms_m == pytest.approx(abs(h["error_p"][0] * a + h["error_v"][0] * b) / math.sqrt(2), rel=1e-9)
