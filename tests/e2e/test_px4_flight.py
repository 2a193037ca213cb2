"""``offboard fly`` against a real PX4 v1.16 SITL (SIH quadrotor), with no controller file.

The offboard reads SIH's vehicle (SIH_MASS, SIH_T_MAX x rotors, SIH_I**, SIH_KDV) and PX4's
MC_* gains, designs the law's gains for that inner loop (docs/controller-design.md) and flies.
Before the design, Table I's gains flew an attitude limit cycle of +-20-36 deg in every hold.
"""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest

from offboard.missions import MISSIONS_DIR
from bench.design import px4_hold_truth
from bench.px4_log import latency_figures, px4_ulog, setpoint_latencies_ms, true_roll_pitch
from bench.px4sitl import running_px4
from helpers.flights import ENV, PY

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py


def assert_no_limit_cycle(tilt_deg: np.ndarray) -> None:
    """The second half of the hold at 12 m holds, with no limit cycle: Table I's gains ring there at
    39 deg RMS tilt, 49.7 deg at most (make bench). The designed law's tilt in the hold is not
    the loop's own: it follows EKF2's errors. SIH's truth (``python bench/px4_estimator.py``) has
    the vehicle wandering 0.10-0.12 m (std, north) while the estimate it is held on moves 0.04-0.06 m,
    with EKF2's velocity 0.14-0.50 m/s off on average; the tilt that takes was 1.6-2.3 deg RMS and
    3.3-5.4 deg at most over ten flights, the most on a loaded machine (a CI run). Issue 11's
    target (at most 5 deg) is that maximum, measured and reported by ``make bench``'s real PX4 rows,
    not timed here; this asserts what tells a hold from a limit cycle, with room for the estimator."""
    rms = float(np.sqrt(np.mean(tilt_deg**2)))
    assert rms < 4.0 and tilt_deg.max() < 10.0, (rms, float(tilt_deg.max()))


