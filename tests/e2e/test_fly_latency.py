"""Issue 11's delay target, flown: over 50 +- 20 ms each way the designed law, handed the state
predicted over the latency (offboard.controller.prediction), holds as it does without delay."""

from __future__ import annotations

import json
import math
import re
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from helpers.flights import fly, series, write_mission

# a climb to 2 m, then a 1.5 m step north-east and a 0.5 m step up held for 8 s: the helix's
# hold at 12 m in small (a step from where the vehicle flies to a point held)
STEP_AND_HOLD = """[[mission.segment]]
type = "hold"
name = "climb"
position = [0, 0, 2]
yaw = 0
until_s = 4

[[mission.segment]]
type = "hold"
name = "step"
position = [1.2, 0.9, 2.5]
yaw = 0
until_s = 12
"""


def _hold_rms(flown) -> float:
    s = series(flown)
    t = s["t_s"]
    second_half = (t >= 8.0) & (t < 12.0)
    err = np.stack([s[f"pos_ned_m_{i}"] - s[f"ref_pos_ned_m_{i}"] for i in range(3)], axis=1)
    return float(np.sqrt(np.mean(np.sum(err[second_half] ** 2, axis=1))))


def test_over_a_delayed_link_the_predicted_state_holds_within_twice_the_undelayed_error(tmp_path, capsys):
    """Real time, the same mission without delay and over ``sitl-plant --link delay=50,jitter=20``
    (both ways), flown at once. The delayed flight measures its latency (~110 ms), designs for the
    predicted state with the autopilot's rate loop observed and says so; the second half of its
    hold is at most twice the undelayed flight's error (issue 11's target; in the helix's hold
    0.93-1.38x, 1.73-1.99x with the rate loop taken at hover, where the measured state's design
    held 0.104 m against 0.0007 m). Its prediction of the tilt is better than no prediction (the
    deadbeat observer's was not: 2.70 deg against 2.91)."""
    mission = write_mission(tmp_path / "step.toml", STEP_AND_HOLD)
    with ThreadPoolExecutor(2) as pool:
        clean = pool.submit(fly, tmp_path, mission, lockstep=False, name="clean")
        late = pool.submit(fly, tmp_path, mission, lockstep=False, name="late",
                           plant_args=("--link", "delay=50,jitter=20", "--seed", "3"))  # fmt: skip
        clean_flown, late_flown = clean.result(), late.result()
    for flown in (clean_flown, late_flown):
        assert flown.returncode == 0 and flown.status == "complete", flown.stderr
    said = re.search(r"latency (\d+) ms, the law handed the state predicted over it", late_flown.stderr)
    assert said and 80 <= int(said.group(1)) <= 200, late_flown.stderr  # ~2 x 50 ms + one telemetry period
    assert re.search(r"latency \d+ ms, the law handed the state predicted over it, the rate loop observed", late_flown.stderr)
    # for replay --rerun: observed, with 20 samples of memory
    assert late_flown.summary["observed_rate_loop"] is True and late_flown.summary["observer_memory_s"] == 1.0
    # without delay the latency is one telemetry period and the loopback's round trip (~11 ms)
    said = re.search(r"latency (\d+) ms, the law handed the state predicted over it", clean_flown.stderr)
    assert said and int(said.group(1)) < 40, clean_flown.stderr
    # the loop's latency in the vehicle's clock, from its ATTITUDE_TARGET echo (offboard.echo):
    # the measurement's way down and the setpoint's way up, ~2 x 50 ms, as the design's round trip
    # says; without delay the plant takes an answer in the 4 ms tick it arrives in (0 or 8 ms at the median)
    late_echo, clean_echo = late_flown.summary["setpoint_echo"], clean_flown.summary["setpoint_echo"]
    print(f"\nsetpoint echo: {late_echo} over 50 +- 20 ms, {clean_echo} without")
    assert late_echo["paired"] > 50 and 60.0 <= late_echo["p50_ms"] <= 160.0, late_echo
    assert clean_echo["paired"] > 50 and clean_echo["p50_ms"] <= 10.0, clean_echo
    assert "setpoint echo: the vehicle took the setpoints" in (late_flown.run_dir / "summary.txt").read_text()
    clean_rms, late_rms = _hold_rms(clean_flown), _hold_rms(late_flown)
    print(f"\nhold's second half: {late_rms:.5f} m over 50 +- 20 ms, {clean_rms:.5f} m without")
    assert math.isfinite(late_rms) and late_rms <= 2.0 * clean_rms
    # how well the delayed flight's prediction predicted, from its log (offboard replay --rerun):
    # the state it handed the law against what the vehicle reported a latency later, beside the
    # measured state's own difference (what a law handed the measurement answers)
    from offboard.cli import main

    earlier = capsys.readouterr().out  # what was printed so far, out of the JSON's way
    assert main(["replay", str(late_flown.run_dir / "flight.tlog"), "--rerun", "--json", "--no-plots",
                 "--run-dir", str(tmp_path / "rerun")]) in (0, 1)  # fmt: skip  (1: the link's gaps make the re-run differ)
    replayed = json.loads(capsys.readouterr().out)
    check = replayed["rerun"]["prediction"]
    print(earlier, end="")
    # the echo from the log is the echo the flight measured
    assert replayed["log_report"]["setpoint_echo"] == late_echo
    print(f"prediction over {check['latency_s'] * 1000:.0f} ms: position {check['position_rms_m'] * 1000:.1f} mm "
          f"({check['position_rms_measured_m'] * 1000:.1f} measured), velocity {check['velocity_rms_m_s'] * 1000:.1f} mm/s "
          f"({check['velocity_rms_measured_m_s'] * 1000:.1f}), thrust axis {check['tilt_rms_deg']:.2f} deg "
          f"({check['tilt_rms_measured_deg']:.2f})")  # fmt: skip
    assert check["samples"] > 200 and 0.08 <= check["latency_s"] <= 0.2
    # flown (the helix over a 50 +- 20 ms link, three flights): 2.9-4.5 mm against 132-138 mm, 61-81 mm/s against 176-196,
    # 0.93-1.09 deg against 2.79-3.03
    assert check["position_rms_m"] < 0.25 * check["position_rms_measured_m"]
    assert check["velocity_rms_m_s"] < 0.75 * check["velocity_rms_measured_m_s"]
    assert check["tilt_rms_deg"] < 0.75 * check["tilt_rms_measured_deg"]


