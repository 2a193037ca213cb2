"""bench/design.py's verdicts on issue 11's flight targets, from rows made here."""

from __future__ import annotations

from bench.design import _target_lines


def _row(vehicle, mission, condition, moving, hold_tilt, peak=30.0, controller="designed", status="complete"):
    return {"vehicle": vehicle, "mission": mission, "controller": controller, "condition": condition, "status": status,
            "moving_rms_m": moving, "hold_tilt_max_deg": hold_tilt, "peak_tilt_deg": peak}  # fmt: skip


def test_each_designed_flight_is_judged_against_its_target():
    lines = _target_lines([
        _row("sitl-plant", "paper-helix.toml", "real time", 0.015, 0.0, peak=33.7),
        _row("sitl-plant", "paper-helix.toml", "real time", 0.2, 30.0, controller="paper"),  # not the designed law
        _row("sitl-plant", "paper-square.toml", "lockstep", 0.1, 0.1),  # not a target's flight
        _row("real PX4", "paper-helix.toml", "real time", 0.091, 3.5),
        _row("real PX4", "paper-square.toml", "real time", 0.147, 4.5),  # square: no helix figure to meet
        _row("real PX4", "paper-helix.toml", "--speed 4, vehicle clock", 0.12, 5.1),
        _row("real PX4", "figure-eight.toml", "real time", 0.14, 4.0, status="link lost"),
    ])  # fmt: skip
    verdicts = [line for line in lines if line.startswith("- ")]
    assert verdicts == [
        "- sitl-plant, paper-helix.toml, real time: met",
        "- real PX4, paper-helix.toml, real time: met",
        "- real PX4, paper-square.toml, real time: met",
        "- real PX4, paper-helix.toml, --speed 4, vehicle clock: not met: hold tilt 5.1 deg > 5, helix 0.120 m > 0.1",
        "- real PX4, figure-eight.toml, real time: not met: status link lost",
    ]


def test_the_demos_flight_must_keep_its_peak_within_the_tilt_limit():
    (line,) = [
        x
        for x in _target_lines([_row("sitl-plant", "paper-helix.toml", "real time", 0.04, 2.0, peak=51.0)])
        if x.startswith("- ")
    ]
    assert line.endswith("not met: peak tilt 51.0 deg > 35")


def test_no_designed_flight_no_lines():
    assert _target_lines([_row("real PX4", "paper-helix.toml", "real time", 0.2, 49.7, controller="paper")]) == []
