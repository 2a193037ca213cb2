"""Trajectories: the Trajectory contract, analytic derivatives, the paper's helix, waypoint limits."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

import offboard.trajectory as trajectory_pkg
from offboard.trajectory import (
    Helix,
    Hold,
    Line,
    Lissajous,
    Polygon,
    Segment,
    Sequence,
    Trajectory,
    VerticalMove,
    Waypoint,
    WaypointLegs,
    circle,
    figure_eight,
    square,
)
from offboard.trajectory.profile import Trapezoid, boundary_speeds
from offboard.trajectory.sampling import sample, summarize

PI = math.pi


def _paper_helix() -> Sequence:
    return Sequence(
        [
            Helix((0, 0, -2), 2.0, 1.0, 0.8, 12.0, yaw_rad=PI / 2, name="helix"),
            Hold((0, 0, -12), -PI / 2, 13.0, "hold-12m"),
            Hold((0, 0, 0), 0.0, 15.0, "descent"),
        ]
    )


# One instance of every trajectory kind, with its yaw modes (the contract and derivative tests
# run on all of them; test_every_class_is_covered fails if a new class is not added here).
CASES = {
    "hold": lambda: Hold((1, 2, -3), 0.5, 4.0),
    "line-fixed": lambda: Line((0, 0, -1), (3, 4, -2), 1.5, yaw_rad=0.3),
    "line-along": lambda: Line((0, 0, -1), (-3, 4, -2), 1.5, yaw_mode="along-path"),
    "helix-fixed": lambda: Helix((0, 0, -2), 2.0, 1.0, 0.8, 12.0, yaw_rad=PI / 2),
    "helix-along-ccw": lambda: Helix((1, 1, -2), 1.5, -0.7, -0.2, 9.0, phase_rad=1.0, yaw_mode="along-path"),
    "helix-center": lambda: Helix((0, 0, -5), 3.0, 0.5, 0.0, 10.0, yaw_mode="center"),
    "circle": lambda: circle((0, 0, -4), 2.0, 0.6, 11.0, yaw_mode="along-path"),
    "lissajous": lambda: Lissajous((0, 0, -5), (2, 1, 0.5), (0.5, 1.0, 0.25), (0, 0.3, 0), 20.0, yaw_rad=0.2),
    "figure-eight-along": lambda: figure_eight((0, 0, -3), 8.0, 4.0, 10.0, 25.0, yaw_mode="along-path"),
    "polygon": lambda: Polygon([(0, 0, -2), (3, 0, -2), (3, 3, -3)], 1.0, closed=True, laps=2, yaw_mode="along-path"),
    "square": lambda: square((0, 0, -5), 5.0, 1.0),
    "legs-stop-fixed": lambda: WaypointLegs((0, 0, 0), [Waypoint((5, 0, -3)), Waypoint((5, 5, -3))], 2.0, 1.0, yaw_rad=0.4),
    "legs-blend-along": lambda: WaypointLegs(
        (0, 0, 0),
        [Waypoint((10, 0, -5)), Waypoint((10, 10, -5), hold_s=2), Waypoint((0, 10, -5)), Waypoint((0, 0, -5)),
         Waypoint((0, 0, -10)), Waypoint((5, 5, -12))],
        3.0, 2.0, corners="blend", yaw_mode="along-path", start_yaw_rad=2.5,
    ),
    "legs-blend-waypoint": lambda: WaypointLegs(
        (0, 0, 0),
        [Waypoint((10, 0, -5), yaw_rad=2.0), Waypoint((10, 10, -5), yaw_rad=-3.0), Waypoint((10, 10, -5), yaw_rad=0.5),
         Waypoint((0, 10, -8)), Waypoint((0, 0, -5), yaw_rad=3.0, speed_m_s=1.0)],
        3.0, 2.0, corners="blend", yaw_mode="waypoint",
    ),
    "vertical": lambda: VerticalMove((1, 2, -5), 0.0, 0.7, 1.0, 0.3, "land", end_yaw_rad=-2.0),
    "sequence-paper": _paper_helix,
}


def _all_trajectory_classes() -> set[type]:
    return {
        obj
        for _, obj in inspect.getmembers(trajectory_pkg, inspect.isclass)
        if obj not in (Segment,) and hasattr(obj, "reference") and not inspect.isabstract(obj) and obj.__module__ != "offboard.trajectory.base"
    }


def test_every_class_is_covered():
    covered = {type(make()) for make in CASES.values()}
    assert _all_trajectory_classes() <= covered


@pytest.mark.parametrize("case", sorted(CASES))
def test_contract(case):
    traj = CASES[case]()
    assert isinstance(traj, Trajectory)
    duration = traj.duration_s
    assert duration > 0 and math.isfinite(duration)
    phases = traj.phases()
    assert phases[0].start_s == 0.0
    assert phases[-1].end_s == pytest.approx(duration)
    for a, b in zip(phases, phases[1:]):
        assert a.end_s == pytest.approx(b.start_s)
    assert all(p.kind in ("track", "hold") for p in phases)
    # after the end: the final point, at rest
    end = traj.reference(duration)
    for t in (duration, duration + 1.0, duration + 1e6):
        ref = traj.reference(t)
        assert_allclose(ref.pos_ned_m, end.pos_ned_m)
        assert_allclose(ref.vel_ned_m_s, 0.0)
        assert_allclose(ref.acc_ned_m_s2, 0.0)
        assert ref.yaw_rate_rad_s == 0.0
        assert ref.yaw_rad == end.yaw_rad
    # the end point is where the motion was heading
    assert_allclose(traj.reference(duration - 1e-9).pos_ned_m, end.pos_ned_m, atol=1e-6)
    # before the start: the start point
    assert_allclose(traj.reference(-1.0).pos_ned_m, traj.reference(0.0).pos_ned_m)


@pytest.mark.parametrize("case", sorted(CASES))
def test_derivatives_match_finite_differences(case):
    """Analytic velocity, acceleration and yaw rate equal one-sided differences of position,
    velocity and yaw (the analytic value is right-continuous, so at a step it equals the
    forward difference; elsewhere both sides agree)."""
    traj = CASES[case]()
    duration = traj.duration_s
    rng = np.random.default_rng(7)
    times = np.concatenate([np.linspace(0.0, duration, 400, endpoint=False), rng.uniform(0.0, duration, 400)])
    h = 1e-6
    tol = 2e-4
    checked = 0
    for t in times:
        if t + h >= duration:
            continue
        r0, rf = traj.reference(t), traj.reference(t + h)
        rb = traj.reference(t - h) if t - h >= 0 else None
        for name, value, f, b in (
            ("vel", r0.vel_ned_m_s, (rf.pos_ned_m - r0.pos_ned_m) / h, None if rb is None else (r0.pos_ned_m - rb.pos_ned_m) / h),
            ("acc", r0.acc_ned_m_s2, (rf.vel_ned_m_s - r0.vel_ned_m_s) / h, None if rb is None else (r0.vel_ned_m_s - rb.vel_ned_m_s) / h),
            ("yaw", r0.yaw_rate_rad_s, (rf.yaw_rad - r0.yaw_rad) / h, None if rb is None else (r0.yaw_rad - rb.yaw_rad) / h),
        ):
            forward_ok = np.allclose(value, f, atol=tol)
            backward_ok = b is not None and np.allclose(value, b, atol=tol)
            assert forward_ok or backward_ok, f"{name} at t = {t}: analytic {value}, forward {f}, backward {b}"
        checked += 1
    assert checked > 700


@pytest.mark.parametrize("case", sorted(set(CASES) - {"sequence-paper", "polygon", "square", "line-fixed", "line-along"}))
def test_continuous_inside_segment(case):
    """Position and yaw never jump inside a segment (only Sequence switches and polygon corners
    step the velocity; none of these steps position or yaw)."""
    dt = 5e-3
    s = sample(CASES[case](), dt)
    step = np.linalg.norm(np.diff(s.pos_ned_m, axis=0), axis=1)
    speed = np.linalg.norm(s.vel_ned_m_s, axis=1)
    assert np.all(step <= dt * speed.max() * 1.01 + 1e-9)
    assert np.all(np.abs(np.diff(s.yaw_rad)) <= dt * np.abs(s.yaw_rate_rad_s).max() * 1.01 + 1e-9)


def test_paper_helix_numbers():
    """Radius 2 m about the origin, climbing 0.8 m/s, turning 1 rad/s, yaw pi/2; starts at (2, 0, 2 up)."""
    traj = _paper_helix()
    t = np.linspace(0.0, 11.99, 1200)
    s = sample(traj, t_end_s=11.99, dt_s=0.01)
    assert_allclose(s.t_s, t)
    assert_allclose(np.hypot(s.pos_ned_m[:, 0], s.pos_ned_m[:, 1]), 2.0, atol=1e-12)  # radius
    assert_allclose(-s.pos_ned_m[:, 2], 2.0 + 0.8 * t, atol=1e-12)  # z_up = 2 + 0.8 t
    assert_allclose(-s.vel_ned_m_s[:, 2], 0.8, atol=1e-12)  # climb 0.8 m/s
    angle = np.unwrap(np.arctan2(s.pos_ned_m[:, 1], s.pos_ned_m[:, 0]))
    assert_allclose(np.diff(angle) / np.diff(t), 1.0, atol=1e-9)  # 1 rad/s
    assert_allclose(s.pos_ned_m[:, 0], 2 * np.cos(t), atol=1e-12)
    assert_allclose(s.pos_ned_m[:, 1], 2 * np.sin(t), atol=1e-12)
    assert_allclose(s.yaw_rad, PI / 2)
    assert_allclose(traj.reference(0.0).pos_ned_m, (2.0, 0.0, -2.0))
    assert_allclose(np.hypot(s.vel_ned_m_s[:, 0], s.vel_ned_m_s[:, 1]), 2.0, atol=1e-12)  # r omega


def test_sequence_switches_are_abrupt():
    """At t = 12 s every reference steps to the hold; at t = 25 s only z and yaw step."""
    traj = _paper_helix()
    before, after = traj.reference(12.0 - 1e-9), traj.reference(12.0)
    assert_allclose(before.pos_ned_m, (2 * math.cos(12.0), 2 * math.sin(12.0), -(2 + 0.8 * 12.0)), atol=1e-6)
    assert_allclose(after.pos_ned_m, (0.0, 0.0, -12.0))
    assert (before.yaw_rad, after.yaw_rad) == (PI / 2, -PI / 2)
    before, after = traj.reference(25.0 - 1e-9), traj.reference(25.0)
    assert_allclose(before.pos_ned_m[:2], after.pos_ned_m[:2])
    assert (before.pos_ned_m[2], after.pos_ned_m[2]) == (-12.0, 0.0)
    assert (before.yaw_rad, after.yaw_rad) == (-PI / 2, 0.0)
    assert [(p.name, p.start_s, p.end_s, p.kind) for p in traj.phases()] == [
        ("helix", 0.0, 12.0, "track"),
        ("hold-12m", 12.0, 25.0, "hold"),
        ("descent", 25.0, 40.0, "hold"),
    ]
    jumps = summarize(traj).jumps
    assert [j.t_s for j in jumps] == [12.0, 25.0]
    assert jumps[1].position_m == pytest.approx(12.0)


def test_square_is_piecewise_linear_at_constant_speed():
    traj = square((0, 0, -5), 5.0, 1.0)
    corners = [(0, 0), (5, 0), (5, 5), (0, 5), (0, 0)]
    for k, (n, e) in enumerate(corners):
        assert_allclose(traj.reference(5.0 * k).pos_ned_m, (n, e, -5.0), atol=1e-12)
    assert traj.duration_s == pytest.approx(20.0)
    s = sample(traj, 0.01, t_end_s=19.99)
    assert_allclose(np.linalg.norm(s.vel_ned_m_s, axis=1), 1.0)
    assert_allclose(s.acc_ned_m_s2, 0.0)
    # the velocity jumps at the corners (the paper's "sharp variations")
    assert_allclose(traj.reference(5.0 - 1e-9).vel_ned_m_s, (1, 0, 0))
    assert_allclose(traj.reference(5.0).vel_ned_m_s, (0, 1, 0))


def test_trapezoid_profile():
    p = Trapezoid(10.0, 0.0, 0.0, 2.0, 1.0)
    assert p.duration_s == pytest.approx(10.0 / 2.0 + 2.0 / 1.0)  # L/v + v/a
    assert p.at(p.duration_s)[:2] == (10.0, 0.0)
    assert p.at(1.0) == pytest.approx((0.5, 1.0, 1.0))
    tri = Trapezoid(1.0, 0.0, 0.0, 10.0, 1.0)  # too short to reach 10 m/s
    assert tri.v_peak == pytest.approx(1.0)
    assert tri.duration_s == pytest.approx(2.0)
    v = boundary_speeds([1.0, 100.0, 1.0], [5.0, 5.0, 5.0], [False, False, False], 2.0)
    assert v[0] == v[-1] == 0.0
    assert v[1] == pytest.approx(2.0) and v[2] == pytest.approx(2.0)  # sqrt(2 a L)


LEG_POINTS = [(20, 0, -5), (20, 15, -5), (5, 15, -10), (5, 30, -10), (0, 0, -2)]


@pytest.mark.parametrize("corners", ["stop", "blend"])
@pytest.mark.parametrize("yaw_mode", ["fixed", "along-path", "waypoint"])
def test_waypoint_legs_respect_limits_and_reach_waypoints(corners, yaw_mode):
    cruise, accel, blend = 3.0, 1.5, 2.0
    wps = [Waypoint(p, yaw_rad=0.3 * k if yaw_mode == "waypoint" else None) for k, p in enumerate(LEG_POINTS)]
    legs = WaypointLegs((0, 0, 0), wps, cruise, accel, corners, blend, yaw_mode, max_yaw_rate_rad_s=1.0)
    s = sample(legs, 0.005)
    speed = np.linalg.norm(s.vel_ned_m_s, axis=1)
    assert speed.max() <= cruise + 1e-9
    assert speed.max() > 0.9 * cruise  # long legs do reach cruise
    assert np.linalg.norm(s.acc_ned_m_s2, axis=1).max() <= accel + 1e-9
    assert_allclose(s.pos_ned_m[0], (0, 0, 0))
    assert_allclose(s.vel_ned_m_s[0], 0.0)
    assert_allclose(legs.reference(legs.duration_s).pos_ned_m, LEG_POINTS[-1], atol=1e-9)
    for p in LEG_POINTS[:-1]:
        closest = np.linalg.norm(s.pos_ned_m - np.array(p), axis=1).min()
        assert closest <= (1e-6 if corners == "stop" else blend) + 0.01
    if corners == "stop":  # at rest on every waypoint
        for p in LEG_POINTS:
            k = np.argmin(np.linalg.norm(s.pos_ned_m - np.array(p), axis=1))
            assert speed[k] < 0.02
    if yaw_mode == "fixed":
        assert_allclose(s.yaw_rad, 0.0)
    if yaw_mode == "along-path":
        assert np.abs(s.yaw_rate_rad_s).max() <= 1.0 + 1e-6
        moving = np.hypot(s.vel_ned_m_s[:, 0], s.vel_ned_m_s[:, 1]) > 0.05
        heading = np.arctan2(s.vel_ned_m_s[moving, 1], s.vel_ned_m_s[moving, 0])
        assert_allclose(np.angle(np.exp(1j * (s.yaw_rad[moving] - heading))), 0.0, atol=1e-6)
    if yaw_mode == "waypoint":
        for k, p in enumerate(LEG_POINTS):
            if corners == "stop" or k == len(LEG_POINTS) - 1:
                i = np.argmin(np.linalg.norm(s.pos_ned_m - np.array(p), axis=1))
                assert math.remainder(s.yaw_rad[i] - 0.3 * k, 2 * PI) == pytest.approx(0.0, abs=0.01)


def test_waypoint_legs_time_optimal_single_leg_and_speed_change():
    legs = WaypointLegs((0, 0, 0), [Waypoint((30, 0, 0))], 3.0, 1.5)
    assert legs.duration_s == pytest.approx(30.0 / 3.0 + 3.0 / 1.5)
    slow = WaypointLegs((0, 0, 0), [Waypoint((30, 0, 0)), Waypoint((60, 0, 0), speed_m_s=1.0)], 3.0, 1.5, corners="blend")
    s = sample(slow, 0.01)
    second = s.pos_ned_m[:, 0] > 31.0
    assert np.linalg.norm(s.vel_ned_m_s[second], axis=1).max() <= 1.0 + 1e-9
    assert np.linalg.norm(s.vel_ned_m_s[~second], axis=1).max() == pytest.approx(3.0)


def test_waypoint_hold_is_a_hold_phase():
    legs = WaypointLegs((0, 0, 0), [Waypoint((5, 0, -2), hold_s=4.0, label="pic"), Waypoint((5, 5, -2))], 2.0, 1.0)
    phases = legs.phases()
    assert [p.kind for p in phases] == ["track", "hold", "track"]
    hold = phases[1]
    assert hold.name == "waypoints:hold-pic"
    assert hold.end_s - hold.start_s == pytest.approx(4.0)
    for t in np.linspace(hold.start_s, hold.end_s - 1e-6, 20):
        ref = legs.reference(t)
        assert_allclose(ref.pos_ned_m, (5, 0, -2), atol=1e-9)
        assert_allclose(ref.vel_ned_m_s, 0.0, atol=1e-9)


def test_along_path_turns_in_place_at_stops():
    legs = WaypointLegs((0, 0, 0), [Waypoint((5, 0, 0)), Waypoint((5, 5, 0))], 1.0, 1.0, "stop", yaw_mode="along-path",
                        max_yaw_rate_rad_s=0.5)
    s = sample(legs, 0.01)
    still = np.linalg.norm(s.vel_ned_m_s, axis=1) < 1e-12
    turning = still & (np.abs(s.yaw_rate_rad_s) > 1e-6)
    assert turning.any()  # the 90 deg turn happens at rest on the corner
    assert_allclose(s.pos_ned_m[turning], np.tile((5, 0, 0), (int(turning.sum()), 1)), atol=1e-9)
    assert np.abs(s.yaw_rate_rad_s).max() == pytest.approx(0.5, rel=1e-3)
    assert s.yaw_rad[-1] == pytest.approx(PI / 2)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: Helix((0, 0, 0), -1.0, 1.0, 0.0, 1.0), "radius_m must be > 0"),
        (lambda: Helix((0, 0, 0), 1.0, 0.0, 0.0, 1.0), "angular_rate_rad_s must be nonzero"),
        (lambda: Line((0, 0, 0), (0, 0, 0), 1.0), "coincide"),
        (lambda: Line((0, 0, 0), (1, 0, 0), 0.0), "speed_m_s must be > 0"),
        (lambda: Hold((0, 0, math.nan), 0.0, 1.0), "must be finite"),
        (lambda: Hold((0, 0, 0), 0.0, 0.0), "duration_s must be finite and > 0"),
        (lambda: WaypointLegs((0, 0, 0), [], 1.0, 1.0), "at least one waypoint"),
        (lambda: WaypointLegs((0, 0, 0), [Waypoint((1, 0, 0))], 1.0, 1.0, corners="round"), "corners must be one of"),
        (lambda: Polygon([(0, 0, 0), (0, 0, 0)], 1.0), "coincide"),
        (lambda: figure_eight((0, 0, 0), 0.0, 1.0, 1.0, 1.0), "length_m must be > 0"),
        (lambda: Lissajous((0, 0, 0), (1, 0, 0), (1, 1, 1), (0, 0, 0), 5.0, yaw_mode="along-path"), "horizontal speed vanishes"),
    ],
)
def test_bad_parameters_raise_value_error(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_reference_lookup_uses_precomputed_starts():
    """Sequence and waypoint legs find their piece by bisection on start times fixed at construction."""
    traj = _paper_helix()
    assert traj.starts_s == (0.0, 12.0, 25.0)
    assert [traj.segment_at(t) for t in (-1.0, 0.0, 11.999, 12.0, 30.0, 99.0)] == [0, 0, 0, 1, 2, 2]


def test_a_shifted_trajectory_moves_positions_only_and_a_tiny_offset_not_at_all():
    from offboard.trajectory.shifted import MIN_SHIFT_M, ShiftedTrajectory, shift_trajectory

    helix = Helix(center_ned_m=(0.0, 0.0, -2.0), radius_m=2.0, angular_rate_rad_s=1.0, climb_rate_m_s=0.8, duration_s=12.0)
    assert shift_trajectory(helix, None) is helix
    assert shift_trajectory(helix, (MIN_SHIFT_M / 2, 0.0, -MIN_SHIFT_M / 2)) is helix
    moved = shift_trajectory(helix, (-1.5, 2.0, 0.25))
    assert isinstance(moved, ShiftedTrajectory) and moved.duration_s == helix.duration_s and moved.phases() == helix.phases()
    for t in (0.0, 3.3, 12.0, 20.0):
        a, b = helix.reference(t), moved.reference(t)
        assert_allclose(b.pos_ned_m - a.pos_ned_m, [-1.5, 2.0, 0.25], atol=1e-12)
        assert_allclose(b.vel_ned_m_s, a.vel_ned_m_s, rtol=0, atol=0)
        assert_allclose(b.acc_ned_m_s2, a.acc_ned_m_s2, rtol=0, atol=0)
        assert (b.yaw_rad, b.yaw_rate_rad_s) == (a.yaw_rad, a.yaw_rate_rad_s)
