"""The mission's own reference steps are told apart from tracking: per step its size and how long
its transient lasted, and a one-line verdict on the tracking once settled (the demo's 12 m maxima
are the paper's deliberate steps, not errors the controller made)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from offboard.metrics import SETTLED_M, format_table, summarize, verdict
from offboard.record import COLUMNS, RecordBuilder


def record(ref_north: list[float], pos_north: list[float], dt_s: float = 0.05, tilt_rad: float = 0.1):
    rows = RecordBuilder(COLUMNS)
    for k, (r, p) in enumerate(zip(ref_north, pos_north)):
        rows.append(t_s=k * dt_s, pos_ned_m=(p, 0.0, -1.0), vel_ned_m_s=(0.0, 0.0, 0.0), euler_rad=(tilt_rad, 0.0, 0.0),
                    ref_pos_ned_m=(r, 0.0, -1.0), ref_yaw_rad=0.0, ref_euler_rad=(0.0, 0.0, 0.0), thrust_n=5.0,
                    torques_nm=(0.0, 0.0, 0.0), tau_tilde=(0.0, 0.0, 0.0))  # fmt: skip
    return rows.build()


def test_a_step_its_transient_and_the_tracking_after_it():
    # 2 s on the reference (0.01 m off), a 5 m step at t = 2 s closed at 2.5 m/s, then 0.02 m off
    ref = [0.0] * 40 + [5.0] * 100
    pos = [-0.01] * 40 + [min(5.0 - 0.02, 0.125 * k) for k in range(1, 101)]
    summary = summarize(record(ref, pos))
    assert [(s.t_s, s.size_m) for s in summary.reference_steps] == [(2.0, 5.0)]
    (step,) = summary.reference_steps
    first_settled = next(k for k in range(100) if 5.0 - pos[40 + k] < SETTLED_M)
    assert step.settled_after_s == pytest.approx(first_settled * 0.05)
    assert summary.phases[0].axes["3d"].max_m == pytest.approx(4.875)  # the step, in the table's max
    assert summary.settled.max_m == pytest.approx(max(5.0 - pos[40 + first_settled], 0.02))
    assert summary.settled.max_m < SETTLED_M
    text = format_table(summary)
    assert "reference steps (the mission's own, not tracking errors; the maxima above include them):" in text
    assert f"  t =   2.00 s    5.00 m  settled to 0.1 m in {step.settled_after_s:.2f} s" in text
    assert text.splitlines()[-1] == f"verdict: {verdict(summary)}"
    assert verdict(summary).startswith("tracked within 0.0") and verdict(summary).endswith(f"peak tilt {np.degrees(0.1):.1f} deg")


def test_a_start_far_from_the_reference_is_a_step_and_one_never_closed_says_so():
    summary = summarize(record([3.0] * 50, [0.01 * k for k in range(50)]))
    assert [round(s.size_m, 2) for s in summary.reference_steps] == [3.0]
    assert summary.reference_steps[0].settled_after_s is None and summary.settled is None
    assert "not within 0.1 m by the end (2.45 s)" in format_table(summary)
    assert verdict(summary).startswith("never within 0.1 m of the reference after the steps")


def test_without_steps_the_whole_flight_is_tracking_and_without_references_nothing_is_claimed():
    smooth = summarize(record([0.02 * k for k in range(60)], [0.02 * k - 0.03 for k in range(60)]))
    assert smooth.reference_steps == [] and smooth.settled.max_m == pytest.approx(0.03)
    assert verdict(smooth).startswith("tracked within 0.030 m (3D RMS 0.030 m)")
    none = summarize(record([float("nan")] * 10, [0.0] * 10))
    assert none.reference_steps == [] and verdict(none).startswith("no references to track")
    payload = json.loads(json.dumps(none.to_dict()))
    assert payload["settled"] is None and payload["verdict"].startswith("no references")


def test_long_phase_names_are_printed_whole():
    """A waypoint file's phases ("waypoints 3..6:to-item4", "waypoints 3..6:hold-item4") were cut to
    16 characters, both "waypoints 3..6:t": the column is as wide as the longest name."""
    from offboard.trajectory.base import Phase, PhaseKind

    rec = record([0.0] * 100, [0.01] * 100)
    phases = [Phase("waypoints 3..6:to-item4", 0.0, 2.0), Phase("waypoints 3..6:hold-item4", 2.0, 5.0, PhaseKind.HOLD)]
    lines = format_table(summarize(rec, phases)).splitlines()
    rows = [line for line in lines if line.startswith("waypoints")]
    assert [row.split("  ")[0].strip() for row in rows] == ["waypoints 3..6:to-item4", "waypoints 3..6:hold-item4"]
    assert len({line.index("span s") for line in lines[:1]}) == 1 and all(len(row) == len(lines[0]) for row in rows)
    # a short name keeps the table as it was
    assert format_table(summarize(rec)).splitlines()[0].startswith(f"{'phase':<16} {'span s':>11}  {'3d rms':>7}")
