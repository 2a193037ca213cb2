"""A GPS lost in Hold, on the real PX4 v1.16 SITL and on ``sitl-plant``, side by side.

PX4's GPS is stopped from its shell (``sensor_gps_sim stop``: its SIH build never answers
MAV_CMD_INJECT_FAILURE), the plant's by MAV_CMD_INJECT_FAILURE. Both dead-reckon, then EKF2 stops
vouching for the horizontal velocity and position (ESTIMATOR_STATUS 0x37f to 0x365) and the
failsafe lands blind: Land, system status CRITICAL, "Failsafe activated" (measured by hand in
real time: 5.1-5.2 s after the stop; docs/plant.md). What ``offboard fly`` does with the same
loss in Offboard is tests/e2e/test_px4_flight.py's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from pymavlink import mavutil

from helpers.commander import AUTO_LAND, AUTO_LOITER, Client, fly_side_by_side, heartbeat_state, heartbeat_text, settle_heartbeat

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py

mavlink = mavutil.mavlink
SPEED = 4.0
POSITION_FLAGS = mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_HORIZ_ABS


@dataclass
class GpsLoss:
    flags_before: int
    flags_lost: int  # the first ESTIMATOR_STATUS without the horizontal position
    flags_lost_after_s: float  # vehicle time from the GPS's stop
    failsafe_after_s: float
    heartbeat: tuple[int, tuple[int, int], int]
    mode_before_failsafe: tuple[int, int]
    hold_asked: tuple[list[int], tuple[int, int]]  # Hold asked for after the failsafe: its ACKs, the mode then
    #: how far the estimate (LOCAL_POSITION_NED) is from the truth (HIL_STATE_QUATERNION), horizontally,
    #: DRIFT_AT_S after the GPS's stop, less what it was in the second before (where the frames' origins differ)
    drift_m: float


#: when the dead reckoning's error is read: before the failsafe's Land (5 s) changes what the vehicle does
DRIFT_AT_S = 4.5
EARTH_RADIUS_M = 6378137.0


def estimate_error_m(c: Client, t_stop: float, at_s: float) -> float:
    """The horizontal distance of the estimate from the truth ``at_s`` after ``t_stop`` (vehicle
    time), less the mean offset of the second before the stop (the two frames' origins)."""
    truth = np.array(c.truths)
    est = np.array([(s.t_s, *s.pos_ned_m) for s in c.samples])
    lat0, lon0 = truth[0, 1], truth[0, 2]
    north = np.radians(truth[:, 1] - lat0) * EARTH_RADIUS_M
    east = np.radians(truth[:, 2] - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))

    def error(t: float) -> np.ndarray:
        return np.array([np.interp(t, est[:, 0], est[:, 1]) - np.interp(t, truth[:, 0], north),
                         np.interp(t, est[:, 0], est[:, 2]) - np.interp(t, truth[:, 0], east)])  # fmt: skip

    offset = np.mean([error(t_stop - 1.0 + 0.1 * k) for k in range(10)], axis=0)
    return float(np.hypot(*(error(t_stop + at_s) - offset)))