def test_the_paper_helix_flies_smoothly_through_px4s_attitude_loop(tmp_path):
    run = tmp_path / "run"
    with running_px4(tmp_path / "px4") as px4:
        flown = subprocess.run(
            [PY, "-m", "offboard.cli", "fly", str(MISSIONS_DIR / "paper-helix.toml"), "--connect",
             f"udpin:127.0.0.1:{px4.api_listen_port}", "--run-dir", str(run), "--no-plots", "--json"],
            capture_output=True, text=True, env=ENV, timeout=240,
        )  # fmt: skip
    assert flown.returncode == 0, flown.stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["controller_choice"] == "tuned"
    c = summary["controller"]
    # SIH's vehicle, read from PX4: 1 kg, 4 x 5 N, its inertia and drag; no --thrust-max-n needed
    assert c["mass_kg"] == pytest.approx(1.0) and c["thrust_max_n"] == pytest.approx(20.0)
    assert c["inertia_kg_m2"] == pytest.approx([0.025, 0.025, 0.03]) and c["linear_drag_n_s_m"] == pytest.approx(1.0)
    assert c["gains"]["kx1"] != 0.78  # designed, not Table I's
    # PX4's EKF2 aligns its heading from the magnetometer 1.5 m above the take-off point: read from
    # PX4 (EKF2_MAG_TYPE, SYS_HAS_MAG, EKF2_DELAY_MAX), the helix's first turn waits for it
    hold = summary["takeoff_heading_hold"]
    assert hold["mode"] == "auto" and hold["held"] and abs(hold["heading_deg"]) < 10.0, hold
    assert summary["vehicle_params"]["EKF2_DELAY_MAX"] == pytest.approx(200.0)
    assert 1.0 < hold["released_s"] < 4.0  # 1.2 s after the vehicle passed 1.5 m, 0.9-1.0 s into the climb
    d = np.genfromtxt(run / "series.csv", delimiter=",", names=True)
    t = d["t_s"]
    tilt = np.degrees(np.arccos(np.cos(d["euler_rad_0"]) * np.cos(d["euler_rad_1"])))
    err = np.linalg.norm(np.stack([d[f"pos_ned_m_{i}"] - d[f"ref_pos_ned_m_{i}"] for i in range(3)], 1), axis=1)
    hold = (t >= 18.5) & (t < 25.0)  # the second half of the hold at 12 m
    helix = (t >= 5.0) & (t < 11.9)
    helix_rms = float(np.sqrt(np.mean(err[helix] ** 2)))
    tilt_rms = float(np.sqrt(np.mean(tilt[hold] ** 2)))
    print(f"\nreal PX4: hold tilt max {tilt[hold].max():.2f} deg, RMS {tilt_rms:.2f} deg, helix 5-11.9 s RMS {helix_rms:.3f} m")
    assert_no_limit_cycle(tilt[hold])
    # The design predicts 0.05 m; PX4 SITL in real time flew 0.054-0.100 m in twelve flights with
    # the take-off heading hold (0.07-0.25 m before it; its EKF and the machine's load move it). 0.5 m still catches a wrong frame, sign or scale,
    # any of which costs metres; the hold's tilt above is what tells Table I (49 deg) apart.
    assert helix_rms < 0.5
    # the tilt read above is EKF2's (ATTITUDE); SIH's own, in PX4's log at the stamps of the same
    # samples (bench.design.px4_hold_truth, which make bench reports beside it), moves with it:
    # correlated 0.72-0.99 on each axis in eleven flights, EKF2 leaning 0.2-0.9 deg off it on
    # average in real time, up to 2 deg at --speed 4 (docs/controller-design.md). A stamp on
    # another clock, a second late, or an axis or sign mixed up breaks the correlation.
    truth = px4_hold_truth(run, tmp_path / "px4")
    t_us, true_roll, true_pitch = true_roll_pitch(px4_ulog(tmp_path / "px4"))
    stamps_us = d["time_boot_ms"][hold] * 1000.0
    correlation = [float(np.corrcoef(d[f"euler_rad_{k}"][hold], np.interp(stamps_us, t_us, truth_k))[0, 1])
                   for k, truth_k in enumerate((true_roll, true_pitch))]  # fmt: skip
    print(f"SIH's truth: hold tilt max {truth['hold_true_tilt_max_deg']:.2f} deg, EKF2's roll and pitch "
          f"{truth['hold_attitude_error_deg']} deg off it, correlated {correlation}")
    assert min(correlation) > 0.5, correlation
    assert abs(truth["hold_true_tilt_max_deg"] - tilt[hold].max()) < 3.0 and max(map(abs, truth["hold_attitude_error_deg"])) < 3.0
    # its own log re-runs exactly: the latency prediction it flew (summary.json, series.csv's
    # telemetry ages), and each sample paired with the ATTITUDE of its position's instant, which
    # PX4's streams log before a newer one in a tenth of the samples (before, a quarter of the
    # samples read another position and every command after the first differed)
    assert summary["predicted_latency_s"] is not None
    # (the thrust scale from the log, SIH_T_MAX x CA_ROTOR_COUNT, as offboard fly read it: no --thrust-max-n)
    replay = subprocess.run([PY, "-m", "offboard.cli", "replay", str(run / "flight.tlog"), "--rerun",
                             "--run-dir", str(tmp_path / "replay"), "--no-plots", "--json"],
                            capture_output=True, text=True, env=ENV, timeout=240)  # fmt: skip
    assert replay.returncode == 0, replay.stderr
    rerun = json.loads(replay.stdout)["rerun"]
    assert rerun["exact"] and rerun["samples"] == len(t), rerun["first_mismatch"]
    # how well the prediction predicted PX4: over ~10 ms its position lands on what EKF2 then
    # reported (2.7 mm RMS against 14.4 mm measured; 3.9 against 14.2 at --speed 4), while its
    # velocity, which EKF2's noise dominates over 10 ms, gains little (18.8 against 20.5 mm/s)
    check = rerun["prediction"]
    print(f"prediction over {check['latency_s'] * 1000:.0f} ms: position {check['position_rms_m'] * 1000:.1f} mm "
          f"({check['position_rms_measured_m'] * 1000:.1f} measured), velocity {check['velocity_rms_m_s'] * 1000:.1f} mm/s "
          f"({check['velocity_rms_measured_m_s'] * 1000:.1f})")  # fmt: skip
    assert check["samples"] > 0.9 * len(t) and check["position_rms_m"] < 0.5 * check["position_rms_measured_m"]
    # the latency the law was designed for (the TIMESYNC round trip and one telemetry period, in
    # the offboard's clock) against PX4's own log of when each setpoint reached it, in its clock,
    # from the ATTITUDE stamp the setpoint answers (bench/px4_log.py): 4 ms median, 8-12 ms p90,
    # in real time as at --speed 4, against the design's 10 ms
    latency = latency_figures(setpoint_latencies_ms(run / "flight.tlog", tmp_path / "px4"))
    designed_ms = summary["predicted_latency_s"] * 1000.0
    echo = summary["setpoint_echo"]
    print(f"setpoints in PX4's log: {latency}; offboard fly's ATTITUDE_TARGET echo: {echo}; designed for {designed_ms:.1f} ms")
    assert latency["paired"] > 0.9 * len(t) and latency["p50_ms"] <= designed_ms, latency
    # what offboard fly measured over MAVLink (PX4's ATTITUDE_TARGET at 10 Hz: every other setpoint)
    # is what PX4 logged, to one of SIH's 4 ms steps of PX4's clock
    assert echo["paired"] > 0.4 * len(t) and abs(echo["p50_ms"] - latency["p50_ms"]) <= 4.0, echo


