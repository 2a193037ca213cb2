"""``offboard fly`` switches off the vehicle's streams it never reads (issue 16), as PX4's clients do:
two real processes on loopback UDP, the message types counted in both processes' tlogs."""

from __future__ import annotations

from collections import Counter

import pytest
from pymavlink.dialects.v20 import common as mavlink

from offboard import codec
from helpers.flights import fly, hover_mission, read_tlog

pytestmark = pytest.mark.e2e

VEHICLE, US = 1, 245
UNREAD = {mavlink.mavlink_map[mid].msgname for mid in codec.UNREAD_STREAMS if mid in mavlink.mavlink_map}


def _split_at_stream_setup(messages: list) -> tuple[Counter, Counter, list]:
    """The vehicle's message types before our first SET_MESSAGE_INTERVAL and after the last ACK of
    one (the whole mission and landing), and the SET_MESSAGE_INTERVAL commands we sent."""
    commands = [m for m in messages if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
                and m.get_srcSystem() == US]  # fmt: skip
    first = next(i for i, m in enumerate(messages) if m in commands)
    last_ack = max(i for i, m in enumerate(messages) if m.get_type() == "COMMAND_ACK"
                   and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and m.get_srcSystem() == VEHICLE)  # fmt: skip
    before = Counter(m.get_type() for m in messages[:first] if m.get_srcSystem() == VEHICLE)
    after = Counter(m.get_type() for m in messages[last_ack + 1 :] if m.get_srcSystem() == VEHICLE)
    return before, after, commands


def test_lockstep_flight_switches_off_the_unread_streams_and_samples_at_its_rate(tmp_path):
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 1.0, 2.0))
    assert flown.returncode == 0, flown.stderr
    assert flown.status == "complete"
    for log in (flown.tlog, flown.plant_tlog):  # what the offboard heard, and what the plant sent
        before, after, commands = _split_at_stream_setup(read_tlog(log))
        # they were on: PX4's onboard defaults at >= 20 Hz arrive every lockstep period
        assert {"ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "HIGHRES_IMU", "ODOMETRY"} <= set(before), before
        assert set(after) & UNREAD == set(), after  # and none came after
        assert after["ATTITUDE"] >= 40 and after["LOCAL_POSITION_NED"] == after["ATTITUDE"]  # 2 s hover, landing: one a period
        assert after["HEARTBEAT"] > 0 and after["EXTENDED_SYS_STATE"] > 0  # read: kept on
        offs = {int(m.param1) for m in commands if m.param2 == codec.INTERVAL_OFF_US}
        assert offs == set(codec.UNREAD_STREAMS)
        rates = {int(m.param1): m.param2 for m in commands if m.param2 > 0}
        # 1/To, To = 50 ms; the estimator's state at 5 Hz (offboard.flight.guards)
        assert rates == {**{mid: 50_000.0 for mid in codec.SAMPLED_STREAMS}, mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 200_000.0}
        assert after["ESTIMATOR_STATUS"] >= 10  # 5 Hz of the vehicle's time, through the hover and the landing
    assert "SET_MESSAGE_INTERVAL refused" not in flown.stderr


def test_keep_streams_leaves_them_on(tmp_path):
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 1.0, 1.0), fly_args=("--keep-streams", "--telemetry-rate", "0"))
    assert flown.returncode == 0, flown.stderr
    sent = read_tlog(flown.tlog)
    assert not [m for m in sent if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL]
    last = Counter(m.get_type() for m in sent[len(sent) // 2 :] if m.get_srcSystem() == VEHICLE)
    assert {"ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "HIGHRES_IMU", "ODOMETRY"} <= set(last)


def test_real_time_flight_switches_them_off_too_but_for_the_setpoints_echo(tmp_path):
    flown = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 1.0, 1.5), lockstep=False)
    assert flown.returncode == 0, flown.stderr
    before, after, commands = _split_at_stream_setup(read_tlog(flown.tlog))
    assert set(after) & UNREAD == {"ATTITUDE_TARGET"}, after  # read in real time: the setpoints' echo
    assert after["ATTITUDE_TARGET"] >= 20 and flown.summary["setpoint_echo"]["paired"] >= 10, flown.summary["setpoint_echo"]
    assert {"ATTITUDE_QUATERNION", "HIGHRES_IMU"} <= set(before)
    # real time: the smallest multiple of the 20 Hz sample rate at or above 100 Hz; the echo at PX4's 10 Hz
    assert {int(m.param1): m.param2 for m in commands if m.param2 > 0} == {**{mid: 10_000.0 for mid in codec.SAMPLED_STREAMS},
                                                                            mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 200_000.0,
                                                                            mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: 100_000.0}
    # --no-setpoint-echo: off with the rest
    quiet = fly(tmp_path, hover_mission(tmp_path / "hover.toml", 1.0, 1.5), lockstep=False, name="quiet",
                fly_args=("--no-setpoint-echo",))  # fmt: skip
    assert quiet.returncode == 0, quiet.stderr
    _, after, _ = _split_at_stream_setup(read_tlog(quiet.tlog))
    assert set(after) & UNREAD == set(), after
    assert quiet.summary["setpoint_echo"] is None
