"""bench/px4_dead_reckoning.py's reading of a record made here with a known dead reckoning (the
flight itself needs a PX4: ``python bench/px4_dead_reckoning.py``)."""

from __future__ import annotations

import math

import pytest

from bench.px4_dead_reckoning import REPORT_AT_S, acceleration_error, drift, landing_speeds
from bench.px4_estimator import EARTH_RADIUS_M, GroundStationRecord

LAT0, LON0 = 47.397742, 8.545594
STOP_S = 20.0
B = (0.3, -0.4)  # the estimate's acceleration error from the stop on (north, east), |b| = 0.5


def _record() -> GroundStationRecord:
    """A vehicle 3 m north of its estimate's origin that moves east at 1 m/s from the stop on; the
    estimate 1 m off the truth (the frames' origins) plus 1/2 b t^2 after the stop, its velocity
    b t off, at 50 Hz."""
    record = GroundStationRecord()
    for n in range(int(80.0 * 50)):
        t = 5.0 + n / 50.0
        after = max(0.0, t - STOP_S)
        north, east = 3.0, after
        est_n, est_e = north + 1.0 + 0.5 * B[0] * after**2, east + 0.5 * B[1] * after**2
        ve = 1.0 if after > 0 else 0.0  # the truth's, east
        record.estimates.append((t, est_n, est_e, -5.0, B[0] * after, ve + B[1] * after, 0.0))
        lat = LAT0 + math.degrees(north / EARTH_RADIUS_M)
        lon = LON0 + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(LAT0))))
        record.truths.append((t, lat, lon, 493.0, 0.0, 1.0 if after > 0 else 0.0, 0.5 if after > 0 else 0.0))
    return record


def test_the_estimate_error_and_its_b_are_read_from_the_record():
    rows = drift(_record(), STOP_S)
    assert [r["after_s"] for r in rows] == list(REPORT_AT_S)
    for r in rows:
        t = r["after_s"]
        assert r["estimate_error_m"] == pytest.approx(0.5 * 0.5 * t * t, rel=0.01, abs=0.02)  # the origins' 1 m taken out
        assert r["b_m_s2"] == pytest.approx(0.5, rel=0.01)
        assert r["vehicle_moved_m"] == pytest.approx(t, rel=0.01, abs=0.02)
        assert r["velocity_error_m_s"] == pytest.approx(0.5 * t, rel=0.01, abs=0.02)  # b t, the estimate's own velocity 0


def test_too_short_a_record_is_refused():
    with pytest.raises(ValueError, match="too little recorded"):
        drift(GroundStationRecord(), STOP_S)


def test_the_acceleration_error_is_fitted_from_the_first_seconds_after_the_stop():
    assert acceleration_error(_record(), STOP_S) == pytest.approx(B, abs=1e-6)


def test_the_landing_speeds_are_the_truths_and_their_direction_is_read_against_b():
    rows = landing_speeds(_record(), STOP_S, acceleration_error(_record(), STOP_S), every_s=0.5, until_s=3.0)
    assert [r[0] for r in rows] == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    assert rows[0][1] == pytest.approx(0.0, abs=1e-9) and math.isnan(rows[0][3])  # at rest: no direction
    assert all(speed == pytest.approx(1.0) and down == pytest.approx(0.5) for _, speed, down, _ in rows[1:])
    assert all(cosine == pytest.approx(-0.8) for *_, cosine in rows[1:])  # east against b = (0.3, -0.4)
