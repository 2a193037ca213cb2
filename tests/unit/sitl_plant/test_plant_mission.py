"""The mission protocol (sitl_plant/mission.py) and the navigator (sitl_plant/navigator.py), pure:
pymavlink-encoded messages in, the answers out, and a vehicle that flies its setpoints exactly.

The expected exchanges are the ones measured on PX4 v1.16 SITL (docs/parity/mission.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from helpers.mission_client import items_from_file
from offboard.missions import MISSIONS_DIR
from sitl_plant import codec
from sitl_plant.autopilot import Autopilot, Command, IdleTask, Mode
from sitl_plant.mission import RETRY_S, TIMEOUT_S, MissionManager, TransferState
from sitl_plant.navigator import Frame, Navigator, corner_speed_m_s, geodetic_to_ned, orbit_limits
from sitl_plant.params import plant_params
from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams

GCS = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
OTHER = mavlink.MAVLink(None, srcSystem=254, srcComponent=1)
_PARSER = mavlink.MAVLink(None)
BOX = items_from_file(MISSIONS_DIR / "px4-sitl-box.waypoints")
HOME = Frame(47.397742, 8.545594, 488.0)


def wire(msg, sender=GCS):
    return _PARSER.parse_buffer(msg.pack(sender))[0]


def item_int(it, seq, mission_type=0, current=0):
    return mavlink.MAVLink_mission_item_int_message(1, 1, seq, it.frame, it.command, current, it.autocontinue, *it.params, it.x, it.y, it.z, mission_type)


def kinds(outs):
    return [(o.kind, o.fields[0]) for o in outs]


def upload(mm, items, mission_type=0, now=0.0):
    """A ground station's upload, answering every request; returns the exchange."""
    log = []
    outs = mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, len(items), mission_type)), now)
    while outs:
        out = outs.pop(0)
        log.append((out.kind, out.fields[0]))
        if out.kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            outs += mm.handle(wire(item_int(items[out.fields[0]], out.fields[0], mission_type)), now)
    return log


def test_the_first_upload_after_boot_requests_in_float_mode_then_int_as_px4_1_16():
    mm = MissionManager()
    log = upload(mm, BOX)
    # PX4 v1.16 SITL, freshly booted: MISSION_REQUEST 0, then MISSION_REQUEST_INT 1.. once an INT item came
    assert log[0] == ("MISSION_REQUEST", 0)
    assert log[1:-1] == [("MISSION_REQUEST_INT", s) for s in range(1, 7)]
    assert log[-1] == ("MISSION_ACK", mavlink.MAV_MISSION_ACCEPTED)
    assert mm.mission_current() == (0, 7, 0, 0)
    # the next upload asks in INT mode from the start
    assert upload(mm, BOX[:2])[0] == ("MISSION_REQUEST_INT", 0)


