"""The vehicle handed to its own landing in flight, with the real processes: its GPS failed by a
ground station (MAV_CMD_INJECT_FAILURE, as on PX4 with SYS_FAILURE_EN), and a wind it cannot
beat. ``offboard fly`` ends ESTIMATE_LOST (exit 11) or LOST_TRACK (exit 9) where it happens, not
at the mission's end, and the tlog says what the vehicle said and what we asked."""

from __future__ import annotations

import json
import re
import struct
import subprocess
import time

import numpy as np
import pytest
from pymavlink import mavutil

from helpers.flights import ENV, PY, error_3d, fly, hover_mission, read_tlog, series
from offboard.metrics import LOST_TRACK_M
from offboard.model.vehicle import PAPER_VEHICLE_FILE

pytestmark = pytest.mark.e2e

mav = mavutil.mavlink
PX4_SIH_VEHICLE = PAPER_VEHICLE_FILE.parent / "px4-sih.toml"


def _int_param(value: int) -> float:
    """A PX4 INT32 parameter's bytes in PARAM_SET's float field."""
    return struct.unpack("<f", struct.pack("<i", value))[0]


def test_a_gps_failed_by_a_ground_station_ends_estimate_lost_and_lands(tmp_path):
    results = {}

    def fail_gps(ctx):
        ctx.wait_for("mission started")
        time.sleep(0.3)
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ctx.gcs_port}", source_system=255, source_component=190, dialect="common")
        try:
            gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            gcs.mav.param_set_send(1, 1, b"SYS_FAILURE_EN", _int_param(1), mav.MAV_PARAM_TYPE_INT32)
            value = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
            results["param"] = None if value is None else value.param_id
            gcs.mav.command_long_send(1, 1, mav.MAV_CMD_INJECT_FAILURE, 0, mav.FAILURE_UNIT_SENSOR_GPS, mav.FAILURE_TYPE_OFF,
                                      0, 0, 0, 0, 0)  # fmt: skip
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=10)
            results["ack"] = None if ack is None else ack.result
        finally:
            gcs.close()

    # a hover far longer than the test: a lockstep flight runs many times faster than real time
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 2.0, 600.0), gcs=True, during=fail_gps)
    assert results == {"param": "SYS_FAILURE_EN", "ack": mav.MAV_RESULT_ACCEPTED}
    assert flown.returncode == 11, flown.stderr
    assert flown.status == "estimate_lost" and flown.summary["exit_code"] == 11
    assert flown.summary["lost_track_m"] == LOST_TRACK_M and flown.summary["watch_estimator"] is True
    assert "no longer vouches for its horizontal velocity, horizontal position" in flown.summary["detail"]
    assert "offboard fly: ESTIMATE_LOST: at t = " in flown.stderr
    assert "vehicle: GPS unhealthy (SYS_STATUS)" in flown.stderr and "vehicle: horizontal position control unhealthy" in flown.stderr
    assert flown.summary["landed"] and flown.summary["disarmed"]
    assert flown.summary["duration_s"] < 590.0  # ended where it happened
    msgs = read_tlog(flown.tlog)
    flags = [m.flags for m in msgs if m.get_type() == "ESTIMATOR_STATUS"]
    assert flags[0] & mav.ESTIMATOR_POS_HORIZ_REL and not flags[-1] & mav.ESTIMATOR_POS_HORIZ_REL  # in the log, both
    assert [m for m in msgs if m.get_type() == "COMMAND_LONG" and m.command == mav.MAV_CMD_NAV_LAND]
    # the replay tells the same story from the log alone, in the order it happened
    replay = subprocess.run([PY, "-m", "offboard.cli", "replay", str(flown.tlog), "--no-plots", "--json", "--run-dir",
                             str(tmp_path / "replay")], capture_output=True, text=True, env=ENV, timeout=120)  # fmt: skip
    assert replay.returncode == 0, replay.stderr
    events = [(e["kind"], e["text"]) for e in json.loads(replay.stdout)["log_report"]["events"] if e["kind"] in ("health", "estimator")]
    # the GPS unhealthy at once; 5 s later, in the same period of both 5 Hz streams, in either order, the
    # position control unhealthy and the estimator giving up
    assert events[0] == ("health", "GPS unhealthy (SYS_STATUS)")
    assert set(events[1:3]) == {("health", "horizontal position control unhealthy (SYS_STATUS)"),
                                ("estimator", "the vehicle's estimator no longer vouches for its horizontal velocity, "
                                              "horizontal position (ESTIMATOR_STATUS flags 0x365)")}  # fmt: skip


def test_a_wind_the_vehicle_cannot_beat_ends_lost_track_in_flight(tmp_path):
    """PX4 SIH's twin (1 N s/m of drag) in 15 m/s of wind: 15 N against the 6.9 N that 35 degrees of
    tilt give 1 kg. It is blown away, the flight ends LOST_TRACK in flight and it lands downwind."""
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 2.0, 60.0),
                plant_args=("--vehicle", str(PX4_SIH_VEHICLE), "--wind", "constant:15,0,0"))  # fmt: skip
    assert flown.returncode == 9, flown.stderr
    assert flown.status == "lost_track"
    assert "not closing" in flown.summary["detail"] and "handed to the vehicle's landing" in flown.summary["detail"]
    s = series(flown)
    err = error_3d(s)
    assert s["t_s"][-1] < 30.0  # in flight, not at the mission's end
    assert err[-1] > LOST_TRACK_M and np.all(np.diff(s["pos_ned_m_0"][-20:]) > 0)  # blown north, still going
    assert flown.summary["landed"] and flown.summary["disarmed"]
    # what docs/offboard.md says of this flight (lockstep: the same figures every run)
    doc = " ".join((PAPER_VEHICLE_FILE.parents[2] / "docs" / "offboard.md").read_text().split())
    quoted = re.search(r"is handed over ([0-9.]+) s into a hover, ([0-9.]+) m downwind", doc)
    flown_figures = re.search(r"at t = ([0-9.]+) s the vehicle was ([0-9.]+) m off", flown.summary["detail"])
    assert quoted and flown_figures and quoted.groups() == flown_figures.groups()


def test_with_the_guard_off_the_same_wind_is_flown_to_its_end(tmp_path):
    """``--lost-track-m inf``: flown to the mission's end, whose verdict is still lost_track (metrics.check_tracking);
    the summary says the guards were off (null: never, strict JSON)."""
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 2.0, 20.0),
                plant_args=("--vehicle", str(PX4_SIH_VEHICLE), "--wind", "constant:15,0,0"),
                fly_args=("--lost-track-m", "inf", "--ignore-estimator"))  # fmt: skip
    assert flown.returncode == 9, flown.stderr
    assert flown.summary["detail"].startswith("flown to its end but")
    assert flown.summary["lost_track_m"] is None and flown.summary["watch_estimator"] is False
    assert series(flown)["t_s"][-1] == pytest.approx(20.0, abs=0.06)
