"""Replay of MAVLink logs the project did not write, damaged logs, statistics and streaming.

The "foreign" log is written here with pymavlink, as a PX4 vehicle seen by a ground station
would leave it: another system id, no setpoints, ATTITUDE and LOCAL_POSITION_NED at different
rates and stamps, POSITION_TARGET_LOCAL_NED, mode changes, a failsafe, a telemetry gap and
packets missing from the sequence.
"""

from __future__ import annotations

import json
import math
import socket
import struct
import threading
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pymavlink.dialects.v20 import common as mavlink

from offboard.cli import main
from offboard.errors import LogFormatError
from offboard.flight.guards import heading_reset_deg
from offboard.replay.report import format_log_report
from offboard.replay import (
    LoggedMessage,
    LogScan,
    SeqCounter,
    TlogReader,
    build_record,
    log_report,
    px4_mode_name,
    scan_log,
    stream_log,
)

from helpers.logs import DROPPED, EPOCH_US, MODE_HOLD, MODE_LAND, MODE_OFFBOARD, VEHICLE, ForeignLog, write_foreign_log


@pytest.fixture(scope="module")
def foreign(tmp_path_factory) -> ForeignLog:
    return write_foreign_log(tmp_path_factory.mktemp("foreign") / "px4-gcs.tlog")


@pytest.fixture(scope="module")
def foreign_scan(foreign):
    reader = TlogReader(foreign.path)
    return reader, scan_log(reader)


# --- reading ------------------------------------------------------------------------------------


def test_reader_reads_every_record_with_its_offset(foreign):
    records = list(TlogReader(foreign.path))
    assert [r.offset for r in records] == foreign.offsets
    assert records[0].time_s == pytest.approx(EPOCH_US / 1e6)


def cut(path: Path, data: bytes, name: str) -> Path:
    out = path.parent / name
    out.write_bytes(data)
    return out


@pytest.mark.parametrize("shortfall", [1, 5, 12])
def test_truncated_log_is_read_up_to_its_last_whole_record(foreign, shortfall):
    data = foreign.path.read_bytes()
    path = cut(foreign.path, data[: len(data) - shortfall], f"truncated-{shortfall}.tlog")
    reader = TlogReader(path)
    records = list(reader)
    assert len(records) == len(foreign.offsets) - 1
    assert len(reader.damages) == 1
    damage = reader.damages[0]
    assert damage.offset == foreign.offsets[-1] and damage.resumed_at is None
    line = reader.describe_damage()
    assert f"byte {foreign.offsets[-1]}" in line and "\n" not in line and "mid-packet" in line


@pytest.mark.parametrize("where", ["checksum", "header", "timestamp"])
def test_corrupted_record_is_skipped_and_reading_resumes(foreign, where):
    data = bytearray(foreign.path.read_bytes())
    k = len(foreign.offsets) // 2
    start = foreign.offsets[k]
    # byte 8 is the packet's start marker, 9 its length, the last byte its checksum, byte 0
    # the high byte of the timestamp (a jump of years)
    position = {"checksum": foreign.offsets[k + 1] - 1, "header": start + 8, "timestamp": start}[where]
    data[position] ^= 0x5A
    path = cut(foreign.path, bytes(data), f"corrupt-{where}.tlog")
    reader = TlogReader(path)
    records = list(reader)
    assert [r.offset for r in records] == foreign.offsets[:k] + foreign.offsets[k + 1 :]
    assert [(d.offset, d.resumed_at) for d in reader.damages] == [(start, foreign.offsets[k + 1])]
    assert f"byte {start}" in reader.describe_damage()


def test_garbage_in_the_middle_is_skipped(foreign):
    data = foreign.path.read_bytes()
    k = len(foreign.offsets) // 3
    start = foreign.offsets[k]
    junk = bytes(range(256)) * 3  # holds 0xFD and 0xFE markers that are no packets
    path = cut(foreign.path, data[:start] + junk + data[start:], "garbage.tlog")
    reader = TlogReader(path)
    records = list(reader)
    assert len(records) == len(foreign.offsets)
    assert reader.damages[0].offset == start and reader.damages[0].resumed_at == start + len(junk)


