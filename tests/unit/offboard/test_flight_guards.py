"""offboard.flight.guards: the vehicle handed to its landing when it is off its reference and not
coming back (LOST_TRACK in flight), or when its estimator stops vouching for what the law reads
(ESTIMATE_LOST). The rules alone, then a flight against the real plant in-process
(``test_fly_flight.PlantLink``: pymavlink packing both ways, no socket)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from offboard.codec import KEPT_STREAMS, UNREAD_STREAMS
from offboard.flight import ControllerChoice, Flight, FlightConfig
from offboard.flight.guards import NEEDED_ESTIMATES, EstimatorGuard, TrackGuard, sensor_health_changes
from offboard.metrics import LOST_TRACK_M, LOST_TRACK_WINDOW_S
from offboard.record import FlightStatus
from offboard.trajectory.analytic import Line
from sitl_plant.autopilot import Mode
from helpers import FakeClock
from test_fly_flight import PAPER, PlantLink, command_sequence, make_plant

DT = 0.05


def feed(guard: TrackGuard, errors: list[float]) -> list[str | None]:
    return [guard.update(k * DT, e) for k, e in enumerate(errors)]


# --- the rules -------------------------------------------------------------------------------------


def test_off_and_not_closing_through_the_window_is_lost_at_its_end():
    verdicts = feed(TrackGuard(), [LOST_TRACK_M + 1.0 + 0.1 * k for k in range(40)])  # off, drifting away
    first = next(k for k, v in enumerate(verdicts) if v)
    assert first * DT == pytest.approx(LOST_TRACK_WINDOW_S)  # through the whole window, not a sample less
    assert "11.0 m then" in verdicts[first] and "since t = 0.00 s" in verdicts[first]


def test_a_vehicle_far_off_but_closing_flies_on():
    # a reference step of 200 m: the vehicle closes at 1 m/s, far above the limit all along
    assert not any(feed(TrackGuard(), [200.0 - 1.0 * k * DT for k in range(200)]))


def test_a_vehicle_that_stalls_far_off_is_lost():
    # closing, then held 15 m off (a wind it cannot beat): lost a window after it stopped closing
    errors = [20.0 - 1.0 * k * DT for k in range(200)]
    errors = [max(e, 15.0) for e in errors]
    verdicts = feed(TrackGuard(), errors)
    stalled = next(k for k, e in enumerate(errors) if e == 15.0)
    first = next(k for k, v in enumerate(verdicts) if v)
    assert stalled < first <= stalled + round(LOST_TRACK_WINDOW_S / DT)


@pytest.mark.parametrize("gap", [LOST_TRACK_M - 0.5, math.nan])
def test_a_sample_back_within_the_limit_or_without_a_reference_starts_the_window_again(gap):
    errors = [LOST_TRACK_M + 2.0] * 15 + [gap] + [LOST_TRACK_M + 2.0] * 19
    assert not any(feed(TrackGuard(), errors))  # 15 and 19 samples: each under a window
    assert feed(TrackGuard(), [LOST_TRACK_M + 2.0] * 21)[-1]  # 21 without the gap: lost


def test_reset_forgets_the_history():
    guard = TrackGuard()
    feed(guard, [50.0] * 15)
    guard.reset()
    assert guard.update(15 * DT, 50.0) is None and guard.update(30 * DT, 50.0) is None
    assert guard.update(35 * DT, 50.0)


def test_a_guard_needs_a_positive_limit_and_window():
    with pytest.raises(ValueError, match="must be > 0"):
        TrackGuard(0.0)
    with pytest.raises(ValueError, match="must be > 0"):
        FlightConfig(lost_track_m=-1.0)


def test_the_estimator_must_vouch_for_every_estimate_the_law_reads():
    guard = EstimatorGuard()
    assert not guard.heard
    assert guard.update(1023) is None and guard.heard  # PX4's EKF2, converged on GPS
    everything = sum(NEEDED_ESTIMATES)
    for bit, name in NEEDED_ESTIMATES.items():
        why = guard.update(everything & ~bit)
        assert why and name in why and f"0x{everything & ~bit:x}" in why
    # what sitl-plant reports with its GPS failed: attitude, vertical velocity and position only
    why = guard.update(mavlink.ESTIMATOR_ATTITUDE | mavlink.ESTIMATOR_VELOCITY_VERT | mavlink.ESTIMATOR_POS_VERT_ABS)
    assert why is not None and "horizontal velocity, horizontal position" in why


def test_sensor_health_is_reported_as_it_changes():
    gps, baro = mavlink.MAV_SYS_STATUS_SENSOR_GPS, mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    present = enabled = gps | baro
    health, lines = sensor_health_changes(None, present, enabled, present)
    assert health == {"barometer": True, "GPS": True} and lines == []
    health, lines = sensor_health_changes(health, present, enabled, baro)
    assert lines == ["GPS unhealthy (SYS_STATUS)"]
    health, lines = sensor_health_changes(health, present, enabled, baro)
    assert lines == []  # said once
    _, lines = sensor_health_changes(health, present, enabled, present)
    assert lines == ["GPS healthy again (SYS_STATUS)"]
    # a sensor present but not enabled (or absent) is no one's concern; the first message names the unhealthy
    assert sensor_health_changes(None, present, baro, baro)[1] == []
    assert sensor_health_changes(None, present, enabled, baro)[1] == ["GPS unhealthy (SYS_STATUS)"]
    # PX4 v1.16 drops a GPS that stopped from present and enabled, its health bit left set (measured)
    health, lines = sensor_health_changes(health, baro, baro, present)
    assert health == {"barometer": True} and lines == ["GPS no longer reported (SYS_STATUS)"]
    assert sensor_health_changes(health, present, enabled, present)[1] == ["GPS back (SYS_STATUS)"]


def test_the_health_streams_are_read_not_switched_off():
    for mid in (mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS):
        assert mid in KEPT_STREAMS and mid not in UNREAD_STREAMS


# --- flown against the plant ------------------------------------------------------------------------


def fly_plant(trajectory, hook=None, config: FlightConfig | None = None):
    link = PlantLink(make_plant(), FakeClock())
    link.hook = hook
    events: list[str] = []
    flight = Flight(link, trajectory, ControllerChoice(base=PAPER), config or FlightConfig(lockstep=True, connect="test"),
                    clock=link.clock, event=events.append)  # fmt: skip
    return flight.run(), link, events


def hover(duration_s: float) -> Line:
    return Line((0.0, 0.0, -1.0), (0.0, 0.0, -1.0 - 0.1 * duration_s), 0.1, yaw_rad=0.0)


def gps_fails_at(time_s: float):
    def hook(lk: PlantLink) -> None:
        ap = lk.plant.autopilot
        if ap.armed and ap.mode is Mode.OFFBOARD and lk.plant.time_s > time_s and "gps" not in ap.failures:
            ap.inject_failure("gps", lk.plant.time_s)

    return hook


def test_an_estimate_lost_in_flight_hands_the_vehicle_to_its_landing():
    result, link, events = fly_plant(hover(30.0), gps_fails_at(3.0))
    assert result.status is FlightStatus.ESTIMATE_LOST and result.status.exit_code == 11, result.detail
    assert "no longer vouches for its horizontal velocity, horizontal position" in result.detail
    assert result.detail.endswith("handed to the vehicle's landing")
    assert result.landed and result.disarmed
    assert command_sequence(link)[-2:] == [(mavlink.MAV_CMD_NAV_LAND, 0.0), (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)]
    t = result.record["t_s"]
    # EKF2 dead-reckons 5 s (the plant as PX4), its ESTIMATOR_STATUS comes at 1 Hz; mission time is ~0.8 s behind the plant's
    assert 3.0 + 5.0 - 1.0 < t[-1] < 3.0 + 5.0 + 1.0 and len(t) < 200
    # the GPS unhealthy at once; as PX4 v1.16, the position control unhealthy with the estimate, the GPS
    # dropped from present 2 s later
    assert result.notes[:3] == ["vehicle: GPS unhealthy (SYS_STATUS)", "vehicle: horizontal position control unhealthy (SYS_STATUS)",
                                "vehicle: GPS no longer reported (SYS_STATUS)"]  # fmt: skip
    # from the end of the mission to the landing: level at the heading flown, hover thrust (the law,
    # following EKF2's dead reckoning, had the vehicle tilted)
    land_at = next(i for i, m in enumerate(link.sent) if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_NAV_LAND)
    last_law = [m for m in link.sent[:land_at] if m.get_type() == "SET_ATTITUDE_TARGET"][-1]
    level = [m for m in link.sent[land_at:] if m.get_type() == "SET_ATTITUDE_TARGET"][0]
    assert abs(last_law.q[1]) + abs(last_law.q[2]) > 1e-3
    assert level.q[1] == pytest.approx(0.0, abs=1e-9) and level.q[2] == pytest.approx(0.0, abs=1e-9)
    assert level.thrust == pytest.approx(0.25, abs=0.01)  # the paper's quad hovers at 0.25


def test_ignore_estimator_flies_on():
    """... on the dead-reckoned estimate, as on PX4 (flown so, its estimate ran 21 m from the truth
    in 10 s, and the vehicle 20 m the other way): the flight's record holds the reference while
    the vehicle itself leaves it, the opposite way to the estimate's drift."""
    flown: list[tuple[np.ndarray, np.ndarray]] = []  # (truth, report) while the offboard flies it

    def hook(lk: PlantLink) -> None:
        gps_fails_at(1.0)(lk)
        if lk.plant.autopilot.mode is Mode.OFFBOARD and lk.plant.autopilot.armed:
            flown.append((lk.plant.sim.truth().pos_ned_m.copy(), lk.plant.measured().pos_ned_m.copy()))

    result, _, _ = fly_plant(hover(10.0), hook, FlightConfig(lockstep=True, connect="test", watch_estimator=False))
    assert result.status is FlightStatus.COMPLETE, result.detail
    assert "vehicle: GPS no longer reported (SYS_STATUS)" in result.notes  # still said
    t, err = result.record["t_s"], np.linalg.norm(result.record.error_ned_m, axis=1)
    assert np.max(err[t > 5.0]) < 0.1  # the estimate held on the reference (from the start's transient on)
    truth, report = flown[-1]
    drift = (report - truth)[:2]  # about 15 m in the 8.5 s from the loss to the mission's end
    assert np.linalg.norm(drift) > 5.0
    assert np.linalg.norm(truth[:2] + drift) < 0.1 * np.linalg.norm(drift)  # the vehicle went where the estimate did not (the reference: x = y = 0)


