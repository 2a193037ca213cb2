"""Follow Target against the real PX4 v1.16 SITL: one client script, both vehicles.

``follow_script`` (below) runs the same pymavlink client (tests/helpers/commander.py) against PX4
(SIH quadrotor) and against ``sitl-plant``, both at ``--speed 4``, at the same time (a thread
each). On each it switches to Follow Target disarmed, takes off in Hold, switches to Follow
Target 1.5 m up, then streams FOLLOW_TARGET for a target that starts 8 m south of the vehicle
and walks south at 1.5 m/s (5 reports a second of vehicle time, position and velocity, at the
altitude of home), and after a while stops the stream. South, because PX4 starts the orbit angle
at 0 (the vehicle's place north of the target), which is behind a target going south: the
vehicle need not swing round it first (8-10 s of PX4's time for a target going north), and the
script stays short. It records where each vehicle puts itself
about the target (distance and bearing from the target, height above where it armed, heading)
and where it stops once the target is lost. Default parameters: FLW_TGT_DST 8 m, FLW_TGT_FA 180
(behind), FLW_TGT_HT 8 m above home.

Figures measured while this was written are in docs/parity/commander.md (Follow Target rows).
"""

from __future__ import annotations

import math

import pytest
from pymavlink import mavutil

from helpers.commander import (AUTO_LOITER, Observed, Client, fly_side_by_side, heartbeat_state, heartbeat_text, print_figures, results_text, settle_heartbeat)  # fmt: skip

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py

mavlink = mavutil.mavlink
SPEED = 4.0  # PX4's --speed (the page of findings says it)
NAN = math.nan
FOLLOW = (4, 8)  # AUTO_FOLLOW_TARGET
EARTH_RADIUS_M = 6_371_000.0
TARGET_SPEED_M_S = -1.5  # north (so south)
TARGET_AHEAD_M = -8.0  # where the target starts, north of the vehicle
REPORT_EVERY_S = 0.2  # vehicle time
FOLLOW_S = 20.0  # the stream, vehicle time
STEADY_FROM_S = 10.0  # both have climbed to the follow height and settled behind the target by then
LOST_S = 9.0  # after the stream stops: 3 s of dead reckoning, then the vehicle settles (PX4 in 6-9 s)




def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


#: Streams the script does not read, off, and fewer of those it reads (interval in vehicle time,
#: us): each vehicle sends about 1 500 messages a second of wall time at speed 4, and one client
#: process parsing 3 000 a second fell behind on a loaded machine (its view of the vehicle's clock,
#: which stamps the target's reports, lagged by seconds).
QUIET_STREAMS = {105: -1, 31: -1, 331: -1,  # HIGHRES_IMU, ATTITUDE_QUATERNION, ODOMETRY (a MAVLink 2 message)
                 30: 50_000, 33: 200_000}  # ATTITUDE at 20 Hz, GLOBAL_POSITION_INT at 5 Hz  # fmt: skip