@pytest.mark.parametrize(
    "content, expected",
    [
        (b"", "empty file"),
        (b"this is a text file, not a log\n" * 40, "not a MAVLink telemetry log"),
        (b"ULog\x01\x12\x35\x01" + bytes(200), "ULog"),
        (b"\xa3\x95\x80\x80" + bytes(200), "DataFlash"),
    ],
)
def test_a_file_that_is_not_a_tlog_is_a_log_format_error(tmp_path, content, expected):
    path = tmp_path / "not.tlog"
    path.write_bytes(content)
    with pytest.raises(LogFormatError, match=expected):
        list(TlogReader(path))


# --- what the scan finds --------------------------------------------------------------------------


def test_packet_loss_from_sequence_numbers(foreign_scan):
    _, scan = foreign_scan
    vehicle = scan.seq[(VEHICLE, 1)]
    assert vehicle.lost == DROPPED
    assert vehicle.duplicates == 0 and vehicle.streams == 1
    assert scan.seq[(255, 190)].lost == 0


@pytest.mark.parametrize(
    "sequence, lost, duplicates, counters",
    [
        ([0, 1, 2, 3], 0, 0, 1),
        ([0, 1, 4, 5], 2, 0, 1),
        ([254, 255, 0, 1], 0, 0, 1),  # wrap-around
        ([0, 1, 1, 2], 0, 1, 1),  # a repeat
        ([10, 11, 0, 12, 1, 13, 2], 0, 0, 2),  # two interleaved counters (a plant logging two links)
        ([10, 11, 0, 12, 1, 15, 2], 2, 0, 2),
    ],
)
def test_seq_counter(sequence, lost, duplicates, counters):
    counter = SeqCounter()
    for seq in sequence:
        counter.add(seq)
    assert (counter.received, counter.lost, counter.duplicates, counter.streams) == (len(sequence), lost, duplicates, counters)


def test_rates_and_gaps(foreign, foreign_scan):
    reader, scan = foreign_scan
    record = build_record(scan)
    report = log_report(reader, scan, float(record.meta["start_log_time_s"]))
    rates = {(r.system, r.message): r for r in report.rates}
    att = rates[(VEHICLE, "ATTITUDE")]
    assert att.count == len(foreign.attitude)
    span_s = (foreign.attitude[-1][0] - foreign.attitude[0][0]) / 1000.0
    assert att.rate_hz == pytest.approx((att.count - 1) / span_s)  # 50 Hz less the 1 s gap
    assert att.max_gap_s == pytest.approx(1.02, abs=1e-6)  # 2.98 -> 4.00
    assert att.max_gap_at_s == pytest.approx(2.98 - 0.01, abs=1e-6)  # t = 0 is the first position sample (10 ms)
    assert rates[(VEHICLE, "LOCAL_POSITION_NED")].rate_hz == pytest.approx(25.0, rel=0.05)
    sources = {(s.system, s.component): s for s in report.sources}
    assert sources[(VEHICLE, 1)].role == "vehicle" and sources[(255, 190)].role == "ground station"
    assert sources[(VEHICLE, 1)].received == len(foreign.vehicle_messages)
    assert sources[(VEHICLE, 1)].lost == DROPPED
    assert sources[(VEHICLE, 1)].loss_percent == pytest.approx(100.0 * DROPPED / (len(foreign.vehicle_messages) + DROPPED))


def test_mode_changes_and_failsafes_with_their_times(foreign_scan):
    _, scan = foreign_scan
    modes = [(round(e.time_s - EPOCH_US / 1e6, 2), e.text) for e in scan.events if e.kind == "mode"]
    assert modes == [(0.0, "Hold"), (1.0, "Offboard"), (5.0, "Land")]
    failsafes = [(round(e.time_s - EPOCH_US / 1e6, 2), e.text) for e in scan.events if e.kind == "failsafe"]
    assert failsafes == [(4.0, "system status CRITICAL"), (4.5, "[CRITICAL] Failsafe activated: no offboard signal")]
    assert any(e.kind == "armed" and round(e.time_s - EPOCH_US / 1e6, 2) == 1.0 for e in scan.events)
    texts = [e.text for e in scan.events if e.kind == "text"]
    assert texts == ["[INFO] Takeoff detected", "[CRITICAL] Disarming denied: not landed"]


@pytest.mark.parametrize(
    "custom_mode, name",
    [(MODE_HOLD, "Hold"), (MODE_OFFBOARD, "Offboard"), (MODE_LAND, "Land"), (3 << 16, "Position"), ((4 << 16) | (4 << 24), "Mission")],
)
def test_px4_mode_names(custom_mode, name):
    assert px4_mode_name(custom_mode) == name


