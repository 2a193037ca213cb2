"""``bench/px4_own.py`` flies a mission with PX4's own position controller on a real PX4 SITL:
the setpoints PX4 takes (OFFBOARD with SET_POSITION_TARGET_LOCAL_NED) and the figures read as
``make bench`` reads the law's (``bench.design.flight_figures``)."""

from __future__ import annotations

import pytest

from bench.px4_own import fly_px4_own
from helpers.flights import hover_mission

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py
PX4_SPEED = 4.0


def test_px4s_own_controller_takes_off_into_the_hold_and_holds_it(tmp_path):
    """A hold at 3 m for 16 s from the ground: PX4 arms in OFFBOARD on the streamed setpoint, spools
    up and climbs (about 3 s of its time before it leaves the ground, the law's flights' reference
    for PX4's own behaviour), and holds the point: the hold's second half (8-16 s) near it, level."""
    f = fly_px4_own(hover_mission(tmp_path / "hold.toml", height_m=3.0, duration_s=16.0), tmp_path / "flight", PX4_SPEED)
    assert f["status"] == "complete", f
    assert f["duration_s"] == pytest.approx(16.0)
    assert f["hold_rms_m"] < 0.5, f  # PX4's own hold on EKF2's estimate (0.2-0.45 m in the helix's hold)
    assert f["hold_tilt_max_deg"] < 10.0, f  # a hold, not a climb nor a fall
