"""Follow Target (sitl_plant/follow.py and the autopilot's AUTO_FOLLOW_TARGET), pure: the target
estimator, the flight task flown by a vehicle that is where it is asked to be, and the mode's
entry, arming and heartbeat through the plant's message handling.

What PX4 v1.16 SITL did is in docs/parity/commander.md (Follow Target rows)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pymavlink.dialects.v20 import common as mavlink

from offboard.model.vehicle import VehicleParams
from sitl_plant.autopilot import Autopilot, IdleTask, Mode, PositionTask
from sitl_plant.follow import STALE_TIMEOUT_S, FollowTarget, TargetEstimator, estimator_gains
from sitl_plant.params import plant_params

GCS = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
_PARSER = mavlink.MAVLink(None)
DT = 0.01  # PX4's estimator runs every 10 ms
FOLLOW_MODE = (4, 8)


def wire(msg):
    return _PARSER.parse_buffer(msg.pack(GCS))[0]


def test_estimator_gains_are_px4s_for_the_default_responsiveness():
    g_p, h_p, k_p, g_v, h_v = estimator_gains(0.1)
    beta = 0.1 ** (1 / 3)
    assert_allclose((g_p, h_p, k_p), (0.9, 1.5 * (1 - beta) ** 2 * (1 + beta), 0.5 * (1 - beta) ** 3))
    assert_allclose((g_v, h_v), (1 - (0.9 * beta) ** 2, (1 - 0.9 * beta) ** 2))
    assert estimator_gains(0.0) == estimator_gains(0.1)  # PX4 clips FLW_TGT_RS to [0.1, 1]


def _track(est: TargetEstimator, seconds: float, speed=(1.5, 0.0), report_every_s: float = 0.2, t0: float = 0.0, stop_s=math.inf):
    """Reports of a target moving at ``speed`` (m/s, north and east) from the origin, every
    ``report_every_s`` until ``stop_s``; the estimate predicted every 10 ms. The target's last
    true position."""
    truth = (0.0, 0.0)
    next_report = t0
    for k in range(round(seconds / DT) + 1):
        t = t0 + k * DT
        truth = (speed[0] * min(t, stop_s), speed[1] * min(t, stop_s))
        if k:
            est.predict(t, DT)
        if t >= next_report - 1e-9 and t <= stop_s:
            est.report(t, (truth[0], truth[1], 0.0), (speed[0], speed[1], 0.0))
            next_report += report_every_s
    return truth


def test_the_estimate_tracks_a_target_at_constant_speed():
    est = TargetEstimator(0.1)
    truth = _track(est, 20.0)
    assert est.valid
    assert_allclose(est.pos[:2], truth, atol=0.05)
    assert_allclose(est.vel[:2], (1.5, 0.0), atol=0.02)


def test_a_lost_target_is_dead_reckoned_for_3_s_then_its_estimate_stops():
    est = TargetEstimator(0.1)
    last = _track(est, 30.0, stop_s=20.0)
    # PX4's TargetEstimator: after GPS_MESSAGE_STALE_TIMEOUT_MS (3 s) velocity and acceleration are zeroed
    assert STALE_TIMEOUT_S == 3.0
    assert est.valid and est.vel == (0.0, 0.0, 0.0)
    assert est.pos[0] == pytest.approx(last[0] + 1.5 * 3.0, abs=0.1)


def test_positions_are_fused_at_most_every_half_second():
    est = TargetEstimator(0.1)
    est.report(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    est.report(0.2, (5.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # too soon after the first: not fused
    assert est.pos == (0.0, 0.0, 0.0)
    est.report(0.6, (5.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert est.pos[0] == pytest.approx(0.9 * 5.0)  # G_p = 1 - FLW_TGT_RS


# --- the flight task, flown by a vehicle that is where it is asked to be ---------------------------


def _follow(params=None, seconds=40.0, speed=(1.5, 0.0), start=(0.0, 0.0, -8.0), stop_s=math.inf, yaw=0.0):
    """FollowTarget flown perfectly (the vehicle at the setpoint each step) after a target that
    starts 10 m north of the origin; home at the origin. The vehicle's last position, yaw
    setpoint, the target's last true position and every setpoint."""
    params = params or plant_params(VehicleParams())
    task = FollowTarget(params)
    task.activate(yaw, 0.0, 0.0)
    pos = start
    sps = []
    next_report = 0.0
    truth = (10.0, 0.0)
    for k in range(round(seconds / DT) + 1):
        t = k * DT
        tt = min(t, stop_s)
        truth = (10.0 + speed[0] * tt, speed[1] * tt)
        if t >= next_report - 1e-9 and t <= stop_s:
            task.report(t, (truth[0], truth[1], 0.0), (speed[0], speed[1], 0.0))
            next_report += 0.2
        sp = task.step(t, pos)
        sps.append(sp)
        if sp is not None:
            pos = sp.pos_ned_m
    return pos, task.yaw_sp, truth, sps