def test_download_gives_the_items_back_as_uploaded():
    mm = MissionManager()
    upload(mm, BOX)
    outs = mm.handle(wire(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 1.0)
    assert kinds(outs) == [("MISSION_COUNT", 7)]
    got = []
    for seq in range(7):
        (out,) = mm.handle(wire(mavlink.MAVLink_mission_request_int_message(1, 1, seq, 0)), 1.0)
        msg = wire(codec.mission_message(out))
        assert msg.get_type() == "MISSION_ITEM_INT" and msg.seq == seq
        got.append((msg.frame, msg.command, (msg.param1, msg.param2, msg.param3, msg.param4), msg.x, msg.y, msg.z, msg.autocontinue))
    sent = [(it.frame, it.command, it.params, it.x, it.y, it.z, it.autocontinue) for it in BOX]
    assert [g[:2] + g[3:] for g in got] == [s[:2] + s[3:] for s in sent]
    np.testing.assert_allclose([g[2] for g in got], [s[2] for s in sent], equal_nan=True)
    assert mm.handle(wire(mavlink.MAVLink_mission_ack_message(1, 1, 0, 0)), 1.0) == []
    assert mm.state is TransferState.IDLE


def test_a_legacy_request_gets_a_float_mission_item_in_degrees():
    mm = MissionManager()
    upload(mm, BOX)
    mm.handle(wire(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 0.0)
    (out,) = mm.handle(wire(mavlink.MAVLink_mission_request_message(1, 1, 0, 0)), 0.0)
    msg = wire(codec.mission_message(out))
    assert msg.get_type() == "MISSION_ITEM" and msg.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    assert msg.x == pytest.approx(47.397742, abs=1e-5) and msg.current == 1


def test_an_unanswered_request_is_repeated_then_the_transfer_times_out():
    mm = MissionManager()
    mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 0.0)
    assert mm.update(RETRY_S * 0.9) == []
    assert kinds(mm.update(RETRY_S * 1.1)) == [("MISSION_REQUEST", 0)]
    assert kinds(mm.update(TIMEOUT_S + 0.01)) == [("MISSION_REQUEST", 0)]  # PX4: a retry is due first,
    outs = mm.update(TIMEOUT_S + 0.02)  # the timeout on the next pass
    assert [o.fields for o in outs if o.kind == "STATUSTEXT"] == [(2, "Operation timeout")]
    assert mm.state is TransferState.IDLE and mm.update(TIMEOUT_S + 1.0) == []


@pytest.mark.parametrize("frame, command, params, result", [
    (mavlink.MAV_FRAME_LOCAL_NED, 16, (0, 0, 0, 0), mavlink.MAV_MISSION_UNSUPPORTED_FRAME),  # PX4: 2
    (6, 31000, (0, 0, 0, 0), mavlink.MAV_MISSION_UNSUPPORTED),  # PX4: 3
    (2, 176, (1, 4, 4, 0), mavlink.MAV_MISSION_UNSUPPORTED),  # DO_SET_MODE as an item: PX4 3
    (6, 5001, (4, 0, 0, 0), mavlink.MAV_MISSION_ERROR),  # a fence vertex in a mission
    (6, 16, (0, 0, 0, 0), mavlink.MAV_MISSION_ACCEPTED),
])  # fmt: skip
def test_items_px4_does_not_store_end_the_upload_with_its_reason(frame, command, params, result):
    from helpers.mission_client import Item

    mm = MissionManager()
    log = upload(mm, [Item(frame, command, params, 473977420, 85455940, 5.0)])
    assert log[-1] == ("MISSION_ACK", result)
    assert len(mm.mission) == (1 if result == 0 else 0)


def test_counts_beyond_the_lists_get_no_space_and_zero_clears():
    mm = MissionManager()
    assert kinds(mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 65535, 0)), 0.0)) == [("MISSION_ACK", mavlink.MAV_MISSION_NO_SPACE)]
    assert kinds(mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 65, 1)), 0.0)) == [("MISSION_ACK", mavlink.MAV_MISSION_NO_SPACE)]
    upload(mm, BOX)
    assert kinds(mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 0, 0)), 0.0)) == [("MISSION_ACK", 0)]
    assert mm.mission == [] and mm.mission_current() == (0, 65535, 0, 0)


def test_an_item_out_of_sequence_is_ignored_and_one_outside_a_transfer_is_an_error():
    mm = MissionManager()
    mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 0.0)
    assert mm.handle(wire(item_int(BOX[1], 1)), 0.1) == []  # PX4 keeps requesting seq 0
    assert mm.state is TransferState.GETLIST
    mm.update(TIMEOUT_S + 1)
    mm.update(TIMEOUT_S + 1.01)
    assert mm.state is TransferState.IDLE
    outs = mm.handle(wire(item_int(BOX[0], 0)), 7.0)
    assert ("MISSION_ACK", mavlink.MAV_MISSION_ERROR) in kinds(outs)
    # a download's list is busy until its ACK: an upload meanwhile is refused (PX4: ERROR)
    mm.handle(wire(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 8.0)
    assert ("MISSION_ACK", mavlink.MAV_MISSION_ERROR) in kinds(mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 1, 0)), 8.1))


def test_fence_and_rally_lists_are_kept_apart_and_cleared_by_type():
    from helpers.mission_client import Item

    mm = MissionManager()
    fence = [Item(5, 5001, (4, 0, 0, 0), 473968420 + i, 85442940, 0.0) for i in range(4)]
    assert upload(mm, fence, 1)[-1] == ("MISSION_ACK", 0)
    assert upload(mm, [Item(5, 5100, (0, 0, 0, 0), 473978420, 85456940, 0.0)], 2)[-1] == ("MISSION_ACK", 0)
    assert upload(mm, [Item(5, 5001, (2, 0, 0, 0), 473968420, 85442940, 0.0)], 1)[-1] == ("MISSION_ACK", mavlink.MAV_MISSION_ERROR)
    assert len(mm.lists[1]) == 4 and len(mm.lists[2]) == 1 and mm.mission == []
    assert all(it.autocontinue == 0 for it in mm.lists[1])  # PX4 stores fence points without it
    assert kinds(mm.handle(wire(mavlink.MAVLink_mission_clear_all_message(1, 1, 1)), 0.0)) == [("MISSION_ACK", 0)]
    assert mm.lists[1] == [] and len(mm.lists[2]) == 1
    mm.handle(wire(mavlink.MAVLink_mission_clear_all_message(1, 1, 255)), 0.0)
    assert mm.lists[2] == []