def test_the_body_rate_output_flies_the_paper_helix_on_px4s_rate_loop(tmp_path):
    """--output rates, no controller file, PX4 at --speed 4: the law closes the attitude loop itself
    with angle gains designed for SIH's rate loop. Flown with the default --clock auto, which must
    find PX4's clock running faster than ours and sample on it (the only PX4 flight that tries the
    detection). Measured: helix 5-11.9 s 0.081 m RMS, the hold's second half within 4.1 deg (real
    time: 0.158 m, 4.5 deg)."""
    run = tmp_path / "run"
    with running_px4(tmp_path / "px4", speed=4) as px4:
        flown = subprocess.run(
            [PY, "-m", "offboard.cli", "fly", str(MISSIONS_DIR / "paper-helix.toml"), "--connect",
             f"udpin:127.0.0.1:{px4.api_listen_port}", "--output", "rates", "--run-dir", str(run),
             "--no-plots", "--json"],
            capture_output=True, text=True, env=ENV, timeout=240,
        )  # fmt: skip
    assert flown.returncode == 0, flown.stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["controller_choice"] == "tuned" and summary["output"] == "rates"
    # --clock auto measured PX4's clock (4x ours when the host keeps up; less on a loaded one) and
    # took it: on our own clock the 10 ms samples would be 40 ms of PX4's
    assert summary["clock"] == "vehicle" and summary["clock_rate"] > 1.5, (summary["clock"], summary["clock_rate"])
    assert summary["controller"]["gains"]["kx7"] != 0.7  # designed for the rate loop, not Table I's
    d = np.genfromtxt(run / "series.csv", delimiter=",", names=True)
    t = d["t_s"]
    tilt = np.degrees(np.arccos(np.cos(d["euler_rad_0"]) * np.cos(d["euler_rad_1"])))
    err = np.linalg.norm(np.stack([d[f"pos_ned_m_{i}"] - d[f"ref_pos_ned_m_{i}"] for i in range(3)], 1), axis=1)
    hold = (t >= 18.5) & (t < 25.0)
    helix_rms = float(np.sqrt(np.mean(err[(t >= 5.0) & (t < 11.9)] ** 2)))
    print(f"\nreal PX4, body rates: hold tilt max {tilt[hold].max():.2f} deg, helix 5-11.9 s RMS {helix_rms:.3f} m")
    assert_no_limit_cycle(tilt[hold])
    assert helix_rms < 0.5  # as above: catches a wrong frame, sign or scale (metres)