def test_a_reference_running_away_is_lost_track_in_flight():
    """A reference at 40 m/s: no quadrotor of 35 degrees of tilt keeps up; the flight ends where it
    is lost, not at the mission's end, and the vehicle lands where it is."""
    runaway = Line((0.0, 0.0, -1.0), (2000.0, 0.0, -1.0), 40.0, yaw_rad=0.0)
    result, link, _ = fly_plant(runaway)
    assert result.status is FlightStatus.LOST_TRACK and result.status.exit_code == 9, result.detail
    assert "not closing" in result.detail and result.detail.endswith("handed to the vehicle's landing")
    t, err = result.record["t_s"], np.linalg.norm(result.record.error_ned_m, axis=1)
    assert t[-1] < 10.0 < runaway.duration_s  # ended in flight
    above = err > LOST_TRACK_M
    assert above[-round(LOST_TRACK_WINDOW_S / DT) - 1:].all() and err[-1] >= err[-round(LOST_TRACK_WINDOW_S / DT) - 1]
    assert result.landed and result.disarmed


def test_lost_track_in_flight_can_be_switched_off():
    runaway = Line((0.0, 0.0, -1.0), (200.0, 0.0, -1.0), 40.0, yaw_rad=0.0)
    result, _, _ = fly_plant(runaway, config=FlightConfig(lockstep=True, connect="test", lost_track_m=math.inf))
    assert result.status is FlightStatus.COMPLETE  # flown to its end (the end's verdict is metrics.check_tracking's)
    assert result.record["t_s"][-1] == pytest.approx(runaway.duration_s, abs=DT)


def test_a_landing_that_fails_after_a_guard_is_said_in_the_detail():
    """The guard's end stays the status; a NAV_LAND that never gets through is added to its detail."""
    link = PlantLink(make_plant(), FakeClock())
    link.drop = lambda msg: msg.get_type() == "COMMAND_LONG" and msg.command == mavlink.MAV_CMD_NAV_LAND
    link.hook = gps_fails_at(2.0)
    flight = Flight(link, hover(30.0), ControllerChoice(base=PAPER), FlightConfig(lockstep=True, connect="test"), clock=link.clock)
    result = flight.run()
    assert result.status is FlightStatus.ESTIMATE_LOST
    assert "handed to the vehicle's landing; then the landing failed: MAV_CMD_NAV_LAND" in result.detail, result.detail
    assert not result.landed