def test_missions_are_addressed_as_px4_checks_them():
    to_planner = wire(mavlink.MAVLink_mission_count_message(1, 190, 1, 0))
    broadcast = wire(mavlink.MAVLink_mission_count_message(0, 0, 1, 0))
    assert MissionManager.addressed_to_us(to_planner, 1, 1)
    assert not MissionManager.addressed_to_us(broadcast, 1, 1)


def test_set_current_moves_within_the_list_only():
    mm = MissionManager()
    upload(mm, BOX)
    assert mm.handle(wire(mavlink.MAVLink_mission_set_current_message(1, 1, 3)), 0.0) == [] and mm.current_seq == 3
    outs = mm.handle(wire(mavlink.MAVLink_mission_set_current_message(1, 1, 9)), 0.0)
    assert outs[0].fields[1] == "WPM: WP CURR CMD: Not in list" and mm.current_seq == 3


# --- the navigator, flying a vehicle that follows its setpoints exactly ------------------------


def fly(nav: Navigator, seconds: float, dt: float = 0.05, start_s: float = 0.0, pos=(0.0, 0.0, 0.0)):
    """Step the navigator with a vehicle at its setpoint (landed at down >= 0): the trace."""
    p, yaw, trace = list(pos), 0.0, []
    t = start_s
    while t < start_s + seconds:
        sp = nav.setpoint()
        if sp is not None:
            if sp.descend_m_s is not None:
                p = [sp.pos_ned_m[0], sp.pos_ned_m[1], min(p[2] + sp.descend_m_s * dt, 0.0)]
            else:
                climb = sp.max_climb_m_s or 1e9
                p = [sp.pos_ned_m[0], sp.pos_ned_m[1], max(sp.pos_ned_m[2], p[2] - climb * dt)]
            yaw = sp.yaw_rad
        nav.observe(tuple(p), yaw, p[2] >= 0.0)
        nav.update(t)
        trace.append((t, tuple(p), nav.current_seq, nav.reached_seq))
        t += dt
    return trace


def mission_nav() -> Navigator:
    from sitl_plant.mission import parse_item

    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    items = [parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(BOX)]
    nav.load(items)
    nav.observe((0.0, 0.0, 0.0), 0.0, True)
    nav.start("mission", 0.0)
    return nav


def test_the_box_mission_reaches_its_items_in_order_holds_and_lands():
    nav = mission_nav()
    trace = fly(nav, 120.0)
    reached = []
    for _, _, _, r in trace:
        if r >= 0 and (not reached or reached[-1] != r):
            reached.append(r)
    assert reached == [1, 2, 3, 4, 5, 6]  # PX4 v1.16: 1, 2, 3, 4, 5, 6 (takeoff 0 and speed 1 in one step)
    t_of = {r: next(t for t, _, _, rr in trace if rr == r) for r in reached}
    pos_of = {r: next(p for _, p, _, rr in trace if rr == r) for r in reached}
    assert pos_of[1][2] == pytest.approx(-10.0, abs=0.8)  # took off to 10 m (NAV_MC_ALT_RAD)
    assert math.hypot(pos_of[2][0] - 20.0, pos_of[2][1]) <= 2.0  # acceptance radius param2 = 2 m
    # item 3 holds 3 s, item 5 (LOITER_TIME) 5 s, between arriving and the next leg
    arrive3 = next(t for t, p, s, _ in trace if s == 3 and math.hypot(p[0] - 20.0, p[1] - 20.0) <= 2.0 and abs(p[2] + 15.0) <= 0.8)
    assert t_of[3] - arrive3 >= 3.0
    # speed 3 m/s after DO_CHANGE_SPEED: no faster along the legs
    speeds = [math.dist(a[1], b[1]) / (b[0] - a[0]) for a, b in zip(trace, trace[1:]) if a[2] in (2, 3)]
    assert max(speeds) <= 3.0 + 1e-6 and max(speeds) > 2.9
    assert trace[-1][1][2] == 0.0 and nav.finished


@pytest.mark.parametrize(("nxt", "want"), [((20.0, 20.0), math.sqrt(1.5 * 2.0)), ((0.0, 0.0), 0.0), ((20.0, -20.0), math.sqrt(1.5 * 2.0))])
def test_the_corner_speed_is_px4s_from_the_angle_between_the_legs(nxt, want):
    # PX4 v1.16 computeMaxSpeedInWaypoint: sqrt(a d tan(alpha / 2)), a = MPC_XY_TRAJ_P MPC_ACC_HOR
    assert corner_speed_m_s((0.0, 0.0), (20.0, 0.0), nxt, 1.5, 2.0) == pytest.approx(want, abs=1e-6)
    assert corner_speed_m_s((0.0, 0.0), (20.0, 0.0), (40.0, 0.0), 1.5, 2.0) > 100.0  # straight on