def follow_script(c: Client) -> Observed:
    obs = Observed()
    c.connect()
    for message_id, interval_us in QUIET_STREAMS.items():
        c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, interval_us, settle_s=0.0)
    c.pump(0.5)
    obs.acks["follow disarmed"] = c.set_mode(FOLLOW)
    settle_heartbeat(c)
    obs.heartbeat["follow disarmed"] = heartbeat_state(c)
    c.set_mode(AUTO_LOITER)
    c.pump(0.3)
    ground = c.down_m
    c.arm()
    c.command(mavlink.MAV_CMD_NAV_TAKEOFF, NAN, 0, 0, NAN, NAN, NAN, NAN, settle_s=0.0)
    c.wait(lambda: c.down_m < ground - 1.5, 30.0, SPEED)
    # the target's frame: the vehicle's global and local position now (a flat earth over 100 m)
    gp = c.conn.messages["GLOBAL_POSITION_INT"]
    n0, e0, _ = c.samples[-1].pos_ned_m
    lat0, lon0, home_amsl = gp.lat * 1e-7, gp.lon * 1e-7, (gp.alt - gp.relative_alt) / 1000.0
    obs.acks["follow armed"] = c.set_mode(FOLLOW)
    t0 = c.t_s

    def target_at(t: float) -> tuple[float, float]:
        return n0 + TARGET_AHEAD_M + TARGET_SPEED_M_S * (t - t0), e0

    def report(t: float) -> None:
        n, e = target_at(t)
        lat = lat0 + math.degrees((n - n0) / EARTH_RADIUS_M)
        lon = lon0 + math.degrees((e - e0) / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        c.conn.mav.follow_target_send(int(t * 1000), 0b11, int(round(lat * 1e7)), int(round(lon * 1e7)), home_amsl,
                                      [TARGET_SPEED_M_S, 0.0, 0.0], [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 3, 0)  # fmt: skip

    steady: list[tuple[float, float, float, float]] = []  # distance, bearing, height, yaw (deg)
    next_report, last_report, report_gap = t0, t0, 0.0
    while c.t_s < t0 + FOLLOW_S:
        if c.t_s >= next_report:
            report(c.t_s)
            report_gap, last_report = max(report_gap, c.t_s - last_report), c.t_s
            next_report = c.t_s + REPORT_EVERY_S
        c.pump(0.02)
        s = c.samples[-1]
        if s.t_s >= t0 + STEADY_FROM_S:
            tn, te = target_at(s.t_s)
            dn, de = s.pos_ned_m[0] - tn, s.pos_ned_m[1] - te
            # bearing and heading as deviations from behind the target going south (0 deg)
            steady.append((math.hypot(dn, de), math.degrees(math.atan2(de, dn)), ground - s.pos_ned_m[2], math.degrees(c.attitude_yaw) - 180.0))
    obs.heartbeat["follow armed, target streaming"] = heartbeat_state(c)
    obs.figures["longest gap between reports (s)"] = report_gap
    assert len(steady) > 20 and report_gap < 1.5, (
        f"the client fell behind its vehicle ({len(steady)} samples, reports up to {report_gap:.1f} s of vehicle time apart): "
        "the machine was too loaded to stream the target")
    obs.figures["steady: distance from the target (m)"] = sum(x[0] for x in steady) / len(steady)
    obs.figures["steady: bearing from the target, off behind (deg)"] = sum(_wrap_deg(x[1]) for x in steady) / len(steady)
    obs.figures["steady: worst bearing off behind (deg)"] = max(abs(_wrap_deg(x[1])) for x in steady)
    obs.figures["steady: height above the ground at arming (m)"] = sum(x[2] for x in steady) / len(steady)
    obs.figures["steady: heading off the target's course (deg)"] = sum(_wrap_deg(x[3]) for x in steady) / len(steady)
    obs.figures["steady: worst heading off the course (deg)"] = max(abs(_wrap_deg(x[3])) for x in steady)
    obs.figures["steady: distance spread (m)"] = max(x[0] for x in steady) - min(x[0] for x in steady)
    # -- the stream stops ---------------------------------------------------------------------------
    t_stop = c.t_s
    last_n, last_e = target_at(t_stop)
    c.wait_sim(LOST_S)
    # the last 2 s, averaged: PX4's hold wanders by a few tenths (its EKF on SIH)
    end = [s for s in c.samples if s.t_s >= c.t_s - 2.0]
    n, e = (sum(s.pos_ned_m[i] for s in end) / len(end) for i in (0, 1))
    obs.figures["lost: behind the last report (m)"] = n - last_n  # along the target's course (south)
    obs.figures["lost: east of the last report (m)"] = e - last_e
    obs.figures["lost: mean speed over the last 2 s (m/s)"] = math.hypot(*((end[-1].pos_ned_m[i] - end[0].pos_ned_m[i]) / max(end[-1].t_s - end[0].t_s, 1e-3) for i in (0, 1)))
    obs.texts["lost"] = c.texts_since(t_stop)
    obs.heartbeat["lost"] = heartbeat_state(c)
    return obs


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(PX4, plant): the script flown on both, side by side."""
    result = fly_side_by_side(tmp_path_factory.mktemp("px4"), SPEED, follow_script)
    print_figures(result)
    print("PX4", result[0].heartbeat, result[0].texts, "\nplant", result[1].heartbeat, result[1].texts)
    return result


def test_follow_target_is_entered_and_reported_as_px4(runs, parity_finding):
    px4, plant = runs
    for what in ("follow disarmed", "follow armed"):
        parity_finding(f"commander.follow.acks.{what}", f"Follow Target, {what.removeprefix('follow ')}: the COMMAND_ACKs",
                       results_text(px4.acks[what]), results_text(plant.acks[what]))  # fmt: skip
    for what in px4.heartbeat:
        parity_finding(f"commander.follow.heartbeat.{what}", f"Follow Target, {what.removeprefix('follow ')}: heartbeat "
                       "mode, base_mode / system_status", heartbeat_text(px4.heartbeat[what]),
                       heartbeat_text(plant.heartbeat.get(what)))  # fmt: skip
    assert px4.acks["follow disarmed"] == [0, 0] and px4.acks["follow armed"] == [0, 0]
    assert px4.heartbeat["follow disarmed"] == (17, FOLLOW, 0)  # UNINIT: the mode prevents arming
    assert px4.heartbeat["follow armed, target streaming"] == (145, FOLLOW, 4)
    assert plant.acks == px4.acks
    assert plant.heartbeat == px4.heartbeat  # after the target is lost too: the mode stays, no failsafe


def test_the_vehicle_keeps_px4s_place_behind_the_target(runs, parity_finding):
    """Measured over 10-20 s after the first report, in fourteen runs at speed 4 on a loaded 2-core
    machine (load 4-11): PX4 8.14-8.39 m from the target, its mean bearing within 2.2 deg of
    straight behind (at worst 5.8 deg), 7.71-8.31 m above where it armed, its heading within 2.0
    deg of the target's course (at worst 6.0 deg); the plant 7.99-8.05 m, 0.0 deg, 8.00 m, 0.0 deg.
    PX4 trails by a few tenths more: SIH's drag (SIH_KDV) against its position loop, which the
    plant's default vehicle hardly has."""
    px4, plant = runs
    f, g = px4.figures, plant.figures
    for name in (n for n in f if n.startswith("steady: ")):
        parity_finding(f"commander.follow.{name}", f"Follow Target, a target walking at 1.5 m/s, {name}", f[name], g.get(name))
    name = "steady: distance from the target (m)"
    assert g[name] == pytest.approx(f[name], abs=0.6)
    name = "steady: bearing from the target, off behind (deg)"
    assert abs(g[name] - f[name]) < 5.0
    name = "steady: height above the ground at arming (m)"
    assert g[name] == pytest.approx(f[name], abs=0.6)  # PX4's EKF height wanders by a few tenths
    name = "steady: heading off the target's course (deg)"
    assert abs(g[name] - f[name]) < 5.0
    for obs in runs:
        assert obs.figures["steady: worst bearing off behind (deg)"] < 10.0
        assert obs.figures["steady: worst heading off the course (deg)"] < 10.0


def test_a_lost_target_is_dead_reckoned_then_the_vehicle_holds_behind_it_as_px4(runs, parity_finding):
    """The estimate goes on 3 s at 1.5 m/s, then stops, and the vehicle holds 8 m behind that:
    3.5 m behind the last report. PX4 ended 3.20-3.90 m behind in fourteen runs, the plant
    3.59-5.02 m: the estimator's acceleration (2 K / dt^2 of each position innovation, and the
    reports' delivery jitters on a loaded machine) is dead-reckoned for those 3 s too, 0.5 a t^2,
    about a metre either way. Neither says anything nor changes mode (PX4 v1.16 keeps Follow
    Target, 145 / 4); PX4's hold wanders at up to 0.3 m/s, the plant's settles."""
    px4, plant = runs
    f, g = px4.figures, plant.figures
    for name in (n for n in f if n.startswith("lost: ")):
        parity_finding(f"commander.follow.{name}", f"Follow Target, the reports stopped: {name}", f[name], g.get(name))
    name = "lost: behind the last report (m)"
    assert g[name] == pytest.approx(f[name], abs=2.0)
    assert abs(g["lost: east of the last report (m)"] - f["lost: east of the last report (m)"]) < 1.0
    for obs in runs:
        assert 2.0 < obs.figures[name] < 6.0
        assert obs.figures["lost: mean speed over the last 2 s (m/s)"] < 0.5
        assert obs.texts["lost"] == []