# --- the record of a foreign log ------------------------------------------------------------------


def test_foreign_log_record_is_the_telemetry(foreign, foreign_scan):
    _, scan = foreign_scan
    record = build_record(scan)
    assert record.meta["vehicle_sysid"] == VEHICLE
    assert record.meta["commands"] == "none" and record.meta["references"] == "POSITION_TARGET_LOCAL_NED"
    pos = np.array(foreign.position)
    assert len(record) == len(pos)
    assert_allclose(record["t_s"], (pos[:, 0] - pos[0, 0]) / 1000.0)
    assert_allclose(record["pos_ned_m"], pos[:, 1:4])
    assert_allclose(record["vel_ned_m_s"], pos[:, 4:7])
    att = np.array(foreign.attitude)
    latest = np.searchsorted(att[:, 0], pos[:, 0], side="right") - 1  # the ATTITUDE at or before each position
    assert_allclose(record["euler_rad"], att[latest, 1:4])
    assert_allclose(record["ref_pos_ned_m"][:, 0], pos[:, 1] + np.float32(0.1), atol=1e-6)
    assert_allclose(record["ref_yaw_rad"], np.float32(0.25))
    assert np.all(np.isnan(record["thrust_n"])) and np.all(np.isnan(record["torques_nm"]))
    assert [p.name for p in record.phases] == ["Hold", "Offboard", "Land"]


def test_foreign_log_with_a_mission_takes_its_references(foreign_scan):
    from offboard.trajectory import Hold

    _, scan = foreign_scan
    record = build_record(scan, trajectory=Hold((1.0, 2.0, -3.0), 0.5, 2.0, name="point"))
    assert record["t_s"][-1] <= 2.0
    assert_allclose(record["ref_pos_ned_m"], np.tile([1.0, 2.0, -3.0], (len(record), 1)))
    assert [p.name for p in record.phases] == ["point"]


def test_no_attitude_and_position_is_a_log_format_error(tmp_path):
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(tmp_path / "hb.tlog", "wb") as fh:
        for k in range(3):
            fh.write(struct.pack(">Q", EPOCH_US + k * 1_000_000))
            fh.write(mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3).pack(mav))
            mav.seq += 1
    scan = scan_log(TlogReader(tmp_path / "hb.tlog"))
    with pytest.raises(LogFormatError, match="no ATTITUDE and LOCAL_POSITION_NED"):
        build_record(scan)


# --- the command line on a foreign log ------------------------------------------------------------