def test_the_survey_flies_through_its_waypoints_and_stops_where_it_holds():
    """PX4 v1.16 passed the survey's 90-degree corners at 1.0-1.5 m/s and stopped at the loiter
    (test_the_bundled_missions_fly_on_both_as_px4_flies_them); before, the plant stopped at
    every waypoint."""
    from sitl_plant.mission import parse_item

    items = items_from_file(MISSIONS_DIR / "px4-sitl-survey.plan")
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.load([parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(items)])
    nav.observe((0.0, 0.0, 0.0), 0.0, True)
    nav.start("mission", 0.0)
    trace = fly(nav, 200.0)
    speeds = [((a[0] + b[0]) / 2, math.dist(a[1][:2], b[1][:2]) / (b[0] - a[0])) for a, b in zip(trace, trace[10:])]  # 0.5 s chords
    reached_at = {b[3]: b[0] for a, b in zip(trace, trace[1:]) if b[3] != a[3] and b[3] >= 0}
    speed_at = {seq: min(v for t, v in speeds if abs(t - at) < 1.5) for seq, at in reached_at.items()}  # the slowest near it
    for seq in range(3, 9):  # 90-degree corners, NAV_ACC_RAD 2 m: sqrt(0.5 * 3 * 2) = 1.7 m/s
        assert 1.0 < speed_at[seq] <= 4.0 + 1e-6, (seq, speed_at)
    assert speed_at[10] < 0.1  # the loiter (3 s) after waypoint 9 at the same place
    assert nav.finished and trace[-1][1][2] == 0.0


@pytest.mark.parametrize("name", ["px4-sitl-box.waypoints", "px4-sitl-survey.plan"])
def test_every_bundled_mission_file_flies_to_its_last_item_and_lands(name):
    from sitl_plant.mission import parse_item

    items = items_from_file(MISSIONS_DIR / name)
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.load([parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(items)])
    nav.observe((0.0, 0.0, 0.0), 0.0, True)
    nav.start("mission", 0.0)
    trace = fly(nav, 300.0, dt=0.1)
    reached = sorted({r for *_, r in trace if r >= 0})
    assert reached[-1] == len(items) - 1 and nav.finished
    assert reached == sorted(reached) and len(reached) >= len(items) - 2  # a DO item right after the take-off shares its step
    assert trace[-1][1][2] == 0.0 and math.hypot(*trace[-1][1][:2]) < 1.0  # landed at home


def test_a_mission_without_land_ends_holding_at_the_last_item():
    nav = mission_nav()
    nav.items = nav.items[:4]
    trace = fly(nav, 60.0)
    assert nav.finished and trace[-1][2] == 3
    assert math.dist(trace[-1][1], (20.0, 20.0, -15.0)) < 2.0
    assert math.dist(trace[-1][1], trace[-100][1]) < 1e-6  # holding still


@pytest.mark.parametrize("start, height", [
    ((40.0, 0.0, -5.0), 30.0),  # RTL_RETURN_ALT (PX4 v1.16 from 25 m and 36 m away: 30 m)
    ((8.0, 0.0, -5.0), 8.0),  # within RTL_MIN_DIST: the 45 deg cone, 8 m at 8 m
    ((3.0, 0.0, -2.0), 4.0),  # ... but at least 2 NAV_ACC_RAD
    ((40.0, 0.0, -45.0), 45.0),  # never lower than now
])  # fmt: skip
def test_return_climbs_to_the_cone_altitude_comes_home_descends_and_lands(start, height):
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.observe(start, 0.0, False)
    nav.start("rtl", 0.0)
    trace = fly(nav, 150.0, pos=start)
    top = min(p[2] for _, p, _, _ in trace)
    assert -top == pytest.approx(height, abs=0.9)  # RTL_RETURN_ALT 30, RTL_DESCEND_ALT 10, cone 45 deg
    climbed = next(p for _, p, _, _ in trace if p[2] <= top + 1.0)
    assert climbed[0] == pytest.approx(start[0], abs=0.5)  # climbs first, over the start point
    assert trace[-1][1] == pytest.approx((0.0, 0.0, 0.0), abs=0.3) and nav.landing


def test_orbit_circles_at_its_radius_and_speed():
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.observe((10.0, 0.0, -8.0), 0.0, False)
    nav.orbit((0.0, 0.0, -8.0), 10.0, 2.0, 0.0)
    trace = fly(nav, 20.0, pos=(10.0, 0.0, -8.0))
    radii = [math.hypot(p[0], p[1]) for _, p, _, _ in trace[5:]]
    np.testing.assert_allclose(radii, 10.0, atol=1e-6)
    arc = sum(math.dist(a[1], b[1]) for a, b in zip(trace, trace[1:]))
    assert arc / 20.0 == pytest.approx(2.0, rel=0.02)
    assert trace[20][1][1] > 0  # clockwise seen from above: north towards east