def test_with_no_observe_the_delayed_flight_takes_the_rate_loop_at_hover_and_its_rerun_does_too(tmp_path, capsys):
    """``offboard fly --no-observe`` over the same delayed link: it does not say it observes the
    rate loop, records so in summary.json, holds within twice the undelayed flight's error
    (1.73-1.99x on the helix) and ``offboard replay --rerun`` re-runs it at hover (its label says
    so); the undelayed flight, predicting over its ~11 ms, observes by default."""
    mission = write_mission(tmp_path / "step.toml", STEP_AND_HOLD)
    with ThreadPoolExecutor(2) as pool:
        clean = pool.submit(fly, tmp_path, mission, lockstep=False, name="clean")
        late = pool.submit(fly, tmp_path, mission, lockstep=False, name="at-hover", fly_args=("--no-observe",),
                           plant_args=("--link", "delay=50,jitter=20", "--seed", "5"))  # fmt: skip
        clean_flown, late_flown = clean.result(), late.result()
    for flown in (clean_flown, late_flown):
        assert flown.returncode == 0 and flown.status == "complete", flown.stderr
    assert re.search(r"latency \d+ ms, the law handed the state predicted over it", late_flown.stderr)
    assert "the rate loop observed" not in late_flown.stderr
    assert late_flown.summary["observed_rate_loop"] is False and late_flown.summary["observer_memory_s"] is None
    assert clean_flown.summary["observed_rate_loop"] is True
    # the loop's latency in the vehicle's clock, from its ATTITUDE_TARGET echo (offboard.echo):
    # the measurement's way down and the setpoint's way up, ~2 x 50 ms, as the design's round trip
    # says; without delay the plant takes an answer in the 4 ms tick it arrives in (0 or 8 ms at the median)
    late_echo, clean_echo = late_flown.summary["setpoint_echo"], clean_flown.summary["setpoint_echo"]
    print(f"\nsetpoint echo: {late_echo} over 50 +- 20 ms, {clean_echo} without")
    assert late_echo["paired"] > 50 and 60.0 <= late_echo["p50_ms"] <= 160.0, late_echo
    assert clean_echo["paired"] > 50 and clean_echo["p50_ms"] <= 10.0, clean_echo
    assert "setpoint echo: the vehicle took the setpoints" in (late_flown.run_dir / "summary.txt").read_text()
    clean_rms, late_rms = _hold_rms(clean_flown), _hold_rms(late_flown)
    print(f"\nat hover: hold's second half {late_rms:.5f} m over 50 +- 20 ms, {clean_rms:.5f} m without")
    assert math.isfinite(late_rms) and late_rms <= 2.0 * clean_rms
    from offboard.cli import main

    capsys.readouterr()
    assert main(["replay", str(late_flown.run_dir / "flight.tlog"), "--rerun", "--json", "--no-plots",
                 "--run-dir", str(tmp_path / "rerun")]) in (0, 1)  # fmt: skip  (1: the link's gaps make the re-run differ)
    rerun = json.loads(capsys.readouterr().out)["rerun"]
    assert "state predicted over" in rerun["controller"] and "the rate loop observed" not in rerun["controller"]
    assert rerun["prediction"]["samples"] > 200