def lose_gps_in_hold(c: Client) -> GpsLoss:
    c.connect()
    c.pump(1.0)
    assert c.wait(lambda: len(c.samples) >= 10, 30.0, SPEED), "no LOCAL_POSITION_NED"
    ground = c.down_m
    c.take_off(ground, SPEED, 40.0)
    assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 20000)[-1:] == [
        mavlink.MAV_RESULT_ACCEPTED]  # the simulator's truth, 50 Hz
    c.wait_sim(2.0)
    assert len(c.truths) > 20, "no HIL_STATE_QUATERNION"
    assert c.estimator_flags, "no ESTIMATOR_STATUS"
    flags_before = c.estimator_flags[-1][1]
    assert c.fail_gps is not None
    t_stop = c.t_s
    c.fail_gps()
    failsafe = lambda: any("Failsafe activated" in text for t, text in c.texts if t >= t_stop)  # noqa: E731
    assert c.wait(failsafe, 15.0, SPEED), f"no failsafe on {c.port}: mode {c.mode}, texts {c.texts[-5:]}"
    t_fs = next(t for t, text in c.texts if t >= t_stop and "Failsafe activated" in text)
    mode_before = c.mode
    settle_heartbeat(c)
    c.wait_sim(1.0)
    lost = next(((t, f) for t, f in c.estimator_flags if t >= t_stop and not f & mavlink.ESTIMATOR_POS_HORIZ_REL), None)
    assert lost is not None, f"the estimator still vouches for the position: {c.estimator_flags[-3:]}"
    heartbeat = heartbeat_state(c)
    acks = c.set_mode(AUTO_LOITER)
    c.wait_sim(0.5)
    return GpsLoss(flags_before, lost[1], lost[0] - t_stop, t_fs - t_stop, heartbeat, mode_before, (acks, c.mode),
                   estimate_error_m(c, t_stop, DRIFT_AT_S))  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(PX4, plant): the GPS lost in Hold on both, side by side."""
    px4, plant = fly_side_by_side(tmp_path_factory.mktemp("px4"), SPEED, lose_gps_in_hold)
    for name, r in (("PX4", px4), ("plant", plant)):
        print(f"{name:5}: flags 0x{r.flags_before:x} -> 0x{r.flags_lost:x} {r.flags_lost_after_s:.1f} s after the stop, "
              f"failsafe at {r.failsafe_after_s:.1f} s, {heartbeat_text(r.heartbeat)}, "
              f"estimate {r.drift_m:.2f} m from the truth {DRIFT_AT_S:g} s after the stop")
    return px4, plant


def test_ekf2_stops_vouching_for_the_position_as_px4s(runs):
    px4, plant = runs
    assert px4.flags_before == plant.flags_before == 0x37F  # EKF2 in the air, converged on GPS
    assert not px4.flags_lost & POSITION_FLAGS and px4.flags_lost & mavlink.ESTIMATOR_ATTITUDE
    assert plant.flags_lost == px4.flags_lost
    # EKF2_NOAID_TOUT's 5 s of dead reckoning; PX4's ESTIMATOR_STATUS comes at 1 Hz, our shell call takes some
    assert abs(plant.flags_lost_after_s - px4.flags_lost_after_s) < 1.5, (plant.flags_lost_after_s, px4.flags_lost_after_s)


def test_hold_lands_blind_as_px4s(runs):
    px4, plant = runs
    assert px4.mode_before_failsafe == AUTO_LOITER  # dead reckoning in Hold until then
    assert px4.heartbeat[1:] == (AUTO_LAND, mavlink.MAV_STATE_CRITICAL)
    assert plant.heartbeat == px4.heartbeat
    assert abs(plant.failsafe_after_s - px4.failsafe_after_s) < 1.5, (plant.failsafe_after_s, px4.failsafe_after_s)


def test_hold_is_refused_without_a_position(runs):
    """Hold asked for after the failsafe: the receiver's ACCEPTED, the commander's TEMPORARILY_REJECTED
    (PX4's two acks), and the vehicle keeps landing."""
    px4, plant = runs
    assert px4.hold_asked == ([mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_TEMPORARILY_REJECTED], AUTO_LAND)
    assert plant.hold_asked == px4.hold_asked


def test_the_estimate_dead_reckons_away_from_the_truth_as_px4s(runs):
    """Without the GPS EKF2 integrates its accelerometer: 4.5 s after the stop PX4's estimate in Hold
    is 0.7-0.9 m from SIH's truth (two runs; before the stop, centimetres), in an Offboard flight
    flown on the estimate 2.6-4.2 m at 4 s (four flights, bench/px4_dead_reckoning.py). SIM_DR_ACC_ERR
    is fitted to the second, the situation of the plant's offboard clients: 1/2 b t^2 = 4.05 m
    (the plant's Hold flies on the truth whatever its estimate says)."""
    px4, plant = runs
    assert 0.3 < px4.drift_m < 15.0, px4.drift_m
    assert plant.drift_m == pytest.approx(0.5 * 0.4 * DRIFT_AT_S**2, abs=0.3)