def test_geodetic_to_ned_inverts_the_plants_projection():
    for ned in ((120.0, -35.0), (-800.0, 2500.0)):
        lat, lon, _ = codec.ned_to_geodetic(np.array([ned[0], ned[1], 0.0]), codec.Home())
        np.testing.assert_allclose(geodetic_to_ned(lat, lon, 47.397742, 8.545594), ned, atol=1e-6)


# --- the autopilot's hooks ------------------------------------------------------------------------


def test_mission_mode_and_mission_start_are_accepted_disarmed_refused_armed_without_a_mission():
    ap = Autopilot(plant_params(VehicleParams()), home_alt_amsl_m=488.0)
    assert ap.set_mode(Mode.AUTO_MISSION, 0.0).result == 0  # PX4 v1.16 accepts it disarmed, even without a mission
    assert ap.mode is Mode.AUTO_MISSION
    ap.set_mode(Mode.AUTO_LOITER, 0.0)
    assert ap.on_command(Command(300, (0.0,) * 7), 0.0).result == 0 and ap.mode is Mode.AUTO_MISSION
    ap.set_mode(Mode.AUTO_LOITER, 0.0)
    assert ap.reposition((10.0, 0.0, -5.0), -1.0, None, 0.0).result == 0 and ap.mode is Mode.AUTO_LOITER  # disarmed: nothing
    assert ap.navigator.activity == ""
    ap.arm(0.0)
    assert ap.set_mode(Mode.AUTO_MISSION, 0.0).result == 1  # PX4 v1.16 in the air without a mission: refused
    assert Mode.from_custom(3, 1) is Mode.ORBIT and Mode.ORBIT.custom_mode == (3 << 16) | (1 << 24)


# --- the server's glue ----------------------------------------------------------------------------


def make_plant():
    from sitl_plant.server import Plant, PlantConfig

    vehicle = VehicleParams()
    params = plant_params(vehicle)
    return Plant(PlantConfig(), vehicle, params, Autopilot(params, home_alt_amsl_m=488.0))


def test_the_plant_answers_missions_on_the_link_they_came_from_and_streams_mission_current():
    from sitl_plant.server import API, GCS

    plant = make_plant()
    plant.handle(GCS, wire(mavlink.MAVLink_mission_count_message(1, 190, 1, 0)))  # to the mission planner: PX4 takes it
    (request,) = plant.outbox[GCS]
    assert request.get_type() == "MISSION_REQUEST" and plant.outbox[API] == []
    plant.handle(GCS, wire(item_int(BOX[0], 0)))
    assert plant.outbox[GCS][-1].get_type() == "MISSION_ACK" and plant.outbox[GCS][-1].type == 0
    plant.handle(API, wire(mavlink.MAVLink_mission_count_message(0, 0, 1, 0)))  # broadcast: PX4 ignores it
    assert plant.outbox[API] == [] and plant.counters.foreign == 1
    current = [m for m in plant.telemetry(API) if m.get_type() == "MISSION_CURRENT"]
    assert (current[-1].seq, current[-1].total) == (0, 1)  # after the boot's (0, 65535): the new mission
    plant.advance(plant.tick_steps)
    assert not [m for m in plant.telemetry(API) if m.get_type() == "MISSION_CURRENT"]  # 1 Hz, and on changes
    plant.advance(round(1.0 / plant.config.physics_dt_s))
    assert [m.total for m in plant.telemetry(API) if m.get_type() == "MISSION_CURRENT"] == [1]


def test_reposition_from_the_ground_takes_off_orbit_is_taken_disarmed_refused_armed_on_the_ground():
    from sitl_plant.server import API

    plant = make_plant()
    orbit = wire(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_ORBIT, 0, 5, 1, 0, math.nan, 47.3978, 8.5456, 500.0))
    plant.handle(API, orbit)  # disarmed: PX4 v1.16 accepts it and switches to Orbit
    assert plant.autopilot.mode is Mode.ORBIT
    plant.autopilot.set_mode(Mode.AUTO_LOITER, 0.0)
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_REPOSITION, 0, 5, 1, 0, math.nan, 47.3978, 8.5456, 500.0)))
    plant.handle(API, orbit)
    acks = [(m.command, m.result) for m in plant.outbox[API] if m.get_type() == "COMMAND_ACK"]
    assert acks == [(34, 0), (400, 0), (192, 0), (34, 1)]  # orbit armed on the ground: refused
    for _ in range(500):  # 2 s: still on the ground, spooling up (COM_SPOOLUP_TIME) and ramping (MPC_TKO_RAMP_T)
        plant.advance(plant.tick_steps)
    assert plant._truth.pos_ned_m[2] > -0.1
    for _ in range(1000):  # 4 s more: PX4 v1.16 takes off towards the point
        plant.advance(plant.tick_steps)
    assert plant.autopilot.mode is Mode.AUTO_LOITER and plant._truth.pos_ned_m[2] < -1.0