def test_cli_report_of_a_foreign_log(foreign, tmp_path, capsys):
    run_dir = tmp_path / "report"
    code = main(["replay", str(foreign.path), "--run-dir", str(run_dir), "--json"])
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["vehicle_sysid"] == VEHICLE and payload["samples"] == len(foreign.position)
    assert {p.name for p in run_dir.iterdir()} >= {"path3d.png", "position.png", "attitude.png", "errors.png",
                                                    "actions.png", "series.csv", "summary.txt", "summary.json"}
    sources = {(s["system"], s["component"]): s for s in payload["log_report"]["sources"]}
    assert sources[(VEHICLE, 1)]["lost"] == DROPPED
    assert [e["text"] for e in payload["log_report"]["events"] if e["kind"] == "mode"] == ["Hold", "Offboard", "Land"]
    header = (run_dir / "series.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["t_s", "pos_ned_m_0", "pos_ned_m_1", "pos_ned_m_2"]
    assert len((run_dir / "series.csv").read_text().splitlines()) == len(foreign.position) + 1


def test_cli_damaged_log_warns_once_and_reports(foreign, tmp_path, capsys):
    data = foreign.path.read_bytes()
    path = cut(foreign.path, data[:-9], "cut.tlog")
    code = main(["replay", str(path), "--run-dir", str(tmp_path / "r"), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"byte {foreign.offsets[-1]}" in lines[0] and "warning" in lines[0]
    assert (tmp_path / "r" / "summary.json").exists()


@pytest.mark.parametrize("content", [b"", b"definitely not a tlog\n" * 30])
def test_cli_not_a_tlog_is_one_line_and_exit_2(tmp_path, capsys, content):
    path = tmp_path / "bad.tlog"
    path.write_bytes(content)
    code = main(["replay", str(path), "--run-dir", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "bad.tlog" in err and "Traceback" not in err


def test_cli_missing_file_is_one_line(tmp_path, capsys):
    code = main(["replay", str(tmp_path / "nope.tlog")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "nope.tlog" in err


def test_cli_rerun_without_mission_or_controller_misuse(foreign, tmp_path, capsys):
    assert main(["replay", str(foreign.path), "--controller", "x.toml"]) == 2
    assert "--controller: only with --rerun" in capsys.readouterr().err
    assert main(["replay", str(foreign.path), "--rerun", "--run-dir", str(tmp_path / "r")]) == 2
    assert "--mission" in capsys.readouterr().err
    assert main(["replay", str(foreign.path), "--to", "/dev/null"]) == 2
    assert "--to" in capsys.readouterr().err


# --- streaming --------------------------------------------------------------------------------------


def test_stream_keeps_the_original_timing_scaled_by_speed(foreign):
    sent: list[bytes] = []
    now = [0.0]
    sleeps: list[float] = []

    def sleep(dt: float) -> None:
        sleeps.append(dt)
        now[0] += dt

    count = stream_log(iter(TlogReader(foreign.path)), sent.append, speed=4.0, systems={VEHICLE}, clock=lambda: now[0], sleep=sleep)
    assert count == len(sent) == len(foreign.vehicle_messages)
    first, last = foreign.vehicle_messages[0][0], foreign.vehicle_messages[-1][0]
    assert now[0] == pytest.approx((last - first) / 4.0, abs=1e-9)
    assert all(dt > 0 for dt in sleeps)


def test_stream_skips_copies_of_a_message_logged_once_per_link():
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = []
    for k, tb in enumerate((0, 0, 50, 50)):  # the same ATTITUDE logged from two links
        m = mavlink.MAVLink_attitude_message(tb, 0.1, 0.2, 0.3, 0, 0, 0)
        packet = m.pack(mav)
        mav.seq += 1
        parsed = mavlink.MAVLink(None).parse_buffer(packet)[0]
        msgs.append(LoggedMessage(tb / 1000.0, k, parsed))
    out: list[bytes] = []
    assert stream_log(iter(msgs), out.append, speed=1e6) == 2
    parser = mavlink.MAVLink(None)
    decoded = [parser.parse_buffer(p)[0] for p in out]
    assert [d.time_boot_ms for d in decoded] == [0, 50]
    assert [d.get_seq() for d in decoded] == [0, 1]  # one counter, as one live link


def test_cli_streams_the_vehicle_messages_over_udp(foreign, capsys):
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(1.0)
    port = listener.getsockname()[1]
    received: list = []

    def listen() -> None:  # a pymavlink parser on the port, reading while the replay sends
        parser = mavlink.MAVLink(None)
        while True:
            try:
                data, _ = listener.recvfrom(65535)
            except (socket.timeout, OSError):
                return
            received.extend(m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")

    thread = threading.Thread(target=listen)
    thread.start()
    try:
        code = main(["replay", str(foreign.path), "--to", f"udpout:127.0.0.1:{port}", "--speed", "20", "--quiet"])
    finally:
        thread.join()
        listener.close()
    assert code == 0
    assert [m.get_type() for m in received] == [kind for _, kind in foreign.vehicle_messages]
    assert all(m.get_srcSystem() == VEHICLE for m in received)
    positions = [(m.time_boot_ms, m.x, m.y, m.z) for m in received if m.get_type() == "LOCAL_POSITION_NED"]
    assert positions == [p[:4] for p in foreign.position]
    seqs = [m.get_seq() for m in received]
    assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:]))


def test_sample_numbers_undo_a_late_command_and_keep_a_real_gap():
    from offboard.replay import sample_numbers

    to = 0.05
    exact = np.arange(10) * to
    assert sample_numbers(exact, to).tolist() == list(range(10))
    late = exact.copy()
    late[4] += 0.03  # sent 0.6 To late: rounds onto sample 5, which then seems doubled
    assert np.rint(late / to).astype(int).tolist().count(5) == 2
    assert sample_numbers(late, to).tolist() == list(range(10))
    early = exact.copy()
    early[6] -= 0.03  # 0.6 To early: onto sample 5
    assert sample_numbers(early, to).tolist() == list(range(10))
    gap = np.concatenate([exact[:4], exact[7:]])  # no command for samples 4-6 (an outage)
    assert sample_numbers(gap, to).tolist() == [0, 1, 2, 3, 7, 8, 9]


def test_the_rerun_takes_the_attitude_the_command_answered_not_a_newer_one():
    """offboard fly pairs the position with the ATTITUDE of its own instant: a newer ATTITUDE may
    be logged before the command that answered the older one (real time)."""
    from types import SimpleNamespace

    from offboard.replay import _telemetry_rows

    def att(ms, roll, msgno):
        return (ms, roll, 0.0, 0.0, 0.0, 0.0, 0.0, ms / 1000.0, msgno)

    def pos(ms, msgno):
        return (ms, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, ms / 1000.0, msgno)

    # samples at 100, 150, ..., each command logged right after its pair; at 300 the ATTITUDE of
    # 308 arrives (and is logged) before the command that answered 300
    attitudes, positions, commands, stamps = [], [], [], []
    msgno = 0
    for ms in range(100, 10100, 50):  # 200 samples: one odd one in 200 is the flight's own log (>= 99 % echoed)
        attitudes.append(att(ms, ms / 1e4, msgno)); positions.append(pos(ms, msgno + 1)); msgno += 2
        if ms == 300:
            attitudes.append(att(308, 9.0, msgno)); msgno += 1
        commands.append(msgno); stamps.append(ms); msgno += 1
    scan = SimpleNamespace(attitude={1: attitudes}, local_position={1: positions})
    i_att, i_pos, att_table, _ = _telemetry_rows(scan, 1, np.array(stamps), np.array(commands))
    assert att_table[i_att, 0].tolist() == stamps  # every sample's own ATTITUDE, 300 included
    assert 9.0 not in att_table[i_att, 1]


def test_a_burst_of_one_message_has_no_rate_and_says_so_with_a_dash():
    """Messages all sent at one instant (the offboard's parameter requests go out at once) have no
    span: the table prints "-" for their rate and gap, never nan, and the JSON has null."""
    import math

    from offboard.jsonout import dumps
    from offboard.replay.report import LogReport, MessageRate, format_log_report

    burst = MessageRate(245, 191, "PARAM_REQUEST_READ", 24, math.nan, 0.0, math.nan)
    steady = MessageRate(1, 1, "ATTITUDE", 100, 50.0, 0.04, 1.5)
    report = LogReport("x.tlog", 1, 124, 0, 0.0, 2.0, [], [], [burst, steady], [], 1)
    text = format_log_report(report)
    row = next(line for line in text.splitlines() if "PARAM_REQUEST_READ" in line)
    assert row.split()[2:] == ["24", "-", "0.000", "-"] and "nan" not in text.lower()
    assert "50.00" in next(line for line in text.splitlines() if "ATTITUDE" in line)
    assert "NaN" not in dumps(report.to_dict())


def test_a_heading_reset_is_an_event_and_a_turn_is_not():
    """PX4's EKF2 resets its heading in flight (-32.8 deg on a paper helix at 1.30 s, its ulog's
    delta_heading): ATTITUDE's yaw jumps while its body rates do not turn it. A fast turn, through
    +-pi, at a pitch and roll where the Euler yaw rate is not the body z rate, is no event; nor is a
    gap too long to judge, nor a pitch near 90 deg."""
    packer, parser = mavlink.MAVLink(None, srcSystem=1, srcComponent=1), mavlink.MAVLink(None)
    scan = LogScan()
    roll, pitch, r = 0.3, -0.2, 2.0  # body z rate 2 rad/s: the Euler yaw rate is r cos(roll) / cos(pitch)
    yaw_rate = r * math.cos(roll) / math.cos(pitch)
    yaw, t_ms = 3.0, 1000
    rows = []
    for k in range(60):  # 100 Hz, turning through +pi at ~0.08 s
        if k == 30:
            yaw += math.radians(-32.8)  # the reset
        rows.append((t_ms, yaw))
        t_ms += 10
        yaw += yaw_rate * 0.01
    rows.append((t_ms + 500, yaw + 1.0))  # a 0.5 s gap: not judged
    for t, y in rows:
        wrapped = (y + math.pi) % (2 * math.pi) - math.pi
        msg = mavlink.MAVLink_attitude_message(t, roll, pitch, wrapped, 0.0, 0.0, r)
        scan.add(t / 1000.0, parser.parse_buffer(msg.pack(packer))[0])
    events = [(e.time_s, e.kind, e.text) for e in scan.events]
    assert len(events) == 1 and events[0][:2] == (1.3, "estimator"), events
    assert events[0][2].startswith("heading reset by -32.8 deg")
    # the rule alone: near pitch 90 deg the Euler yaw is not defined
    assert heading_reset_deg((0, 0.0, 1.45, 0.0, 0, 0, 0), (10, 0.0, 1.45, 1.0, 0, 0, 0)) is None
    assert heading_reset_deg((0, 0.0, 0.0, 0.0, 0, 0, 0), (10, 0.0, 0.0, math.radians(4.0), 0, 0, 0)) is None  # under 5 deg
    assert heading_reset_deg((0, 0.0, 0.0, 0.0, 0, 0, 0), (10, 0.0, 0.0, math.radians(6.0), 0, 0, 0)) == pytest.approx(6.0)


def test_the_estimators_state_and_sensor_health_are_events():
    """What offboard fly ends ESTIMATE_LOST on, and the SYS_STATUS health it reports, told from the log
    alone: an event when the set of estimates the estimator no longer vouches for changes (not when
    only the flags do), and one per sensor whose health changes (a GPS dropped from present, as PX4)."""
    gps = mavlink.MAV_SYS_STATUS_SENSOR_GPS
    packer, parser = mavlink.MAVLink(None, srcSystem=1, srcComponent=1), mavlink.MAVLink(None)
    scan = LogScan()
    messages = [(t, mavlink.MAVLink_estimator_status_message(int(t * 1e6), flags, 0, 0, 0, 0, 0, 0, 0.3, 0.3))
                for t, flags in ((1.0, 0x37F), (2.0, 0x37F), (3.0, 0x365), (4.0, 0x025), (5.0, 0x37F))]
    messages += [(t, mavlink.MAVLink_sys_status_message(present, present, gps | 1, 0, 16200, -1, 100, 0, 0, 0, 0, 0, 0))
                 for t, present in ((1.5, gps | 1), (3.5, 1))]  # fmt: skip
    for t, msg in sorted(messages, key=lambda m: m[0]):
        scan.add(t, parser.parse_buffer(msg.pack(packer))[0])
    events = [(e.time_s, e.kind, e.text) for e in scan.events]
    assert events == [
        (3.0, "estimator", "the vehicle's estimator no longer vouches for its horizontal velocity, horizontal position (ESTIMATOR_STATUS flags 0x365)"),
        (3.5, "health", "GPS no longer reported (SYS_STATUS)"),
        (5.0, "estimator", "the vehicle's estimator vouches again for every estimate the law reads (ESTIMATOR_STATUS flags 0x37f)"),
    ]  # fmt: skip


def test_commands_were_sampled_on_the_vehicles_clock_where_it_ran_at_another_rate_than_the_log():
    from offboard.replay.record import vehicle_clock_rate

    log = 100.0 + np.arange(200) * 0.0125  # 2.5 s of the log's clock, a command every 12.5 ms
    assert vehicle_clock_rate(log, 4000 + np.arange(200) * 50) == pytest.approx(4.0)  # the vehicle's 50 ms each (PX4 at --speed 4)
    assert vehicle_clock_rate(log, 4000 + np.rint(np.arange(200) * 12.5)) is None  # real time
    assert vehicle_clock_rate(log, np.full(200, 4000)) is None  # a vehicle that waits (lockstep, stalled)
    assert vehicle_clock_rate(log[:40], 4000 + np.arange(40) * 50) is None  # under a second of the log: not measured


# --- commands that answer one telemetry stamp -----------------------------------------------------


def test_two_samples_that_read_one_telemetry_stamp_are_two_commands_and_a_resend_is_one(tmp_path):
    """A real-time sample that found no newer telemetry answers the stamp the sample before it
    answered, with a command of its own: both are the controller's samples (the log kept only the
    first, and a real-time flight with its telemetry at 15 Hz and its samples at 20 Hz re-ran 91
    of its 121 samples, 88 of them differently). The same command sent again is one."""
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    sent = [(100, 0.50), (150, 0.51), (150, 0.52), (200, 0.53), (200, 0.53), (250, 0.54)]  # (stamp, thrust)
    with open(tmp_path / "commands.tlog", "wb") as fh:
        for k, (stamp, thrust) in enumerate(sent):
            fh.write(struct.pack(">Q", EPOCH_US + k * 50_000))
            fh.write(mavlink.MAVLink_set_attitude_target_message(stamp, VEHICLE, 1, 0b111, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, thrust).pack(mav))
            mav.seq = (mav.seq + 1) % 256
    from offboard.replay.record import setpoints_for

    series = setpoints_for(scan_log(TlogReader(tmp_path / "commands.tlog")), VEHICLE)
    assert series.kind == "attitude"
    assert series.time_boot_ms.tolist() == [100, 150, 150, 200, 250]
    assert_allclose(series.values[:, -1], [0.50, 0.51, 0.52, 0.53, 0.54], rtol=1e-6)


# --- the setpoints' echo ----------------------------------------------------------------------------


def test_the_log_report_pairs_the_setpoints_with_the_vehicles_attitude_target_echo(tmp_path):
    """A flight's tlog holds its SET_ATTITUDE_TARGETs and, in real time, the vehicle's
    ATTITUDE_TARGET stamped when it took each (offboard.echo): the report gives the latency in the
    vehicle's clock as ``offboard fly`` did in flight, in the order logged (the order the flight
    handled them), not by the log's times. A body-rate setpoint (attitude ignored) and an echo of
    another module's attitude pair nothing; a log without echoes has no figure."""
    ours = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
    vehicle = mavlink.MAVLink(None, srcSystem=VEHICLE, srcComponent=1)

    def q(roll: float) -> list[float]:
        return [math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0]

    frames = [(0, mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 129, MODE_OFFBOARD, 4, 3).pack(vehicle)),
              (1, mavlink.MAVLink_attitude_message(1000, 0, 0, 0, 0, 0, 0).pack(vehicle)),
              (2, mavlink.MAVLink_local_position_ned_message(1000, 0, 0, -2, 0, 0, 0).pack(vehicle))]  # the vehicle's
    keep = (0, 30, 32, 82)  # with the setpoints alone: the heartbeat, ATTITUDE, LOCAL_POSITION_NED, SET_ATTITUDE_TARGET
    for k in range(6):  # a setpoint every 50 ms answering telemetry of 1000 + 50 k; echoed every other one
        stamp = 1000 + 50 * k
        frames.append((k * 50_000, mavlink.MAVLink_set_attitude_target_message(stamp, VEHICLE, 1, 0b111, q(0.01 * k), 0, 0, 0, 0.5).pack(ours)))
        if k % 2 == 0:  # the second echo logged after its setpoint with an earlier time (a wall clock stepped back)
            frames.append((k * 50_000 + (-1_000 if k == 2 else 8_000),
                           mavlink.MAVLink_attitude_target_message(stamp + 4 * (k + 1), 0, q(0.01 * k), 0, 0, 0, 0.5).pack(vehicle)))
    frames.append((301_000, mavlink.MAVLink_set_attitude_target_message(1300, VEHICLE, 1, 0b10000111, q(0.5), 0, 0, 0, 0.5).pack(ours)))
    frames.append((305_000, mavlink.MAVLink_attitude_target_message(1304, 0, q(0.5), 0, 0, 0, 0.5).pack(vehicle)))
    frames.append((306_000, mavlink.MAVLink_attitude_target_message(1306, 0, q(0.9), 0, 0, 0, 0.5).pack(vehicle)))
    with open(tmp_path / "echo.tlog", "wb") as fh:
        for t_us, frame in frames:
            fh.write(struct.pack(">Q", EPOCH_US + t_us) + frame)
    reader = TlogReader(tmp_path / "echo.tlog")
    scan = scan_log(reader)
    report = log_report(reader, scan, scan.first_time_s)
    assert report.setpoint_echo == {"paired": 3, "p50_ms": 12.0, "p90_ms": 18.4, "max_ms": 20.0}  # 4, 12, 20 ms
    assert report.to_dict()["setpoint_echo"] == report.setpoint_echo
    assert "setpoint echo: the vehicle took the setpoints 12 ms (median)" in format_log_report(report)
    # the setpoints alone (an echo switched off): no figure, no line
    with open(tmp_path / "alone.tlog", "wb") as fh:
        for t_us, frame in frames:
            if frame[7] in keep:
                fh.write(struct.pack(">Q", EPOCH_US + t_us) + frame)
    reader = TlogReader(tmp_path / "alone.tlog")
    alone = log_report(reader, scan_log(reader), 0.0)
    assert alone.setpoint_echo is None and "setpoint echo" not in format_log_report(alone)
