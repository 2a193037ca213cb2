"""Bad mission files give one line naming file, place, field and expectation; round trips hold."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.errors import MissionFormatError, UserError
from offboard.missions import MISSIONS_DIR, load_mission
from offboard.missions.geo import LocalProjection
from offboard.missions.items import (
    DEFAULT_ACCEL_M_S2,
    DEFAULT_CRUISE_SPEED_M_S,
    items_from_waypoints,
)
from offboard.missions.plan import read_plan, write_plan
from offboard.missions.wpl import format_wpl, read_wpl, write_wpl
from offboard.trajectory import Waypoint, WaypointLegs
from offboard.trajectory.sampling import sample
from pymavlink import mavutil, mavwp

HOME = (47.397742, 8.545594, 488.0)
WPL_HOME = "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.0\t1"
LAT, LON = LocalProjection(*HOME).global_from_ned(20.0, 10.0, 0.0)[:2]
WP = f"1\t0\t3\t16\t0\t0\t0\tnan\t{LAT}\t{LON}\t10\t1"


def wpl(*rows: str, header: str = "QGC WPL 110") -> str:
    return "\n".join([header, WPL_HOME, *rows]) + "\n"


def plan(items: list, home: object = (47.397742, 8.545594, 488.0), **top: object) -> str:
    doc = {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "QGroundControl",
        "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15, "hoverSpeed": 5,
                    "plannedHomePosition": list(home) if isinstance(home, tuple) else home, "items": items},
    }
    doc.update(top)
    return json.dumps(doc)


def simple(command: int, frame: int, params: list) -> dict:
    return {"type": "SimpleItem", "command": command, "frame": frame, "params": params, "autoContinue": True, "doJumpId": 1}


TOML_HEAD = '[mission]\nframe = "ned"\nangle_unit = "deg"\n'
HOLD = '[[mission.segment]]\ntype = "hold"\nposition = [0, 0, -2]\nduration_s = 3\n'


def toml(*segments: str, head: str = TOML_HEAD) -> str:
    return head + "".join(segments)


# (file name, content, fragments expected in the one-line message)
MALFORMED = [
    # --- QGC WPL 110 ---
    ("header.waypoints", wpl(WP, header="QGC WPL 100"), ["line 1: header: expected 'QGC WPL 110', got 'QGC WPL 100'"]),
    ("empty.waypoints", "", ["line 1: header: expected 'QGC WPL 110', got an empty first line"]),
    ("missing-column.waypoints", wpl("1\t0\t3\t16\t0\t0\t0\t0\t47.4\t8.5\t10"), ["line 3: expected 12 tab-separated fields", "got 11"]),
    ("extra-column.waypoints", wpl(WP + "\t7"), ["line 3: expected 12 tab-separated fields", "got 13"]),
    ("servo.waypoints", wpl(WP, "2\t0\t0\t183\t1\t1500\t0\t0\t0\t0\t0\t1"),
     ["line 4 (item 2): command: MAV_CMD_DO_SET_SERVO (183) is not supported; expected one of NAV_WAYPOINT (16)"]),
    ("unknown-cmd.waypoints", wpl("1\t0\t3\t65000\t0\t0\t0\t0\t47.4\t8.5\t10\t1"), ["line 3 (item 1): command: command 65000 (65000) is not supported"]),
    ("text.waypoints", wpl(f"1\t0\t3\t16\tabc\t0\t0\tnan\t{LAT}\t{LON}\t10\t1"), ["line 3 (item 1): param1: expected a number, got 'abc'"]),
    ("float-cmd.waypoints", wpl(f"1\t0\t3\t16.5\t0\t0\t0\tnan\t{LAT}\t{LON}\t10\t1"), ["line 3 (item 1): command: expected an integer, got '16.5'"]),
    ("nan-lat.waypoints", wpl(f"1\t0\t3\t16\t0\t0\t0\t0\tnan\t{LON}\t10\t1"), ["line 3 (item 1): x (latitude): expected a number, got nan"]),
    ("nan-hold.waypoints", wpl(f"1\t0\t3\t16\tnan\t0\t0\t0\t{LAT}\t{LON}\t10\t1"), ["line 3 (item 1): param1 (hold time): expected a number, got NaN"]),
    ("inf.waypoints", wpl(f"1\t0\t3\t16\t0\t0\t0\t0\t{LAT}\t{LON}\tinf\t1"), ["line 3 (item 1): z (altitude): expected a finite number, got 'inf'"]),
    ("neg-hold.waypoints", wpl(f"1\t0\t3\t16\t-2\t0\t0\tnan\t{LAT}\t{LON}\t10\t1"), ["item 1): param1 (hold time): expected seconds >= 0, got -2"]),
    ("zero-speed.waypoints", wpl("1\t0\t2\t178\t1\t0\t-1\t0\t0\t0\t0\t1", WP.replace("1\t0\t3", "2\t0\t3", 1)),
     ["line 3 (item 1): param2 (speed): expected a speed > 0 m/s (or -1: no change, -2: default), got 0"]),
    ("underground.waypoints", wpl(f"1\t0\t3\t16\t0\t0\t0\tnan\t{LAT}\t{LON}\t-3\t1"), ["line 3 (item 1): z (altitude): point is 3 m below home, underground"]),
    ("underground-amsl.waypoints", wpl(f"1\t0\t0\t16\t0\t0\t0\tnan\t{LAT}\t{LON}\t480\t1"), ["z (altitude): point is 8 m below home"]),
    ("seq.waypoints", wpl(WP.replace("1\t0", "5\t0", 1)), ["line 3: seq: expected 1 (items numbered 0, 1, 2, ... in order), got 5"]),
    ("terrain.waypoints", wpl(f"1\t0\t10\t16\t0\t0\t0\tnan\t{LAT}\t{LON}\t10\t1"),
     ["line 3 (item 1): frame: MAV_FRAME_GLOBAL_TERRAIN_ALT (10) is not supported"]),
    ("mixed.waypoints", wpl("1\t0\t1\t16\t0\t0\t0\tnan\t5\t5\t-5\t1"), ["line 3 (item 1): frame: expected a global frame, like the home item, got MAV_FRAME_LOCAL_NED"]),
    ("swapped.waypoints", wpl(f"1\t0\t3\t16\t0\t0\t0\tnan\t{LON}\t{LAT}\t10\t1"), ["x, y (latitude, longitude): point is", "latitude and longitude swapped?"]),
    ("lat-range.waypoints", wpl("1\t0\t3\t16\t0\t0\t0\tnan\t147.4\t8.5\t10\t1"), ["x (latitude): expected degrees in [-90, 90], got 147.4"]),
    ("only-home.waypoints", wpl(), ["no mission items after the home position (item 0)"]),
    ("current.waypoints", wpl(WP.replace("1\t0\t3", "1\t7\t3", 1)), ["line 3 (item 1): current: expected one of 0, 1, got 7"]),
    ("home-cmd.waypoints", "QGC WPL 110\n0\t1\t0\t22\t0\t0\t0\t0\t47.4\t8.5\t488\t1\n" + WP + "\n",
     ["line 2 (item 0): command: the home item must be MAV_CMD_NAV_WAYPOINT, got MAV_CMD_NAV_TAKEOFF"]),
    ("takeoff-down.waypoints", wpl(f"1\t0\t3\t16\t0\t0\t0\tnan\t{LAT}\t{LON}\t10\t1", "2\t0\t3\t22\t0\t0\t0\tnan\t0\t0\t5\t1"),
     ["line 4 (item 2): z (altitude): take-off altitude is 5 m below the current position; expected a climb"]),
    # --- QGroundControl .plan ---
    ("syntax.plan", '{"fileType": "Plan",\n "version": 1,,}', ["line 2: not valid JSON: Expecting property name"]),
    ("type.plan", plan([simple(16, 3, [0, 0, 0, None, LAT, LON, 10])], fileType="Fence"), ["fileType: expected \"Plan\", got \"Fence\""]),
    ("home.plan", plan([simple(16, 3, [0, 0, 0, None, LAT, LON, 10])], home=[47.4, 8.5]),
     ["mission.plannedHomePosition: expected [latitude, longitude, altitude], got [47.4, 8.5]"]),
    ("complex.plan", plan([{"type": "ComplexItem", "complexItemType": "survey"}]),
     ["mission.items[0] (item 1): type: ComplexItem (\"survey\") is not supported; expected SimpleItem"]),
    ("params.plan", plan([simple(16, 3, [0, 0, 0, LAT, LON, 10])]), ["mission.items[0] (item 1): params: expected 7 values", "got 6 values"]),
    ("param-text.plan", plan([simple(16, 3, [0, 0, 0, None, "47.4", LON, 10])]), ["mission.items[0] (item 1): params[4]: expected a number, got \"47.4\""]),
    ("null-lat.plan", plan([simple(16, 3, [0, 0, 0, None, None, LON, 10])]), ["mission.items[0] (item 1): x (latitude): expected a number, got nan"]),
    ("rtl.plan", plan([simple(20, 2, [0, 0, 0, 0, 0, 0, 0])]), ["mission.items[0] (item 1): command: MAV_CMD_NAV_RETURN_TO_LAUNCH (20) is not supported"]),
    ("version.plan", plan([simple(16, 3, [0, 0, 0, None, LAT, LON, 10])], version=2), ["version: expected 1, got 2"]),
    ("hover.plan", plan([simple(16, 3, [0, 0, 0, None, LAT, LON, 10])]).replace('"hoverSpeed": 5', '"hoverSpeed": 0'),
     ["mission.hoverSpeed: expected a speed > 0 m/s, got 0"]),
    # --- parametric TOML ---
    ("syntax.toml", "[mission\nframe = 1\n", ["not valid TOML"]),
    ("no-frame.toml", '[mission]\nangle_unit = "deg"\n' + HOLD, ["mission.frame: missing"]),
    ("frame.toml", toml(HOLD, head='[mission]\nframe = "enu"\nangle_unit = "deg"\n'), ["mission.frame: expected one of ned, paper-zup, got 'enu'"]),
    ("unit.toml", toml(HOLD, head='[mission]\nframe = "ned"\nangle_unit = "grad"\n'), ["mission.angle_unit: expected one of rad, deg, got 'grad'"]),
    ("unknown-top.toml", toml(HOLD, head=TOML_HEAD + "speed = 3\n"), ["mission.speed: unknown field"]),
    ("unknown-key.toml", toml('[[mission.segment]]\ntype = "hold"\nduration_s = 2\nradius_km = 2\n'), ["mission.segment #1 (hold): radius_km: unknown field"]),
    ("unknown-file-key.toml", "title = 'x'\n" + toml(HOLD), ["title: unknown field"]),
    ("type.toml", toml('[[mission.segment]]\ntype = "spiral"\n'), ["mission.segment #1: type: expected one of hold, line, helix"]),
    ("radius.toml", toml('[[mission.segment]]\ntype = "circle"\ncenter = [0, 0, -5]\nradius_m = -2\nangular_rate = 30\nduration_s = 5\n'),
     ["mission.segment #1 (circle): radius_m: must be > 0, got -2"]),
    ("speed.toml", toml('[[mission.segment]]\ntype = "line"\nto = [5, 0, -2]\nspeed_m_s = 0\n'), ["mission.segment #1 (line): speed_m_s: must be > 0, got 0"]),
    ("nan.toml", toml('[[mission.segment]]\ntype = "hold"\nposition = [0, nan, -2]\nduration_s = 1\n'), ["mission.segment #1 (hold): position[1]: must be finite, got nan"]),
    ("underground.toml", toml('[[mission.segment]]\ntype = "helix"\ncenter = [0, 0, -2]\nradius_m = 2\nangular_rate = 90\nclimb_rate_m_s = -1\nduration_s = 5\n'),
     ["mission.segment #1 (helix): goes 3 m below the ground at t = 5 s"]),
    ("underground-hold.toml", toml('[[mission.segment]]\ntype = "hold"\nposition = [0, 0, 1]\nduration_s = 1\n'), ["mission.segment #1 (hold): goes 1 m below the ground"]),
    ("zup-underground.toml", toml(HOLD.replace("-2]", "-2.5]"), head='[mission]\nframe = "paper-zup"\nangle_unit = "rad"\n'),
     ["mission.segment #1 (hold): goes 2.5 m below the ground"]),
    ("until.toml", toml(HOLD, '[[mission.segment]]\ntype = "hold"\nuntil_s = 2\n'), ["mission.segment #2 (hold-2): until_s: must be after the segment's start at t = 3 s, got 2"]),
    ("duration.toml", toml('[[mission.segment]]\ntype = "hold"\n'), ["mission.segment #1 (hold): duration_s: expected exactly one of duration_s, until_s, got none"]),
    ("both.toml", toml('[[mission.segment]]\ntype = "hold"\nduration_s = 1\nuntil_s = 2\n'), ["expected exactly one of duration_s, until_s, got duration_s, until_s"]),
    ("pi-deg.toml", toml('[[mission.segment]]\ntype = "hold"\nyaw = "pi/2"\nduration_s = 1\n'), ["mission.segment #1 (hold): yaw: expected a number of degrees, got 'pi/2'"]),
    ("pi-bad.toml", toml('[[mission.segment]]\ntype = "hold"\nyaw = "tau/2"\nduration_s = 1\n', head='[mission]\nframe = "ned"\nangle_unit = "rad"\n'),
     ["yaw: expected a number of radians or an expression like 'pi/2', got 'tau/2'"]),
    ("yaw-word.toml", toml('[[mission.segment]]\ntype = "line"\nto = [5, 0, -2]\nspeed_m_s = 1\nyaw = "forward"\n'),
     ["mission.segment #1 (line): yaw: expected an angle in degrees or one of 'along-path', got 'forward'"]),
    ("dup-name.toml", toml(HOLD.replace('"hold"\n', '"hold"\nname = "a"\n'), HOLD.replace('"hold"\n', '"hold"\nname = "a"\n')),
     ["mission.segment #2: name: 'a' is already the name of an earlier segment"]),
    ("no-segment.toml", TOML_HEAD, ["mission.segment: missing"]),
    ("points.toml", toml('[[mission.segment]]\ntype = "waypoints"\ncruise_speed_m_s = 1\naccel_m_s2 = 1\n'), ["points: expected exactly one of points"]),
    ("point-key.toml", toml('[[mission.segment]]\ntype = "waypoints"\ncruise_speed_m_s = 1\naccel_m_s2 = 1\n[[mission.segment.point]]\nposition = [1, 0, -1]\nhold = 3\n'),
     ["mission.segment #1 (waypoints): point[0].hold: unknown field"]),
    ("land-up.toml", toml('[[mission.segment]]\ntype = "land"\nspeed_m_s = 1\naccel_m_s2 = 1\n'),
     ["mission.segment #1 (land): type: a landing must go down; the segment starts at 0 m and the ground is not below it"]),
    ("takeoff-down.toml", toml(HOLD, '[[mission.segment]]\ntype = "takeoff"\naltitude_m = 1\nspeed_m_s = 1\naccel_m_s2 = 1\n'),
     ["mission.segment #2 (takeoff): altitude_m: a take-off must climb; expected an altitude above the segment's start (2 m), got 1"]),
    ("scenario.toml", '[scenario]\nmission = "paper-helix.toml"\n', ["mission: missing; expected a [mission] table (this looks like a scenario file: its mission is 'paper-helix.toml')"]),
    ("lissajous.toml", toml('[[mission.segment]]\ntype = "lissajous"\ncenter = [0, 0, -5]\namplitude_m = [2, 0, 0]\nangular_rate = [30, 30, 30]\nduration_s = 5\nyaw = "along-path"\n'),
     ["mission.segment #1 (lissajous): lissajous: along-path yaw needs horizontal motion throughout"]),
    # typos name the near name (the issue: "[misson]" said "mission.frame: missing")
    ("misson.toml", toml(HOLD).replace("[mission]\n", "[misson]\n", 1), ["misson: unknown field; did you mean mission?"]),
    ("misson-only.toml", TOML_HEAD.replace("[mission]", "[misson]"), ["mission: missing; expected a [mission] table (is [misson] meant to be [mission]?)"]),
    ("radius-typo.toml", toml('[[mission.segment]]\ntype = "circle"\ncenter = [0, 0, -5]\nradius = 2\nangular_rate = 30\nduration_s = 5\n'),
     ["mission.segment #1 (circle): radius_m: missing (is 'radius' meant to be radius_m?)"]),
    ("duration-typo.toml", toml('[[mission.segment]]\ntype = "line"\nto = [5, 0, -2]\nspeed_m_s = 1\nspede_m_s = 2\n'),
     ["mission.segment #1 (line): spede_m_s: unknown field; did you mean speed_m_s?"]),
    # --- any kind ---
    ("unknown.kml", "<kml/>", ["unknown mission file kind; expected .toml (parametric), .plan (QGroundControl) or a 'QGC WPL 110' waypoint file"]),
]


@pytest.mark.parametrize(("name", "content", "fragments"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_file_gives_one_line(tmp_path, name, content, fragments):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(MissionFormatError) as info:
        load_mission(path)
    message = str(info.value)
    assert isinstance(info.value, (UserError, ValueError))
    assert "\n" not in message
    assert message.startswith(f"{name}: ") or message.startswith(f"{path}: ")
    for fragment in fragments:
        assert fragment in message


def test_missing_file(tmp_path):
    with pytest.raises(MissionFormatError, match="no such file"):
        load_mission(tmp_path / "absent.toml")


# --- round trips -------------------------------------------------------------------------------

WAYPOINTS = [
    Waypoint((20.0, 0.0, -10.0)),
    Waypoint((20.0, 15.0, -12.0), hold_s=3.0, blend_radius_m=1.0),
    Waypoint((-5.0, 15.0, -12.0), yaw_rad=math.radians(-90.0), speed_m_s=2.0),
    Waypoint((-5.0, -10.0, -8.0), blend_radius_m=4.0),
    Waypoint((0.0, 0.0, -8.0), yaw_rad=math.radians(170.0)),
]


def _assert_same_reference(a, b, atol=1e-6):
    assert a.duration_s == pytest.approx(b.duration_s, abs=1e-9)
    sa, sb = sample(a, 0.05), sample(b, 0.05)
    assert_allclose(sa.pos_ned_m, sb.pos_ned_m, atol=atol)
    assert_allclose(sa.vel_ned_m_s, sb.vel_ned_m_s, atol=atol)
    assert_allclose(sa.yaw_rad, sb.yaw_rad, atol=atol)


def test_internal_to_wpl_to_internal(tmp_path):
    """Waypoints -> items about a home -> QGC WPL 110 file -> load: the same reference."""
    items = items_from_waypoints(WAYPOINTS, HOME, DEFAULT_CRUISE_SPEED_M_S, "trip.waypoints")
    path = tmp_path / "trip.waypoints"
    write_wpl(items, path)
    mission = load_mission(path)
    (legs,) = mission.trajectory.segments
    direct = WaypointLegs((0, 0, 0), WAYPOINTS, DEFAULT_CRUISE_SPEED_M_S, DEFAULT_ACCEL_M_S2, "blend", 2.0, "waypoint", 0.0)
    assert_allclose([w.pos_ned_m for w in legs.waypoints], [w.pos_ned_m for w in WAYPOINTS], atol=1e-6)
    _assert_same_reference(legs, direct)
    assert read_wpl(path).items == items.items  # the file holds exactly what was written


def test_local_internal_round_trip(tmp_path):
    items = items_from_waypoints(WAYPOINTS, None, 4.0, "local.waypoints")
    write_wpl(items, tmp_path / "local.waypoints")
    legs = load_mission(tmp_path / "local.waypoints").trajectory.segments[0]
    direct = WaypointLegs((0, 0, 0), WAYPOINTS, 5.0, DEFAULT_ACCEL_M_S2, "blend", 2.0, "waypoint", 0.0)
    # a WPL file has no cruise speed: the default applies until the first DO_CHANGE_SPEED
    assert_allclose(sample(legs).pos_ned_m[-1], sample(direct).pos_ned_m[-1], atol=1e-9)


@pytest.mark.parametrize("name", ["px4-sitl-box.waypoints", "px4-sitl-survey.plan"])
def test_wpl_plan_wpl(tmp_path, name):
    """WPL -> .plan -> WPL gives back the same items and text; both load to the same reference."""
    src = MISSIONS_DIR / name
    original = read_wpl(src) if src.suffix == ".waypoints" else read_plan(src)
    write_plan(original, tmp_path / "a.plan")
    via_plan = read_plan(tmp_path / "a.plan")
    assert via_plan.items == original.items
    assert via_plan.home == original.home
    write_wpl(via_plan, tmp_path / "b.waypoints")
    assert format_wpl(read_wpl(tmp_path / "b.waypoints")) == format_wpl(original)
    _assert_same_reference(load_mission(tmp_path / "a.plan").trajectory, load_mission(tmp_path / "b.waypoints").trajectory, 1e-9)
    doc = json.loads((tmp_path / "a.plan").read_text())
    assert doc["fileType"] == "Plan" and doc["version"] == 1 and doc["mission"]["version"] == 2
    assert doc["mission"]["plannedHomePosition"] == list(HOME)
    assert all(item["type"] == "SimpleItem" and len(item["params"]) == 7 for item in doc["mission"]["items"])


def _mavwp_item(seq: int, frame: int, command: int, params: tuple, x: float, y: float, z: float):
    return mavutil.mavlink.MAVLink_mission_item_message(0, 0, seq, frame, command, 1 if seq == 0 else 0, 1, *params, x, y, z)


def test_reads_files_written_by_mavwp(tmp_path):
    """pymavlink's MAVWPLoader writes the file; positions come back where mavextra put them."""
    from pymavlink.mavextra import gps_offset

    offsets = [(30.0, 0.0, 12.0), (30.0, 25.0, 12.0), (-10.0, 25.0, 8.0)]  # north, east, up
    loader = mavwp.MAVWPLoader()
    loader.add(_mavwp_item(0, 0, 16, (0, 0, 0, 0), *HOME))
    loader.add(_mavwp_item(1, 3, 22, (0, 0, 0, 0), 0, 0, 12.0))
    for k, (n, e, up) in enumerate(offsets):
        lat, lon = gps_offset(HOME[0], HOME[1], e, n)
        loader.add(_mavwp_item(2 + k, 3, 16, (0, 0, 0, float("nan")), lat, lon, up))
    loader.add(_mavwp_item(5, 3, 21, (0, 0, 0, 0), 0, 0, 0))
    path = tmp_path / "mavwp.waypoints"
    loader.save(str(path))
    mission = load_mission(path)
    takeoff, legs, land = mission.trajectory.segments
    for w, (n, e, up) in zip(legs.waypoints, offsets):
        # mavextra's sphere (6 378 100 m) and its %f (1e-6 deg) file differ from PX4's projection by < 0.3 %
        assert_allclose(w.pos_ned_m[:2], (n, e), rtol=3e-3, atol=0.15)
        assert w.pos_ned_m[2] == pytest.approx(-up)
    assert_allclose(land.end_reference.pos_ned_m[2], 0.0)