def _relative(pos, target):
    """Distance (m) and bearing (deg, from north towards east) of the vehicle from the target."""
    dn, de = pos[0] - target[0], pos[1] - target[1]
    return math.hypot(dn, de), math.degrees(math.atan2(de, dn))


def test_the_vehicle_takes_its_place_behind_at_the_follow_distance_and_height_facing_the_target():
    pos, yaw, target, _ = _follow()
    dist, bearing = _relative(pos, target)
    assert dist == pytest.approx(8.0, abs=0.1)  # FLW_TGT_DST
    assert abs(abs(bearing) - 180.0) < 1.0  # FLW_TGT_FA 180: behind a target going north
    assert pos[2] == pytest.approx(-8.0)  # FLW_TGT_HT above home
    assert yaw == pytest.approx(0.0, abs=0.02)  # the nose on the target


@pytest.mark.parametrize("angle, course, expected", [(90.0, (1.5, 0.0), 90.0), (-90.0, (0.0, 1.5), 0.0), (0.0, (0.0, -1.5), -90.0)])
def test_the_follow_angle_is_measured_clockwise_from_the_targets_course(angle, course, expected):
    params = plant_params(VehicleParams())
    params.set("FLW_TGT_FA", angle)
    pos, yaw, target, _ = _follow(params, seconds=60.0, speed=course)
    dist, bearing = _relative(pos, target)
    assert dist == pytest.approx(8.0, abs=0.15)
    assert bearing == pytest.approx(expected, abs=1.5)
    facing = math.degrees(yaw) - (expected + 180.0)  # the nose on the target: the bearing turned round
    assert abs((facing + 180.0) % 360.0 - 180.0) < 2.0


def test_height_above_the_target_in_altitude_mode_2():
    params = plant_params(VehicleParams())
    params.set("FLW_TGT_ALT_M", 2)
    params.set("FLW_TGT_HT", 10.0)
    task = FollowTarget(params)
    task.activate(0.0, 0.0, 0.0)
    task.report(0.0, (10.0, 0.0, -3.0), (0.0, 0.0, 0.0))  # the target 3 m above home
    sp = task.step(0.01, (0.0, 0.0, -12.0))
    assert sp.pos_ned_m[2] == pytest.approx(-13.0)


def test_far_from_the_height_only_the_height_is_flown():
    task = FollowTarget(plant_params(VehicleParams()))
    task.activate(0.0, 0.0, 0.0)
    task.report(0.0, (10.0, 0.0, 0.0), (1.5, 0.0, 0.0))
    sp = task.step(0.01, (1.0, 2.0, -2.5))  # 5.5 m below the follow height: more than 3 m
    assert sp.pos_ned_m == (1.0, 2.0, -8.0) and sp.vel_ned_m_s == (0.0, 0.0, 0.0)
    sp = task.step(0.02, (1.0, 2.0, -5.5))  # within 3 m: the place about the target
    assert sp.pos_ned_m[:2] != (1.0, 2.0)


def test_the_orbit_angle_turns_no_faster_than_flw_tgt_max_vel():
    params = plant_params(VehicleParams())
    params.set("FLW_TGT_MAX_VEL", 2.0)
    _, _, _, sps = _follow(params, seconds=20.0)
    speeds = [math.hypot(a.vel_ned_m_s[0] - 1.5, a.vel_ned_m_s[1]) for a in sps if a is not None and a.vel_ned_m_s != (0.0, 0.0, 0.0)]
    assert max(speeds) <= 2.0 + 0.1  # the tangential part, on top of the target's filtered velocity (about 1.5)
    assert max(speeds) > 1.5  # it did swing round (from angle 0, PX4's start, to 180)


