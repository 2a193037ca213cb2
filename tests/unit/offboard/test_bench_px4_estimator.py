"""bench/px4_estimator.py's comparison of EKF2's estimates with SIH's truth, on records made here
with known errors (the flight itself needs a PX4: ``python bench/px4_estimator.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.px4_estimator import EARTH_RADIUS_M, GroundStationRecord, compare

LAT0, LON0, ALT0 = 47.397742, 8.545594, 488.0


def _record(position_error, velocity_bias, truth_delay_s=0.0, seconds=40.0):
    """A vehicle that climbs to 12 m, wanders north 0.1 m at 0.2 Hz in the hold and lands; the
    estimate is the truth plus the given errors, at 50 Hz; the truth is stamped truth_delay_s late."""
    record = GroundStationRecord()
    for n in range(int(seconds * 50)):
        t = 5.0 + n / 50.0
        s = t - 5.0
        down = -12.0 * min(1.0, s / 5.0) if s < 30 else -12.0 * max(0.0, 1 - (s - 30) / 5.0)
        vd = -12.0 / 5.0 if s < 5 else (12.0 / 5.0 if 30 <= s < 35 else 0.0)
        north = 0.1 * math.sin(2 * math.pi * 0.2 * s)
        vn = 0.1 * 2 * math.pi * 0.2 * math.cos(2 * math.pi * 0.2 * s)
        est = (north + position_error(s), 0.0, down, vn + velocity_bias, 0.0, vd)
        record.estimates.append((t, *est))
        lat = LAT0 + math.degrees(north / EARTH_RADIUS_M)
        record.truths.append((t - truth_delay_s, lat, LON0, ALT0 - down, vn, 0.0, vd))
    return record


def _series(seconds=40.0):
    t = np.arange(0.0, seconds, 0.05)
    series = np.zeros(len(t), dtype=[("t_s", float), ("time_boot_ms", float), ("euler_rad_0", float), ("euler_rad_1", float)])
    series["t_s"] = t
    series["time_boot_ms"] = (t + 5.0) * 1000.0
    series["euler_rad_0"] = np.radians(2.0) * np.sin(2 * np.pi * 0.5 * t)
    return series


def test_an_exact_estimate_has_no_error_and_the_hold_wander_is_the_trues():
    f = compare(_record(lambda s: 0.0, 0.0), _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    assert f["position_error_rms_m"] == pytest.approx([0, 0, 0], abs=2e-3)
    assert f["velocity_error_rms_m_s"] == pytest.approx([0, 0, 0], abs=2e-3)
    assert f["hold_true_position_std_m"][0] == pytest.approx(0.1 / math.sqrt(2), rel=0.05)
    assert f["hold_samples"] == 130 and f["hold_tilt_max_deg"] == pytest.approx(2.0, abs=0.05)


def test_a_velocity_bias_is_reported_and_the_consistent_velocity_removes_it():
    raw = compare(_record(lambda s: 0.0, 0.3), _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    read = compare(_record(lambda s: 0.0, 0.3), _series(), velocity_from_position_s=0.5, sample_time_s=0.05)
    assert raw["velocity_error_rms_m_s"][0] == pytest.approx(0.3, abs=0.01)
    assert raw["hold_velocity_error_mean_m_s"][0] == pytest.approx(0.3, abs=0.01)
    assert read["hold_velocity_read_error_rms_m_s"][0] < 0.01  # the law reads the position's derivative


def test_a_position_held_still_while_the_vehicle_wanders():
    """The estimate holds still, the truth wanders: the PX4 hold's case."""
    f = compare(_record(lambda s: -0.1 * math.sin(2 * math.pi * 0.2 * s), 0.0), _series(), 0.0, 0.05)
    assert f["hold_estimated_position_std_m"][0] < 0.005 < 0.06 < f["hold_true_position_std_m"][0]


def test_the_truth_is_aligned_in_time():
    f = compare(_record(lambda s: 0.0, 0.0, truth_delay_s=0.02), _series(), 0.0, 0.05)
    assert f["truth_lag_s"] == pytest.approx(-0.02, abs=0.003)
    assert max(f["velocity_error_rms_m_s"]) < 0.01


