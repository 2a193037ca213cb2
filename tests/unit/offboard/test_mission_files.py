"""Mission files: every bundled file flies, the paper's references, waypoint-file semantics, geodesy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from offboard.errors import MissionFormatError
from offboard.missions import MISSIONS_DIR, Mission, load_mission, mission_from_table, resolve_mission
from offboard.missions.geo import EARTH_RADIUS_M, LocalProjection
from offboard.trajectory import Helix, Hold, Polygon, Sequence, VerticalMove, WaypointLegs
from offboard.trajectory.sampling import sample, summarize

BUNDLED = sorted(
    p for p in MISSIONS_DIR.iterdir() if p.is_file() and not p.name.startswith(("paper-sim", "sweep-")) and p.suffix in (".toml", ".plan", ".waypoints")
)
HOME = (47.397742, 8.545594, 488.0)


def test_bundled_files_found():
    names = {p.name for p in BUNDLED}
    assert {"paper-helix.toml", "paper-square.toml", "figure-eight.toml", "all-segments.toml"} <= names
    assert any(p.suffix == ".plan" for p in BUNDLED) and any(p.suffix == ".waypoints" for p in BUNDLED)


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.name)
def test_every_bundled_mission_loads_and_flies(path):
    mission = load_mission(path)
    assert isinstance(mission, Mission)
    traj = mission.trajectory
    s = sample(traj, 0.01)
    for arr in (s.pos_ned_m, s.vel_ned_m_s, s.acc_ned_m_s2, s.yaw_rad, s.yaw_rate_rad_s):
        assert np.all(np.isfinite(arr))
    assert s.pos_ned_m[:, 2].max() <= 1e-6  # never underground (the origin is on the ground)
    # position is continuous except where one segment hands over to another
    boundaries = np.array(traj.starts_s[1:]) if isinstance(traj, Sequence) else np.array([])
    step = np.linalg.norm(np.diff(s.pos_ned_m, axis=0), axis=1)
    speed = np.linalg.norm(s.vel_ned_m_s, axis=1)
    jumps = np.nonzero(step > 0.01 * speed.max() * 1.01 + 1e-9)[0]
    for k in jumps:
        assert np.any(np.abs(boundaries - s.t_s[k + 1]) <= 0.011), f"jump inside a segment at t = {s.t_s[k + 1]}"
    assert traj.phases()[-1].end_s == pytest.approx(traj.duration_s)


def test_paper_helix_file():
    mission = load_mission(MISSIONS_DIR / "paper-helix.toml")
    traj = mission.trajectory
    assert isinstance(traj, Sequence)
    helix, hold, descent = traj.segments
    assert isinstance(helix, Helix) and isinstance(hold, Hold) and isinstance(descent, Hold)
    assert (helix.radius_m, helix.climb_rate_m_s, helix.angular_rate_rad_s) == (2.0, 0.8, 1.0)  # the paper's numbers
    assert_allclose(helix.center_ned_m, (0, 0, -2))
    assert [(p.name, p.start_s, p.end_s, p.kind) for p in traj.phases()] == [
        ("helix", 0.0, 12.0, "track"),
        ("hold-12m", 12.0, 25.0, "hold"),
        ("descent", 25.0, 40.0, "hold"),
    ]
    for t in (0.0, 3.3, 11.9):  # x = 2 cos t, y = 2 sin t, z_up = 2 + 0.8 t, psi = pi/2
        ref = traj.reference(t)
        assert_allclose(ref.pos_ned_m, (2 * math.cos(t), 2 * math.sin(t), -(2 + 0.8 * t)), atol=1e-12)
        assert ref.yaw_rad == pytest.approx(math.pi / 2)
    assert_allclose(traj.reference(12.0).pos_ned_m, (0, 0, -12))
    assert traj.reference(12.0).yaw_rad == pytest.approx(-math.pi / 2)
    assert_allclose(traj.reference(25.0).pos_ned_m, (0, 0, 0))
    assert traj.reference(25.0).yaw_rad == 0.0
    assert traj.duration_s == 40.0
    assert mission.start_ned_m == (0.0, 0.0, 0.0)
    text = (MISSIONS_DIR / "paper-helix.toml").read_text()
    assert "cannot pass through x = y = 0" in text  # the stated choice stays in the file


def test_paper_square_file():
    traj = load_mission(MISSIONS_DIR / "paper-square.toml").trajectory
    square_seg, hold = traj.segments
    assert isinstance(square_seg, Polygon) and isinstance(hold, Hold)
    for k, (n, e) in enumerate([(0, 0), (5, 0), (5, 5), (0, 5), (0, 0)]):
        assert_allclose(traj.reference(5.0 * k).pos_ned_m, (n, e, -5.0), atol=1e-12)
    assert traj.duration_s == pytest.approx(25.0)
    assert [p.kind for p in traj.phases()] == ["track", "hold"]
    assert_allclose(traj.reference(7.5).vel_ned_m_s, (0, 1, 0))


def test_all_segments_file_has_every_type():
    from offboard.missions.parametric import SEGMENT_TYPES

    text = (MISSIONS_DIR / "all-segments.toml").read_text()
    for kind in SEGMENT_TYPES:
        assert f'type = "{kind}"' in text


# --- waypoint files: semantics -------------------------------------------------------------------


def _wpl(tmp_path: Path, rows: list[str], name: str = "m.waypoints", header: str = "QGC WPL 110") -> Path:
    home = "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.0\t1"
    path = tmp_path / name
    path.write_text("\n".join([header, home, *rows]) + "\n")
    return path


def _ll(north: float, east: float) -> tuple[float, float]:
    lat, lon, _ = LocalProjection(*HOME).global_from_ned(north, east, 0.0)
    return lat, lon


def test_waypoint_file_semantics(tmp_path):
    lat1, lon1 = _ll(30.0, 0.0)
    lat2, lon2 = _ll(30.0, 30.0)
    rows = [
        "1\t0\t3\t22\t0\t0\t0\tnan\t0\t0\t10\t1",  # takeoff to 10 m (lat = lon = 0: here)
        "2\t0\t2\t178\t1\t2.5\t-1\t0\t0\t0\t0\t1",  # ground speed 2.5 m/s
        f"3\t0\t3\t16\t4\t0\t0\tnan\t{lat1}\t{lon1}\t10\t1",  # waypoint, hold 4 s
        f"4\t0\t0\t16\t0\t0\t0\tnan\t{lat2}\t{lon2}\t508.0\t1",  # AMSL frame: 20 m above home
        "5\t0\t2\t178\t3\t0.5\t-1\t0\t0\t0\t0\t1",  # descent speed 0.5 m/s
        "6\t0\t3\t21\t0\t0\t0\tnan\t0\t0\t0\t1",  # land here
    ]
    mission = load_mission(_wpl(tmp_path, rows))
    assert mission.home == HOME
    traj = mission.trajectory
    kinds = [type(s) for s in traj.segments]
    assert kinds == [VerticalMove, WaypointLegs, VerticalMove]
    takeoff, legs, land = traj.segments
    assert_allclose(takeoff.end_reference.pos_ned_m, (0, 0, -10))
    assert max(np.abs(sample(takeoff).vel_ned_m_s[:, 2])) == pytest.approx(1.5)  # PX4's MPC_TKO_SPEED
    assert_allclose([w.pos_ned_m for w in legs.waypoints], [(30, 0, -10), (30, 30, -20)], atol=1e-6)
    assert np.linalg.norm(sample(legs).vel_ned_m_s, axis=1).max() == pytest.approx(2.5)
    assert_allclose(land.end_reference.pos_ned_m, (30, 30, 0), atol=1e-6)
    assert np.abs(sample(land).vel_ned_m_s[:, 2]).max() == pytest.approx(0.5)
    assert [p.kind for p in traj.phases()] == ["track", "track", "hold", "track", "track"]
    assert traj.phases()[2].name == "waypoints 3..4:hold-item3"


def test_waypoint_yaw_and_loiter_and_local_frames(tmp_path):
    rows = [
        "1\t0\t1\t16\t0\t0\t0\t90\t10\t0\t-5\t1",  # LOCAL_NED: 10 m north, 5 m up, yaw east
        "2\t0\t1\t19\t3\t0\t0\t0\t10\t10\t-5\t1",  # loiter 3 s at (10, 10, -5)
    ]
    home = "0\t1\t1\t16\t0\t0\t0\t0\t0\t0\t0\t1"
    path = tmp_path / "local.waypoints"
    path.write_text("\n".join(["QGC WPL 110", home, *rows]) + "\n")
    mission = load_mission(path)
    assert mission.home is None
    traj = mission.trajectory
    (legs,) = traj.segments
    assert_allclose(traj.reference(traj.duration_s).pos_ned_m, (10, 10, -5))
    assert legs.reference(legs.duration_s).yaw_rad == pytest.approx(math.pi / 2)
    assert [p.kind for p in traj.phases()][-1] == "hold"
    assert traj.phases()[-1].end_s - traj.phases()[-1].start_s == pytest.approx(3.0)
    enu = tmp_path / "enu.waypoints"  # LOCAL_ENU: x east, y north, z up
    enu.write_text("QGC WPL 110\n0\t1\t4\t16\t0\t0\t0\t0\t0\t0\t0\t1\n1\t0\t4\t16\t0\t0\t0\tnan\t3\t4\t5\t1\n")
    assert_allclose(load_mission(enu).trajectory.reference(1e9).pos_ned_m, (4, 3, -5))


def test_geo_projection():
    proj = LocalProjection(*HOME)
    # 0.001 deg of latitude is R pi / 180e3 metres north
    north, east, down = proj.ned_from_global(HOME[0] + 1e-3, HOME[1], HOME[2] + 10.0)
    assert north == pytest.approx(EARTH_RADIUS_M * math.pi / 180e3, rel=1e-9)
    assert abs(east) < 1e-9 and down == pytest.approx(-10.0)
    rng = np.random.default_rng(3)
    for n, e, d in rng.uniform(-5000, 5000, size=(50, 3)):
        back = proj.ned_from_global(*proj.global_from_ned(n, e, d))
        assert_allclose(back, (n, e, d), atol=1e-7)


# --- scenario embedding ------------------------------------------------------------------------


def test_resolve_mission_file_table_and_errors(tmp_path):
    (tmp_path / "mine.toml").write_text(
        '[mission]\nframe = "ned"\nangle_unit = "deg"\n[[mission.segment]]\ntype = "hold"\nposition = [0, 0, -1]\nduration_s = 2\n'
    )
    assert resolve_mission("mine.toml", "scenario.toml", tmp_path).trajectory.duration_s == 2.0
    assert resolve_mission("paper-helix.toml", "scenario.toml", tmp_path).name == "paper-helix"  # bundled fallback
    table = {"frame": "paper-zup", "angle_unit": "rad", "segment": [{"type": "hold", "position": [0, 0, 3], "yaw": "pi", "duration_s": 5}]}
    embedded = resolve_mission(table, "scenario.toml", tmp_path)
    assert embedded.source == "scenario.toml: mission"
    assert_allclose(embedded.trajectory.reference(1.0).pos_ned_m, (0, 0, -3))
    assert embedded.trajectory.reference(1.0).yaw_rad == pytest.approx(math.pi)
    assert mission_from_table(table, "scenario.toml", tmp_path).name == "scenario"
    with pytest.raises(MissionFormatError, match=r"scenario\.toml: mission: no mission file 'nope\.toml'"):
        resolve_mission("nope.toml", "scenario.toml", tmp_path)
    with pytest.raises(MissionFormatError, match=r"scenario\.toml: mission: expected a mission file name"):
        resolve_mission(3, "scenario.toml", tmp_path)
    bad = dict(table, segment=[{"type": "hold", "duration_s": -1}])
    with pytest.raises(MissionFormatError, match=r"^scenario\.toml: mission\.segment #1 \(hold\): duration_s: must be > 0"):
        mission_from_table(bad, "scenario.toml", tmp_path)


def test_summary_reports_lengths_and_peaks():
    s = summarize(load_mission(MISSIONS_DIR / "paper-helix.toml").trajectory)
    helix = s.segments[0]
    assert helix.length_m == pytest.approx(12.0 * math.hypot(2.0, 0.8), rel=1e-4)
    assert helix.max_speed_m_s == pytest.approx(math.hypot(2.0, 0.8))
    assert helix.max_accel_m_s2 == pytest.approx(2.0)  # r omega^2
    assert s.min_ned_m[2] == pytest.approx(-12.0) and s.max_ned_m[2] == pytest.approx(0.0)