def _at(down_m: float = 0.0) -> VehicleState:
    z = np.zeros(3)
    return VehicleState(0.0, np.array([0.0, 0.0, down_m]), z, z, z, z, z, np.array([1.0, 0.0, 0.0, 0.0]), on_ground=down_m >= 0.0)


def _climb_limits(start, times_s):
    """The climb limit the autopilot flies at each time after arming at 0 on the ground, after
    ``start(ap)`` chose the take-off; None while it idles (the motors spooling up)."""
    ap = Autopilot(plant_params(VehicleParams()), home_alt_amsl_m=488.0)
    ap.set_origin(HOME.origin_lat_deg, HOME.origin_lon_deg, HOME.origin_alt_amsl_m)
    ap.observe(_at())
    ap.update(0.0)
    start(ap)
    out = []
    for t in times_s:
        ap.update(t)
        task = ap.task()
        out.append(None if isinstance(task, IdleTask) else task.max_climb_m_s)
    return out


def test_every_take_off_from_the_ground_spools_up_and_ramps_as_takeoff_mode():
    """PX4's takeoff handling (mc_pos_control) is the same whatever asks for the take-off: a
    mission's take-off item and a DO_REPOSITION from the ground wait COM_SPOOLUP_TIME, then ramp
    the climb limit from -g / MPC_Z_VEL_P_ACC over MPC_TKO_RAMP_T, as Takeoff mode does."""
    from helpers.mission_client import Item
    from sitl_plant.mission import parse_item

    times = [0.0, 0.5, 0.99, 1.0, 2.5, 4.0, 5.0]

    def takeoff_mode(ap):
        ap.on_command(Command(22, (math.nan,) * 6 + (488.0 + 5.0,)), 0.0)
        ap.arm(0.0)

    def mission(ap):
        items = [Item(6, 22, (0, 0, 0, math.nan), 473977420, 85455940, 5.0), Item(6, 16, (0, 0, 0, math.nan), 473978420, 85455940, 5.0)]
        ap.navigator.load([parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(items)])
        ap.set_mode(Mode.AUTO_MISSION, 0.0)
        ap.arm(0.0)

    def reposition(ap):
        ap.arm(0.0)
        ap.reposition((10.0, 0.0, -5.0), -1.0, None, 0.0)

    p = plant_params(VehicleParams())
    spool, ramp, init = p["COM_SPOOLUP_TIME"], p["MPC_TKO_RAMP_T"], -9.80665 / p["MPC_Z_VEL_P_ACC"]
    expected_takeoff = _climb_limits(takeoff_mode, times)
    assert expected_takeoff[:3] == [None, None, None] and expected_takeoff[3] == pytest.approx(init)
    assert _climb_limits(mission, times) == pytest.approx(expected_takeoff)  # the same 5 m take-off
    # the reposition's leg has no take-off height to slow near: the ramp goes to MPC_TKO_SPEED
    speed = p["MPC_TKO_SPEED"]
    want = [None, None, None] + [init + min((t - spool) / ramp, 1.0) * (speed - init) for t in times[3:]]
    got = _climb_limits(reposition, times)
    assert got[:3] == want[:3] and got[3:] == pytest.approx(want[3:])


def test_a_take_off_item_in_the_air_is_not_ramped():
    """Only a take-off from the ground is: a mission started in the air climbs at MPC_TKO_SPEED
    (limited near the height) at once."""
    from helpers.mission_client import Item
    from sitl_plant.mission import parse_item

    ap = Autopilot(plant_params(VehicleParams()), home_alt_amsl_m=488.0)
    ap.set_origin(HOME.origin_lat_deg, HOME.origin_lon_deg, HOME.origin_alt_amsl_m)
    ap.observe(_at())
    ap.update(0.0)
    ap.arm(0.0)
    ap.observe(_at(-2.0))  # armed in Hold on the ground, now 2 m up (as if flown by a client)
    ap.update(10.0)
    items = [Item(6, 22, (0, 0, 0, math.nan), 473977420, 85455940, 20.0)]
    ap.navigator.load([parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(items)])
    assert ap.set_mode(Mode.AUTO_MISSION, 10.0).result == 0
    ap.update(10.1)
    assert ap.task().max_climb_m_s == pytest.approx(ap.params["MPC_TKO_SPEED"])