def test_too_little_recorded_is_one_line():
    with pytest.raises(ValueError, match="too little recorded"):
        compare(GroundStationRecord(), _series(), 0.0, 0.05)


def test_other_time_constants_are_read_from_the_same_record():
    f = compare(_record(lambda s: 0.0, 0.3), _series(), velocity_from_position_s=0.5, sample_time_s=0.05)
    by_t = f["velocity_read_error_rms_by_time_constant_m_s"]
    assert by_t["0"][0] == pytest.approx(0.3, abs=0.01)  # EKF2's own velocity, its bias whole
    assert by_t["0.5"] == f["velocity_read_error_rms_m_s"]
    assert by_t["0.05"][0] < by_t["1"][0] < 0.3  # a constant bias: the faster filter removes it sooner


def test_the_record_identifies_a_time_constant_and_reads_with_it():
    """A constant bias does not walk, and the estimates are otherwise exact: the identification
    sees no white noise and a walk of about nothing; the T it chooses reads the velocity within
    what the fixed T does (here both take out the constant 0.3 m/s)."""
    f = compare(_record(lambda s: 0.0, 0.3), _series(), velocity_from_position_s=0.5, sample_time_s=0.05, identify=True)
    ident = f["identified"]
    assert ident["white_m_s"] < 0.01 and ident["position_white_m"] < 0.001
    assert 0.0 < ident["time_constant_s"] <= 1.0
    assert ident["velocity_read_error_rms_m_s"][0] < 0.3 / 2
    assert f["velocity_from_position_identify"] is True
    assert f["velocity_read_error_rms_m_s"][0] < 0.3 / 2  # the flight's filter, identifying, removed it too


def test_the_error_spectra_hold_the_errors_variance_and_their_phase():
    """Welch's densities integrate to the variance (Parseval); a velocity error a quarter period
    behind the position error has a cross spectrum at that line whose phase says so."""
    from bench.px4_estimator import error_spectra

    rng = np.random.default_rng(7)
    to = 0.05
    white = rng.normal(0.0, 0.02, 4000)
    t = np.arange(4000) * to
    w = 2 * np.pi * 1.25  # on a bin: 16 cycles a 12.8 s segment
    line_p, line_v = 0.03 * np.cos(w * t), 0.03 * np.sin(w * t)  # v lags p by 90 deg: V = -j P
    sp = error_spectra(white, line_v, to)
    df = sp.frequencies_hz[1] - sp.frequencies_hz[0]
    assert np.sum(sp.position) * df == pytest.approx(np.var(white), rel=0.05)
    assert np.sum(sp.velocity) * df == pytest.approx(0.03**2 / 2, rel=0.02)
    lines = error_spectra(line_p, line_v, to)
    k = int(np.argmax(lines.position))
    assert lines.frequencies_hz[k] == pytest.approx(1.25)
    assert np.angle(lines.cross[k]) == pytest.approx(-np.pi / 2, abs=1e-6)  # E[conj(P) V] of V = -j P
    with pytest.raises(ValueError, match="too few"):
        error_spectra(white[:100], white[:100], to)


def test_the_flown_designs_loop_is_handed_the_recorded_errors():
    """A position error of one line (3 cm at 0.5 Hz, on a bin of the spectra) and no velocity
    error: the predicted north tilt is that line through design.noise_transfer, east none; no
    design, no prediction."""
    from offboard.controller.design import axis_plants, noise_transfer
    from offboard.controller.tuning import design_for_vehicle

    design = design_for_vehicle({"SIH_MASS": 1.0, "SIH_T_MAX": 5.0, "SIH_IXX": 0.025, "SIH_IYY": 0.025, "SIH_IZZ": 0.03,
                                 "SIH_L_ROLL": 0.2, "SIH_T_TAU": 0.05, "SIH_KDV": 1.0}, sample_time_s=0.05)  # fmt: skip
    w = 2 * math.pi * 0.625  # 8 cycles a 12.8 s segment
    record = _record(lambda s: 0.03 * math.sin(w * s), 0.0, seconds=60.0)
    f = compare(record, _series(60.0), velocity_from_position_s=0.5, sample_time_s=0.05, design=design)
    h = noise_transfer(axis_plants(design.model, 0.05)[0], design.north.gains, 0.05, np.array([w]), 0.5)
    noise = f["predicted_noise"]
    # the Hann window spreads the line over three bins, and the velocity the record's truth and
    # estimate share is consistent: within a few per cent of the line's own response
    assert noise["tilt_rms_deg"][0] == pytest.approx(math.degrees(0.03 / math.sqrt(2) * abs(h["tilt_p"][0])), rel=0.05)
    assert noise["tilt_rms_deg"][1] < 1e-3 and noise["tilt_rms_both_deg"] == pytest.approx(noise["tilt_rms_deg"][0], rel=1e-3)
    assert noise["estimate_error_rms_m"][0] == pytest.approx(0.03 / math.sqrt(2) * abs(h["error_p"][0]), rel=0.05)
    assert compare(record, _series(60.0), 0.5, 0.05)["predicted_noise"] is None


