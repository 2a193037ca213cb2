"""bench/design.py's verdicts on issue 11's flight targets, from rows made here."""

from __future__ import annotations

import pytest

from bench.design import _target_lines, main, markdown, px4_sensors_stopped, repeat_summary


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
        {**_row("real PX4", "px4-sitl-survey.plan", "real time", 0.3, None, status="estimate_lost"), "px4_sensors_stopped": True},
    ])  # fmt: skip
    verdicts = [line for line in lines if line.startswith("- ")]
    assert verdicts == [
        "- sitl-plant, paper-helix.toml, real time: met",
        "- real PX4, paper-helix.toml, real time: met",
        "- real PX4, paper-square.toml, real time: met",
        "- real PX4, paper-helix.toml, --speed 4, vehicle clock: not met: hold tilt 5.1 deg > 5, helix 0.120 m > 0.1",
        "- real PX4, figure-eight.toml, real time: not met: status link lost",
        "- real PX4, px4-sitl-survey.plan, real time: not met: status estimate_lost, hold tilt n/a deg > 5 "
        "(PX4's simulated sensors stopped: its px4.log says so)",
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


def test_repeated_flights_are_judged_one_by_one_and_counted():
    flights = [_row("real PX4", "paper-helix.toml", "real time", 0.085, 3.35),
               _row("real PX4", "paper-helix.toml", "real time", 0.117, 5.71),
               _row("real PX4", "paper-helix.toml", "real time", 0.096, 5.15),
               {**_row("real PX4", "paper-helix.toml", "real time", 0.142, None, status="estimate_lost"), "px4_sensors_stopped": True}]  # fmt: skip
    lines = repeat_summary(flights)
    assert lines[0].endswith("hold tilt 3.35 deg  met")
    assert lines[1].endswith("not met: hold tilt 5.7 deg > 5, helix 0.117 m > 0.1")
    assert lines[3].endswith("not met: status estimate_lost, hold tilt n/a deg > 5, helix 0.142 m > 0.1 "
                             "(PX4's simulated sensors stopped: its px4.log says so)")
    assert lines[-1] == ("moving RMS <= 0.1 m: 2 of 4 (0.085-0.142); holds within 5 deg: 1 of 4 (3.35-5.71); "
                         "every target met: 1 of 4 (1 with PX4's simulated sensors stopped: its px4.log says so)")


def test_a_repeated_flight_says_when_its_setpoints_reached_px4_when_px4s_log_told():
    latency = {"sent": 900, "paired": 800, "p50_ms": 4.0, "p90_ms": 12.0, "max_ms": 16.0}
    flights = [{**_row("real PX4", "paper-helix.toml", "real time", 0.054, 3.51), "px4_setpoint_latency": latency},
               {**_row("real PX4", "paper-helix.toml", "real time", 0.055, 3.4), "px4_setpoint_latency": None}]
    lines = repeat_summary(flights)
    assert lines[0].endswith("hold tilt 3.51 deg  met; setpoints reached PX4 4 ms (p50), 12 ms (p90) after the "
                             "ATTITUDE they answer, in its clock")
    assert lines[1].endswith("hold tilt 3.40 deg  met")


def test_a_px4_whose_sensors_stopped_is_told_by_its_log(tmp_path):
    (tmp_path / "px4").mkdir()
    assert not px4_sensors_stopped(tmp_path)  # no log
    (tmp_path / "px4" / "px4.log").write_text("INFO  [commander] Takeoff detected\n")
    assert not px4_sensors_stopped(tmp_path)
    (tmp_path / "px4" / "px4.log").write_text("WARN  [health_and_arming_checks] Preflight Fail: No valid data from Baro 0\n")
    assert px4_sensors_stopped(tmp_path)


@pytest.mark.parametrize("args", [["--px4-repeat", "0"], ["--px4-repeat", "2", "--stagger", "-1"], ["--px4-repeat", "2", "--stagger", "nan"]])
def test_the_repeat_command_refuses_a_bad_count_or_stagger_in_one_line(capsys, args):
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    assert exit_info.value.code == 2
    assert "--px4-repeat must be >= 1, --speed > 0 and --stagger >= 0" in capsys.readouterr().err


def test_the_repeat_command_takes_the_stagger_asked(monkeypatch, tmp_path, capsys):
    import bench.design as design
    import bench.px4sitl as px4sitl

    waits = []
    monkeypatch.setattr(px4sitl, "px4_launcher", lambda: "px4")
    monkeypatch.setattr(design.tempfile, "mkdtemp", lambda prefix: str(tmp_path))
    monkeypatch.setattr(design, "fly_px4", lambda mission, run_dir, **kw: waits.append(kw["start_after_s"]) or {"status": "complete"})
    assert main(["--px4-repeat", "3", "--stagger", "0"]) == 0 and waits == [0.0, 0.0, 0.0]


def test_the_repeat_command_hands_offboard_fly_the_options_after_the_double_dash(monkeypatch, capsys, tmp_path):
    import bench.design as design
    import bench.px4sitl as px4sitl

    flown = []
    monkeypatch.setattr(px4sitl, "px4_launcher", lambda: "px4")
    monkeypatch.setattr(design.tempfile, "mkdtemp", lambda prefix: str(tmp_path))
    monkeypatch.setattr(design, "fly_px4", lambda mission, run_dir, **kw: flown.append(kw) or {"status": "complete", "moving_rms_m": 0.05,
                                                                                              "hold_tilt_max_deg": 3.5, "peak_tilt_deg": 30.0})  # fmt: skip
    assert main(["--px4-repeat", "3", "--", "--clock", "vehicle"]) == 0
    # each flight starts later in PX4's clock than the one before (make bench's stagger, by default)
    assert flown == [{"controller": None, "speed": 1.0, "fly_args": ("--clock", "vehicle"), "start_after_s": k * design.PX4_START_STAGGER_S}
                     for k in range(3)]  # fmt: skip
    assert "real PX4, paper-helix.toml, real time --clock vehicle, no controller file: " in capsys.readouterr().out


def test_the_flights_table_gives_the_setpoints_echo_where_a_flight_measured_it():
    echoed = {**_row("real PX4", "paper-helix.toml", "real time", 0.054, 3.5), "setpoint_echo": {"paired": 400, "p50_ms": 4.0, "p90_ms": 8.0, "max_ms": 16.0}}
    lockstep = {**_row("sitl-plant", "paper-helix.toml", "lockstep", 0.02, 0.0), "setpoint_echo": None}
    rows = [line for line in markdown({"flights": [echoed, lockstep], "px4": True}).splitlines() if line.startswith("| real PX4") or line.startswith("| sitl-plant")]
    assert rows[0].endswith("| 4 / 8 |") and rows[1].endswith("| – |")


def test_make_bench_flies_the_real_px4_helix_again_and_counts_its_flights(monkeypatch, tmp_path):
    import bench.design as design
    import bench.px4_own as px4_own

    # the PX4 helix's holds in the order flown: the table's real-time and --speed 4 flights, then the repeats
    tilts = iter([4.2, 5.3, 3.9, 4.98, 5.05, 4.1])
    flown, waits = [], []

    def fly_px4(mission, run_dir, *, controller, speed=1.0, fly_args=(), start_after_s=0.0):
        helix = mission.name == "paper-helix.toml" and controller is None
        flown.append((mission.name, controller, speed))
        if helix:
            waits.append((speed, start_after_s))
        return {"status": "complete", "moving_rms_m": 0.06, "peak_tilt_deg": 30.0,
                "hold_tilt_max_deg": next(tilts) if helix else 3.0}  # fmt: skip

    monkeypatch.setattr(design.tempfile, "mkdtemp", lambda prefix: str(tmp_path))
    monkeypatch.setattr(design, "fly_plant", lambda *a, **kw: {"status": "complete"})
    monkeypatch.setattr(design, "fly_px4", fly_px4)
    monkeypatch.setattr(px4_own, "fly_px4_own", lambda *a: {"status": "complete"})
    result = design.run(px4=True, say=lambda line: None)
    helix = [(c, s) for m, c, s in flown if m == "paper-helix.toml" and c is None]
    assert helix == [(None, 1.0), (None, 4.0)] + [(None, 1.0)] * 2 + [(None, 4.0)] * 2
    # the table's flights start at once, each repeat later in PX4's clock than the one before it
    stagger = design.PX4_START_STAGGER_S
    assert waits == [(1.0, 0.0), (4.0, 0.0), (1.0, stagger), (1.0, 2 * stagger), (4.0, stagger), (4.0, 2 * stagger)]
    assert [len(flights) for flights in result["repeats"].values()] == [design.PX4_HELIX_FLIGHTS] * 2
    lines = [line for line in markdown(result).splitlines() if ", 3 flights: " in line]
    assert lines == [
        "- real time, 3 flights: moving RMS <= 0.1 m: 3 of 3 (0.06-0.06); holds within 5 deg: 3 of 3 (3.9-4.98); "
        "every target met: 3 of 3",
        "- --speed 4, vehicle clock, 3 flights: moving RMS <= 0.1 m: 3 of 3 (0.06-0.06); holds within 5 deg: 1 of 3 "
        "(4.1-5.3); every target met: 1 of 3",
    ]


def _flight_with_a_hold(run_dir, roll_rad, pitch_rad, boot_ms_at_start=5000.0):
    """A run folder like offboard fly's: a 0-12 s climb, a 12-25 s hold at 10 m (its second half 18.5-25 s)."""
    import json

    import numpy as np

    t = np.arange(0.0, 25.0, 0.05)
    up = np.minimum(t, 10.0)
    cols = {"t_s": t, "pos_ned_m_0": 0 * t, "pos_ned_m_1": 0 * t, "pos_ned_m_2": -up, "ref_pos_ned_m_0": 0 * t,
            "ref_pos_ned_m_1": 0 * t, "ref_pos_ned_m_2": -up, "euler_rad_0": roll_rad(t), "euler_rad_1": pitch_rad(t),
            "time_boot_ms": boot_ms_at_start + 1000.0 * t}  # fmt: skip
    run_dir.mkdir()
    np.savetxt(run_dir / "series.csv", np.stack(list(cols.values()), 1), delimiter=",", header=",".join(cols), comments="")
    (run_dir / "summary.json").write_text(json.dumps({"phases": [
        {"name": "whole flight", "start_s": 0.0, "end_s": 25.0, "steady_state_m": None},
        {"name": "climb", "start_s": 0.0, "end_s": 12.0, "steady_state_m": None},
        {"name": "hold-10m", "start_s": 12.0, "end_s": 25.0, "steady_state_m": 0.01}]}))  # fmt: skip
    (run_dir / "px4" / "log" / "today").mkdir(parents=True)
    (run_dir / "px4" / "log" / "today" / "flight.ulg").write_bytes(b"")
    return t


def test_the_hold_by_sihs_truth_is_read_at_the_stamps_of_the_samples_in_the_holds_second_half(tmp_path, monkeypatch):
    import numpy as np

    import bench.design as design
    import bench.px4_log as px4_log

    # EKF2 reads 1 deg more roll and 0.5 deg less pitch than the truth; the truth swings to 4 deg
    # of pitch at 20 s (in the hold's second half) and to 30 deg at 5 s (the climb, not a hold)
    def true_pitch(t):
        return np.radians(4.0 * np.exp(-(((t - 20.0) / 0.3) ** 2)) + 30.0 * np.exp(-(((t - 5.0) / 0.3) ** 2)))

    _flight_with_a_hold(tmp_path / "run", lambda t: np.radians(1.0) + 0 * t, lambda t: true_pitch(t) - np.radians(0.5))
    truth_s = np.arange(0.0, 40.0, 0.004)  # SIH's truth in PX4's clock, the mission starting at 5 s of it
    monkeypatch.setattr(px4_log, "true_roll_pitch", lambda ulog: (truth_s * 1e6, 0 * truth_s, true_pitch(truth_s - 5.0)))
    truth = design.px4_hold_truth(tmp_path / "run")
    assert abs(truth["hold_true_tilt_max_deg"] - 4.0) < 0.05
    assert np.allclose(truth["hold_attitude_error_deg"], [1.0, -0.5], atol=0.02)
    # stamps the log does not cover (another clock) are refused, not extrapolated
    monkeypatch.setattr(px4_log, "true_roll_pitch", lambda ulog: (truth_s * 1e3, 0 * truth_s, true_pitch(truth_s - 5.0)))
    assert design.px4_hold_truth(tmp_path / "run") == {"hold_true_tilt_max_deg": None, "hold_attitude_error_deg": None}


def test_without_a_px4_log_the_holds_truth_is_unknown(tmp_path):
    import bench.design as design

    _flight_with_a_hold(tmp_path / "run", lambda t: 0 * t, lambda t: 0 * t)
    # the empty .ulg is not a PX4 log (or pyulog is missing): one ValueError inside, unknown outside
    assert design.px4_hold_truth(tmp_path / "run") == {"hold_true_tilt_max_deg": None, "hold_attitude_error_deg": None}
    assert design.px4_hold_truth(tmp_path / "missing") == {"hold_true_tilt_max_deg": None, "hold_attitude_error_deg": None}


def test_a_series_without_the_vehicles_stamps_has_no_truth(tmp_path, monkeypatch):
    import numpy as np

    import bench.design as design
    import bench.px4_log as px4_log

    _flight_with_a_hold(tmp_path / "run", lambda t: 0 * t, lambda t: 0 * t)
    series = tmp_path / "run" / "series.csv"
    header, *rows = series.read_text().splitlines()
    series.write_text("\n".join([header.replace("time_boot_ms", "other"), *rows]) + "\n")
    truth_s = np.arange(0.0, 40.0, 0.004)
    monkeypatch.setattr(px4_log, "true_roll_pitch", lambda ulog: (truth_s * 1e6, 0 * truth_s, 0 * truth_s))
    assert design.px4_hold_truth(tmp_path / "run") == {"hold_true_tilt_max_deg": None, "hold_attitude_error_deg": None}


def test_sihs_attitude_is_read_from_its_quaternion(monkeypatch):
    import numpy as np

    import bench.px4_log as px4_log
    from offboard.model.rotations import quat_from_euler

    q = np.array([quat_from_euler(0.1, -0.2, 2.5), quat_from_euler(-0.05, 0.3, -1.0)])
    monkeypatch.setattr(px4_log, "_topic", lambda ulog, name: {"timestamp": np.array([1000, 2000]),
                                                                **{f"q[{k}]": q[:, k] for k in range(4)}})  # fmt: skip
    t_us, roll, pitch = px4_log.true_roll_pitch("x.ulg")
    assert list(t_us) == [1000.0, 2000.0] and np.allclose(roll, [0.1, -0.05]) and np.allclose(pitch, [-0.2, 0.3])


def test_a_repeated_flight_says_what_sihs_truth_saw_of_its_hold_and_when_it_started():
    flights = [{**_row("real PX4", "paper-helix.toml", "--speed 4, vehicle clock", 0.068, 5.06), "hold_true_tilt_max_deg": 4.03,
                "hold_attitude_error_deg": [-1.87, 0.63], "start_after_s": 10.0},
               {**_row("real PX4", "paper-helix.toml", "--speed 4, vehicle clock", 0.065, 3.96), "hold_true_tilt_max_deg": 5.31,
                "hold_attitude_error_deg": [1.97, -0.02], "start_after_s": 0.0}]  # fmt: skip
    lines = repeat_summary(flights)
    assert lines[0].endswith("not met: hold tilt 5.1 deg > 5; SIH's true attitude: hold tilt 4.03 deg, EKF2's roll -1.87 deg "
                             "and pitch +0.63 deg off it on average (started 10 s of PX4's clock after it was ready)")
    assert lines[1].endswith("met; SIH's true attitude: hold tilt 5.31 deg, EKF2's roll +1.97 deg and pitch -0.02 deg off it on average")
    assert lines[-1].endswith("every target met: 1 of 2; by SIH's true attitude, holds within 5 deg: 1 of 2 (4.03-5.31)")