def test_command_positions_are_read_as_px4_1_16_flies_them():
    here = np.array([3.0, 4.0, -10.0])
    north_lat = 47.397742 + 20 / 111195.0
    long_form = wire(mavlink.MAVLink_command_long_message(1, 1, 192, 0, -1, 1, 0, math.nan, north_lat, 8.545594, 500.0))
    np.testing.assert_allclose(codec.command_position_ned(long_form, HOME, here), (20.0, 0.0, -12.0), atol=0.5)  # float32 degrees
    keep = wire(mavlink.MAVLink_command_long_message(1, 1, 192, 0, -1, 1, 0, math.nan, math.nan, math.nan, math.nan))
    assert codec.command_position_ned(keep, HOME, here) == (3.0, 4.0, -10.0)
    amsl = wire(mavlink.MAVLink_command_int_message(1, 1, 5, 192, 0, 0, -1, 1, 0, math.nan, int(north_lat * 1e7), 85455940, 500.0))
    np.testing.assert_allclose(codec.command_position_ned(amsl, HOME, here), (20.0, 0.0, -12.0), atol=0.05)
    # global-relative COMMAND_INT: PX4 v1.16 stayed where it was and took z = 12 as AMSL (it descended)
    relative = wire(mavlink.MAVLink_command_int_message(1, 1, 6, 192, 0, 0, -1, 1, 0, math.nan, int(north_lat * 1e7), 85455940, 12.0))
    assert codec.command_position_ned(relative, HOME, here) == (3.0, 4.0, 476.0)
    local = wire(mavlink.MAVLink_command_int_message(1, 1, 1, 192, 0, 0, -1, 1, 0, math.nan, 0, 0, 12.0))
    assert codec.command_position_ned(local, HOME, here) is None


def test_bad_items_get_a_reason_and_a_nan_altitude_keeps_the_height():
    from sitl_plant.mission import parse_item

    nan_lat = wire(mavlink.MAVLink_mission_item_message(1, 1, 0, 3, 16, 0, 1, 0, 0, 0, 0, math.nan, 8.5, 10.0, 0))
    assert parse_item(nan_lat, False, 0) == (None, mavlink.MAV_MISSION_INVALID_PARAM5_X)
    off_globe = wire(mavlink.MAVLink_mission_item_message(1, 1, 0, 3, 16, 0, 1, 0, 0, 0, 0, 47.0, 1e30, 10.0, 0))
    assert parse_item(off_globe, False, 0) == (None, mavlink.MAV_MISSION_INVALID_PARAM6_Y)
    nan_alt = wire(mavlink.MAVLink_mission_item_int_message(1, 1, 0, 6, 16, 0, 1, 0, 2, 0, math.nan, 473979219, 85455940, math.nan, 0))
    item, result = parse_item(nan_alt, True, 0)
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.load([item])
    nav.observe((0.0, 0.0, -7.0), 0.0, False)
    nav.start("mission", 0.0)
    trace = fly(nav, 30.0, pos=(0.0, 0.0, -7.0))
    assert result == 0 and all(p[2] == pytest.approx(-7.0) for _, p, _, _ in trace)
    assert math.hypot(trace[-1][1][0] - 20.0, trace[-1][1][1]) < 2.0


def test_reached_goes_out_on_change_then_ten_times_more_at_1_hz_and_current_on_change():
    from sitl_plant.mission import Reporter

    r = Reporter()
    sent = []
    for k in range(300):  # 30 s in steps of 0.1 s; item 2 reached at 1.5 s
        t = round(k * 0.1, 1)
        after = t >= 1.5
        outs = r.due(t, (3 if after else 2, 7, 0, 0), 2 if after else -1, 1 if after else 0, True)
        sent += [(round(t, 1), o.kind) for o in outs]
    reached = [t for t, kind in sent if kind == "MISSION_ITEM_REACHED"]
    current = [t for t, kind in sent if kind == "MISSION_CURRENT"]
    assert reached == [1.5] + [float(t) for t in range(2, 12)]  # at once, then ten repeats at 1 Hz
    assert current == [1.5]  # the change at once (its 1 Hz is the plant's MISSION_CURRENT stream: test_plant_wire)


def test_change_speed_sets_the_speed_of_the_next_reposition():
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.observe((0.0, 0.0, -5.0), 0.0, False)
    nav.change_speed(1.5)  # PX4 v1.16: DO_CHANGE_SPEED 1.5, then DO_REPOSITION 15 m away: 1.47 m/s at most
    nav.reposition((15.0, 0.0, -5.0), -1.0, None, 0.0)
    trace = fly(nav, 15.0, pos=(0.0, 0.0, -5.0))
    speeds = [math.dist(a[1], b[1]) / (b[0] - a[0]) for a, b in zip(trace, trace[1:])]
    assert max(speeds) == pytest.approx(1.5, abs=0.01) and trace[-1][1][0] == pytest.approx(15.0, abs=0.1)