def test_px4_flies_on_in_offboard_without_gps_and_the_offboard_hands_it_to_its_landing(tmp_path):
    """PX4's answer, written down: with its GPS stopped (``sensor_gps_sim stop``, PX4's own shell:
    this SIH build never answers MAV_CMD_INJECT_FAILURE), PX4 v1.16 keeps an attitude-driven
    Offboard running, system status ACTIVE, no failsafe (measured for 40 s by hand, while EKF2's
    estimate ran ~150 m off). About 5 s after the stop EKF2's ESTIMATOR_STATUS drops its horizontal
    velocity and position flags (0x37f to 0x365); ``offboard fly`` then ends ESTIMATE_LOST
    (exit 11) and PX4's Land mode lands the vehicle blind. At --speed 4 (the same in PX4's time)."""
    from helpers.flights import write_mission
    from pymavlink import mavutil

    mission = write_mission(tmp_path / "hold.toml", '[[mission.segment]]\ntype = "hold"\nname = "hold"\n'
                                                    'position = [0, 0, 3]\nyaw = 0\nuntil_s = 120\n')  # fmt: skip
    run = tmp_path / "run"
    with running_px4(tmp_path / "px4", speed=4) as px4:
        with (tmp_path / "fly.stderr").open("w") as err:
            fly = subprocess.Popen([PY, "-m", "offboard.cli", "fly", str(mission), "--connect", f"udpin:127.0.0.1:{px4.api_listen_port}",
                                    "--run-dir", str(run), "--no-plots", "--json"], stdout=subprocess.PIPE, stderr=err, text=True, env=ENV)  # fmt: skip
        try:
            deadline = time.monotonic() + 120
            while "mission started" not in (tmp_path / "fly.stderr").read_text() and fly.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(1.0)  # 4 s of PX4's: in the hold
            stopped_s = time.time()  # the tlog's clock in real time: wall seconds
            px4.shell("sensor_gps_sim", "stop")
            fly.communicate(timeout=120)
        finally:
            if fly.poll() is None:
                fly.kill()
                fly.communicate()
    stderr = (tmp_path / "fly.stderr").read_text()
    assert fly.returncode == 11, stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "estimate_lost" and "horizontal velocity, horizontal position" in summary["detail"], summary["detail"]
    assert summary["landed"] and summary["disarmed"]
    mav = mavutil.mavlink
    log = mavutil.mavlink_connection(str(run / "flight.tlog"))
    beats, flags_lost_s, land_s = [], None, None
    while (m := log.recv_match()) is not None and land_s is None:
        kind = m.get_type()
        if m._timestamp < stopped_s:
            continue
        if kind == "HEARTBEAT" and m.get_srcSystem() == 1 and m.autopilot == mav.MAV_AUTOPILOT_PX4:
            beats.append(m)
        elif kind == "ESTIMATOR_STATUS" and flags_lost_s is None and not m.flags & mav.ESTIMATOR_POS_HORIZ_REL:
            flags_lost_s = m._timestamp
        elif kind == "COMMAND_LONG" and m.command == mav.MAV_CMD_NAV_LAND:
            land_s = m._timestamp
    assert flags_lost_s is not None and land_s is not None and land_s >= flags_lost_s
    print(f"\nPX4 without GPS: EKF2's flags dropped {4 * (flags_lost_s - stopped_s):.1f} s of PX4's time after the stop, "
          f"NAV_LAND {1000 * (land_s - flags_lost_s):.0f} ms of ours later; {len(beats)} heartbeats between")
    # from the GPS stop to our landing command PX4 stayed in Offboard, ACTIVE: no failsafe of its own
    assert len(beats) >= 3 and all((b.custom_mode >> 16) & 0xFF == 6 and b.system_status == mav.MAV_STATE_ACTIVE for b in beats)