def test_a_figure_that_is_not_finite_is_one_line_not_json_with_nan(monkeypatch, capsys):
    import bench.px4_estimator as px4_estimator

    monkeypatch.setattr(px4_estimator, "px4_launcher", lambda: "px4")
    monkeypatch.setattr(px4_estimator, "fly", lambda folder, speed, fly_args: {"truth_lag_s": float("nan")})
    assert px4_estimator.main(["--json"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("px4_estimator: a figure is not a finite number") and len(err.splitlines()) == 1


def test_the_heading_error_at_take_off_and_after_is_read_from_attitude_and_the_truth():
    """A heading reset of -30 deg at 1.2 s of the mission (EKF2's in-flight alignment of a turning
    vehicle), decaying over a second; 2 deg off later; the truth turning through +-pi (the error
    wraps, it does not jump by 360)."""
    record = _record(lambda s: 0.0, 0.0)
    for n in range(40 * 100):
        t = 5.0 + n / 100.0
        s = t - 5.0
        truth = math.pi - 0.2 + 0.1 * s  # through +pi at 2 s
        error = -30.0 * max(0.0, 1.0 - (s - 1.2)) if s >= 1.2 else 0.0
        error += 2.0 if s > 20.0 else 0.0
        wrapped = (truth + math.radians(error) + math.pi) % (2 * math.pi) - math.pi
        record.headings.append((t, wrapped))
        record.true_headings.append((t, (truth + math.pi) % (2 * math.pi) - math.pi))
    f = compare(record, _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    assert f["takeoff_heading_error_deg"] == pytest.approx(-30.0, abs=0.5) and f["takeoff_heading_error_at_s"] == pytest.approx(1.2, abs=0.02)
    assert f["later_heading_error_deg"] == pytest.approx(2.0, abs=0.1)
    # a record without ATTITUDE (a PX4 that did not stream it) says so with nulls
    g = compare(_record(lambda s: 0.0, 0.0), _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    assert g["takeoff_heading_error_deg"] is None and g["later_heading_error_deg"] is None


def test_the_true_tilt_in_the_hold_and_ekf2s_attitude_error_are_read_from_attitude_and_the_truth():
    """The vehicle truly swings 3 deg in roll at 1 Hz in the hold while EKF2 reads its roll 1.5 deg
    low and its pitch 0.5 deg high (an attitude error as PX4 SIH's EKF2 keeps in its holds)."""
    record = _record(lambda s: 0.0, 0.0)
    for n in range(40 * 50):
        t = 5.0 + n / 50.0
        s = t - 5.0
        roll = math.radians(3.0) * math.sin(2 * math.pi * s)
        record.true_attitudes.append((t, roll, 0.0))
        record.attitudes.append((t, roll - math.radians(1.5), math.radians(0.5)))
    f = compare(record, _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    assert f["hold_true_tilt_max_deg"] == pytest.approx(3.0, abs=0.05)
    assert f["hold_true_tilt_rms_deg"] == pytest.approx(3.0 / math.sqrt(2), rel=0.03)
    assert f["hold_attitude_error_mean_deg"] == pytest.approx([-1.5, 0.5], abs=0.02)
    # a record without attitudes says so with nulls
    g = compare(_record(lambda s: 0.0, 0.0), _series(), velocity_from_position_s=0.0, sample_time_s=0.05)
    assert g["hold_true_tilt_max_deg"] is None and g["hold_attitude_error_mean_deg"] is None