def test_a_return_item_hands_the_mission_over_to_return_mode():
    from helpers.mission_client import Item
    from sitl_plant.mission import parse_item

    ap = Autopilot(plant_params(VehicleParams()), home_alt_amsl_m=488.0)
    ap.set_origin(HOME.origin_lat_deg, HOME.origin_lon_deg, HOME.origin_alt_amsl_m)
    items = [Item(6, 22, (0, 0, 0, math.nan), 473977420, 85455940, 5.0), Item(2, 20, (0, 0, 0, 0), 0, 0, 0.0)]
    ap.navigator.load([parse_item(wire(item_int(it, s)), True, 0)[0] for s, it in enumerate(items)])
    ap.set_mode(Mode.AUTO_MISSION, 0.0)
    ap.arm(0.0)
    nav = ap.navigator
    for k in range(200):  # a vehicle at its setpoint: up to the take-off height, then the RTL item
        sp = nav.setpoint()
        down = max(sp.pos_ned_m[2], -0.1 * k) if sp is not None else 0.0
        ap.observe(type("S", (), {"pos_ned_m": np.array([0.0, 0.0, down]), "vel_ned_m_s": np.zeros(3), "euler_rad": np.zeros(3),
                                  "on_ground": down >= 0})())  # fmt: skip
        ap.update(k * 0.1)
        if ap.mode is Mode.AUTO_RTL:
            break
    assert ap.mode is Mode.AUTO_RTL and nav.reached_seq == 1 and nav.activity == "rtl"


def test_requests_outside_a_transfer_are_ignored_and_one_of_an_empty_list_is_an_error():
    mm = MissionManager()
    assert mm.handle(wire(mavlink.MAVLink_mission_request_int_message(1, 1, 0, 0)), 0.0) == []  # PX4: silence
    assert kinds(mm.handle(wire(mavlink.MAVLink_mission_request_list_message(1, 1, 0)), 0.1)) == [("MISSION_COUNT", 0)]
    outs = mm.handle(wire(mavlink.MAVLink_mission_request_int_message(1, 1, 0, 0)), 0.2)
    assert ("MISSION_ACK", mavlink.MAV_MISSION_ERROR) in kinds(outs)


def test_a_clear_during_an_upload_is_ignored_and_the_upload_goes_on():
    mm = MissionManager()
    upload(mm, BOX)
    mm.handle(wire(mavlink.MAVLink_mission_count_message(1, 1, 2, 0)), 1.0)
    outs = mm.handle(wire(mavlink.MAVLink_mission_clear_all_message(1, 1, 0)), 1.1)
    assert [o.kind for o in outs] == ["STATUSTEXT"] and "Busy" in str(outs[0].fields)
    assert mm.state is TransferState.GETLIST and len(mm.mission) == len(BOX)  # nothing cleared


def test_orbit_speed_follows_px4s_acceleration_limit():
    """FlightTaskOrbit::_sanitizeParams: v^2 >= 2 m/s^2 r lowers the speed to sqrt(2 r), the radius
    is kept (within [1, MC_ORBIT_RAD_MAX]) and the speed within MPC_XY_VEL_MAX. PX4 v1.16 SIH asked
    3 m/s on 2 m flew 1.22 m/s (below sqrt(4) = 2 by its drag lag), 2 m/s on 5 m 1.37 m/s."""
    assert orbit_limits(5.0, 2.0, 1000.0, 12.0) == (5.0, 2.0)  # 4 < 10: kept
    assert orbit_limits(2.0, 3.0, 1000.0, 12.0) == (2.0, pytest.approx(2.0))
    assert orbit_limits(-10.0, 5.0, 1000.0, 12.0) == (-10.0, pytest.approx(math.sqrt(20.0)))
    assert orbit_limits(0.2, 0.5, 1000.0, 12.0) == (1.0, 0.5)
    assert orbit_limits(5000.0, 30.0, 1000.0, 12.0) == (1000.0, 12.0)
    nav = Navigator(plant_params(VehicleParams()), frame=HOME)
    nav.observe((2.0, 0.0, -8.0), 0.0, False)
    nav.orbit((0.0, 0.0, -8.0), 2.0, 3.0, 0.0)
    nav.update(0.05)
    sp = nav.setpoint()
    # on the circle: velocity only, tangential (clockwise: east at the north point), the centripetal feed-forward
    assert not sp.hold_xy and sp.vel_ned_m_s[:2] == pytest.approx((0.0, 2.0), abs=1e-9)
    assert sp.acc_ff_ne_m_s2 == pytest.approx((-2.0, 0.0))
    nav.observe((2.5, 0.0, -8.0), 0.0, False)  # 0.5 m outside: pulled back at 1/s
    nav.update(0.1)
    assert nav.setpoint().vel_ned_m_s[:2] == pytest.approx((-0.5, 2.0), abs=1e-9)