def test_mavwp_reads_our_files(tmp_path):
    src = read_wpl(MISSIONS_DIR / "px4-sitl-box.waypoints")
    write_wpl(src, tmp_path / "ours.waypoints")
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(tmp_path / "ours.waypoints")) == 1 + len(src.items)
    for ours, theirs in zip((src.home, *src.items), loader.wpoints):
        assert (theirs.command, theirs.frame, theirs.autocontinue) == (ours.command, ours.frame, int(ours.autocontinue))
        assert_allclose(
            [theirs.param1, theirs.param2, theirs.param3, theirs.param4, theirs.x, theirs.y, theirs.z],
            [*ours.params, ours.x, ours.y, ours.z],
            equal_nan=True,
            atol=1e-6,  # MAVLink 1 MISSION_ITEM carries float32
            rtol=1e-7,
        )


def test_written_plan_is_what_qgroundcontrol_expects(tmp_path):
    items = items_from_waypoints(WAYPOINTS, HOME, 3.0)
    write_plan(items, tmp_path / "w.plan")
    doc = json.loads((tmp_path / "w.plan").read_text())
    mission = doc["mission"]
    assert (mission["firmwareType"], mission["vehicleType"], mission["hoverSpeed"]) == (12, 2, 3.0)
    first = mission["items"][0]
    assert first["command"] == 16 and first["frame"] == 3 and first["AltitudeMode"] == 1
    assert first["params"][3] is None  # NaN yaw is null, as QGroundControl writes it
    assert first["Altitude"] == pytest.approx(10.0)
    assert [i["doJumpId"] for i in mission["items"]] == list(range(1, len(mission["items"]) + 1))
    np.testing.assert_equal(read_plan(tmp_path / "w.plan").items, items.items)


@pytest.mark.parametrize("reader, suffix, kind", [(read_wpl, ".waypoints", "waypoint file"), (read_plan, ".plan", ".plan JSON")])
def test_a_file_that_cannot_be_read_is_one_line(tmp_path, reader, suffix, kind):
    """Both readers open their files the same way (offboard.missions.fields.read_mission_text)."""
    folder = tmp_path / f"folder{suffix}"
    folder.mkdir()
    binary = tmp_path / f"binary{suffix}"
    binary.write_bytes(b"\xff\xfe\x00garbage\x80")
    cases = [
        (tmp_path / f"absent{suffix}", "no such file"),
        (folder, "is a directory, expected"),
        (binary, "not a text file; expected"),
        (binary / f"inside{suffix}", "cannot read it: Not a directory"),  # any other OSError
    ]
    for path, fragment in cases:
        with pytest.raises(MissionFormatError) as info:
            reader(path)
        message = str(info.value)
        assert fragment in message and "\n" not in message
        if fragment != "no such file":
            assert kind in message or "cannot read" in message
