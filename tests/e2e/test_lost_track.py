"""Wrong results are not reported as success: a vehicle on another clock is refused, and a
flight that ends far off its reference is LOST_TRACK (exit 9), not complete."""

from __future__ import annotations

import dataclasses
import subprocess

import numpy as np
import pytest

from offboard.clockrate import CHECK_SPAN_S, ClockRateMeter
from offboard.metrics import LOST_TRACK_M, check_tracking, end_error_m
from offboard.missions import MISSIONS_DIR
from offboard.record import COLUMNS, FlightStatus, RecordBuilder
from helpers.flights import ENV, PY, fly, write_mission
from helpers.scenarios import flown


# --- the vehicle's clock --------------------------------------------------------------------------


def pairs(rate: float, span_s: float = 1.5, hz: float = 100.0, delays_s=()) -> ClockRateMeter:
    """ATTITUDE stamps of a vehicle running ``rate`` times our clock, handled after ``delays_s``
    (cycled): what queueing does to the wall stamps."""
    meter = ClockRateMeter()
    for k in range(int(span_s * hz) + 1):
        vehicle_s = 7.0 + rate * k / hz
        delay = delays_s[k % len(delays_s)] if delays_s else 0.0
        meter.add(100.0 + k / hz + delay, int(round(vehicle_s * 1000)))
    return meter


@pytest.mark.parametrize("rate", [0.5, 1.0, 2.0, 4.0, 5.0])
def test_the_rate_is_measured_through_queueing_delays(rate):
    # every tenth message handled 0.3 s late (a backlog), the rest within a millisecond
    meter = pairs(rate, delays_s=(0.3, 0.001, 0.0, 0.0005, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0))
    measured = meter.measure()
    assert measured is not None
    assert measured.rate == pytest.approx(rate, rel=0.01)
    assert measured.real_time is (rate == 1.0)


def test_no_verdict_before_a_second_of_our_clock():
    assert pairs(5.0, span_s=CHECK_SPAN_S * 0.9).measure() is None
    assert ClockRateMeter().measure() is None


# --- ending far off the reference ------------------------------------------------------------------


def record_ending(errors_m: list[float], dt_s: float = 0.05):
    """A COMPLETE record whose north error is ``errors_m`` sample by sample."""
    rows = RecordBuilder(COLUMNS)
    for k, e in enumerate(errors_m):
        rows.append(t_s=k * dt_s, pos_ned_m=(0.0, 0.0, -1.0), vel_ned_m_s=(0.0, 0.0, 0.0), euler_rad=(0.0, 0.0, 0.0),
                    ref_pos_ned_m=(e, 0.0, -1.0), ref_yaw_rad=0.0, ref_euler_rad=(0.0, 0.0, 0.0), thrust_n=5.0,
                    torques_nm=(0.0, 0.0, 0.0), tau_tilde=(0.0, 0.0, 0.0))  # fmt: skip
    return rows.build()


@pytest.mark.parametrize(
    "errors, status",
    [
        ([0.1] * 100, FlightStatus.COMPLETE),
        ([0.1] * 99 + [12.0], FlightStatus.COMPLETE),  # a 12 m reference step at the very last sample
        ([0.1] * 90 + [12.0] * 10, FlightStatus.COMPLETE),  # a step half a second before the end
        ([0.1] * 70 + [LOST_TRACK_M + 0.5] * 30, FlightStatus.LOST_TRACK),  # off through the whole last second
        ([50.0] * 100, FlightStatus.LOST_TRACK),
        ([float("nan")] * 100, FlightStatus.COMPLETE),  # no references: no verdict
    ],
)  # fmt: skip
def test_the_verdict_looks_at_the_whole_last_second(errors, status):
    assert check_tracking(record_ending(errors)).status is status


def test_an_earlier_status_is_kept():
    record = record_ending([50.0] * 100)
    record.status = FlightStatus.LINK_LOST
    assert check_tracking(record).status is FlightStatus.LINK_LOST


@pytest.mark.parametrize(
    "name, end_m",
    [
        ("paper-sim1-rigid-body-plain.toml", 189.0),  # flown off by the law without the yaw-aware option
        ("paper-sim2.toml", 4.5),  # Simulation 2's integrated 5 % noise: the worst intended case
        ("paper-sim2-noise-free.toml", 0.82),  # Table II's mass error, its closed form
        ("paper-sim1-rigid-body.toml", 0.01),
    ],
)
def test_the_threshold_separates_the_bundled_scenarios(name, end_m):
    """The figures metrics.LOST_TRACK_M's comment quotes."""
    # run_scenario's record (shared with tests/unit/offboard/test_docs_figures.py, run once), copied: the verdict marks its copy
    record = dataclasses.replace(flown(name)[0])
    assert record.status is FlightStatus.COMPLETE  # what run_scenario alone says
    assert end_error_m(record) == pytest.approx(end_m, rel=0.05, abs=0.01)
    lost = end_m > LOST_TRACK_M
    assert check_tracking(record).status is (FlightStatus.LOST_TRACK if lost else FlightStatus.COMPLETE)


def test_simulate_says_lost_track_with_its_exit_code(tmp_path):
    proc = subprocess.run([PY, "-m", "offboard.cli", "simulate", str(MISSIONS_DIR / "paper-sim1-rigid-body-plain.toml"),
                           "--no-plots", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, env=ENV, timeout=300)  # fmt: skip
    assert proc.returncode == FlightStatus.LOST_TRACK.exit_code == 9, proc.stderr
    assert "status lost_track (flown to its end but 188.9 m from the reference" in proc.stdout
    assert proc.stderr.splitlines() == ["offboard simulate: LOST_TRACK: flown to its end but 188.9 m from the reference: "
                                        "more than 10 m off through the whole of its last 1 s"]  # fmt: skip
    assert '"status": "lost_track"' in (tmp_path / "run" / "summary.json").read_text()


@pytest.mark.e2e
def test_fly_says_lost_track_when_the_mission_ends_far_away(tmp_path):
    """A hold 200 m away for 3 s: no quadrotor gets there (PX4's speed limits), the flight is
    flown to its end and landed, and the status says it did not get there."""
    mission = write_mission(tmp_path / "far.toml", '[[mission.segment]]\ntype = "hold"\nname = "far"\n'
                                                   'position = [200, 0, 2]\nyaw = 0\nuntil_s = 3\n')  # fmt: skip
    flown = fly(tmp_path, mission)
    assert flown.returncode == 9, flown.stderr
    assert flown.status == "lost_track" and flown.summary["exit_code"] == 9
    assert flown.summary["landed"] and flown.summary["disarmed"]
    assert "offboard fly: LOST_TRACK: flown to its end but 1" in flown.stderr
    err = np.array(flown.summary["phases"][0]["axes"]["3d"]["max_m"])
    assert err > 190