def test_without_reports_there_is_no_setpoint_and_a_lost_target_is_followed_to_its_last_estimate():
    task = FollowTarget(plant_params(VehicleParams()))
    task.activate(0.0, 0.0, 0.0)
    assert task.step(0.5, (0.0, 0.0, -8.0)) is None  # no target yet: the autopilot holds
    pos, _, last, _ = _follow(seconds=50.0, stop_s=30.0)
    # the estimate goes on 3 s at the target's speed, then stops; the vehicle ends 8 m behind it
    assert pos[0] == pytest.approx(last[0] + 1.5 * 3.0 - 8.0, abs=0.3)


# --- the mode, through the plant -------------------------------------------------------------------


def make_plant():
    from sitl_plant.server import Plant, PlantConfig

    vehicle = VehicleParams()
    params = plant_params(vehicle)
    return Plant(PlantConfig(), vehicle, params, Autopilot(params, home_alt_amsl_m=488.0))


def _acks(plant, api):
    return [(m.command, m.result) for m in plant.outbox[api] if m.get_type() == "COMMAND_ACK"]


def test_follow_target_is_accepted_disarmed_arming_in_it_refused_and_flown_in_the_air_as_px4():
    from sitl_plant.server import API

    plant = make_plant()
    ap = plant.autopilot
    set_follow = wire(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, *FOLLOW_MODE, 0, 0, 0, 0))
    plant.handle(API, set_follow)
    assert _acks(plant, API) == [(mavlink.MAV_CMD_DO_SET_MODE, 0), (mavlink.MAV_CMD_DO_SET_MODE, 0)]
    status = ap.status()
    # PX4 v1.16 (measured): custom mode 4/8, base_mode 17, system status UNINIT (the mode prevents arming)
    assert status.mode is Mode.AUTO_FOLLOW_TARGET and status.base_mode == 17 and status.system_status == 0
    assert status.mode.custom_mode == (4 << 16) | (8 << 24)
    plant.outbox[API].clear()
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    assert _acks(plant, API) == [(400, mavlink.MAV_RESULT_TEMPORARILY_REJECTED)]
    assert "".join(m.text for m in plant.outbox[API] if m.get_type() == "STATUSTEXT") == "Arming denied: Resolve system health failures first"
    assert isinstance(ap.task(), IdleTask)
    # take off in Hold, then Follow Target in the air without a target: accepted, holds
    ap.set_mode(Mode.AUTO_LOITER, plant.time_s)
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, 0, 0, 0, 0)))
    for _ in range(2500):  # 10 s
        plant.advance(plant.tick_steps)
    assert ap.mode is Mode.AUTO_LOITER and ap.armed
    here = plant._truth.pos_ned_m.copy()
    plant.outbox[API].clear()
    plant.handle(API, set_follow)
    assert _acks(plant, API)[-1] == (mavlink.MAV_CMD_DO_SET_MODE, 0)
    assert ap.mode is Mode.AUTO_FOLLOW_TARGET and ap.status().base_mode == 145 and ap.status().system_status == 4
    for _ in range(250):
        plant.advance(plant.tick_steps)
    assert_allclose(plant._truth.pos_ned_m, here, atol=0.1)
    # a FOLLOW_TARGET 10 m north (AMSL altitude of home): the vehicle climbs to FLW_TGT_HT and goes for its place
    lat = int(round((47.397742 + math.degrees(10.0 / 6_371_000.0)) * 1e7))
    plant.handle(API, wire(mavlink.MAVLink_follow_target_message(0, 0, lat, 85455940, 488.0, [0.0] * 3, [0.0] * 3,
                                                                 [1.0, 0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 3, 0)))  # fmt: skip
    assert ap.follow.estimator.valid
    assert ap.follow.estimator.pos[0] == pytest.approx(10.0, abs=0.05)
    plant.advance(plant.tick_steps)
    task = ap.task()
    assert isinstance(task, PositionTask) and task.pos_ned_m[2] == pytest.approx(plant.autopilot.home_ned_m[2] - 8.0)
    # leaving the mode and coming back starts afresh (PX4 builds the flight task again)
    ap.set_mode(Mode.AUTO_LOITER, plant.time_s)
    ap.set_mode(Mode.AUTO_FOLLOW_TARGET, plant.time_s)
    assert not ap.follow.estimator.valid
    assert np.isfinite(plant._truth.pos_ned_m).all()
