"""PX4's services in the plant, without sockets: MAVLink FTP, log download, the shell,
PREFLIGHT_CALIBRATION, STATUSTEXT in and body-frame velocity setpoints (the answers PX4 v1.16
gives, measured: docs/parity/services.md)."""

from __future__ import annotations

import math
import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant import codec
from sitl_plant.autopilot import Autopilot
from sitl_plant.calibration import calibration_result
from sitl_plant.codec import Refused
from sitl_plant.ftp import MAX_DATA, Err, FtpFormatError, FtpPayload, FtpServer, Op, crc32
from sitl_plant.logserve import DATA_LEN, LogServer
from sitl_plant.params import plant_params
from sitl_plant.server import API, Plant, PlantConfig
from sitl_plant.shell import PROMPT, Shell, replies, version_lines
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

_SENDER = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
_PARSER = mavlink.MAVLink(None)


def wire(msg):
    return _PARSER.parse_buffer(msg.pack(_SENDER))[0]


def request(op, data=b"", *, seq=1, session=0, offset=0, size=None):
    return FtpPayload(seq, session, op, len(data) if size is None else size, 0, 0, offset, data).pack()


def answer(server, *args, **kw):
    return [FtpPayload.unpack(r) for r in server.handle(request(*args, **kw))]


@pytest.fixture
def root(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "flight.tlog").write_bytes(bytes(range(256)) * 4)  # 1024 bytes
    (tmp_path / "run" / "logs").mkdir()
    (tmp_path / "secret.txt").write_text("outside")
    (tmp_path / "run" / "link").symlink_to(tmp_path / "secret.txt")
    return tmp_path / "run"


# --- FTP ------------------------------------------------------------------------------------------


def test_ftp_lists_a_folder_as_px4_with_skip_entries_and_eof(root):
    server = FtpServer(root)
    [r] = answer(server, Op.LIST_DIRECTORY, b"/", seq=7)
    assert (r.opcode, r.req_opcode, r.seq) == (Op.ACK, Op.LIST_DIRECTORY, 8)  # seq + 1, as PX4
    entries = r.data.rstrip(b"\0").split(b"\0")
    assert entries == [b"S", b"S", b"Fflight.tlog\t1024", b"S", b"Dlogs"]  # ".", "..", the link skipped
    [r] = answer(server, Op.LIST_DIRECTORY, b"/", seq=9, offset=4)
    assert r.data.rstrip(b"\0") == b"Dlogs"
    [r] = answer(server, Op.LIST_DIRECTORY, b"/", seq=10, offset=5)
    assert (r.opcode, r.data) == (Op.NAK, bytes([Err.EOF]))


@pytest.mark.parametrize("path", ["/nope", "/../", "/logs/../../secret.txt", "/link"])
def test_ftp_never_reaches_outside_its_folder(root, path):
    server = FtpServer(root)
    for op in (Op.LIST_DIRECTORY, Op.OPEN_FILE_RO):
        [r] = answer(server, op, path.encode())
        assert (r.opcode, r.data) == (Op.NAK, bytes([Err.FILE_NOT_FOUND]))


def test_ftp_open_read_burst_terminate_as_px4(root):
    server = FtpServer(root, burst_chunks=3)
    content = (root / "flight.tlog").read_bytes()
    [r] = answer(server, Op.OPEN_FILE_RO, b"/flight.tlog", seq=1)
    assert r.opcode == Op.ACK and struct.unpack("<I", r.data)[0] == 1024
    [r] = answer(server, Op.OPEN_FILE_RO, b"/flight.tlog", seq=2)
    assert r.data == bytes([Err.NO_SESSIONS_AVAILABLE])  # one session, as PX4
    [r] = answer(server, Op.READ_FILE, seq=3, offset=10, size=100)
    assert (r.opcode, r.offset, r.data) == (Op.ACK, 10, content[10:110])
    [r] = answer(server, Op.READ_FILE, seq=4, offset=5000, size=100)
    assert r.data == bytes([Err.EOF])
    [r] = answer(server, Op.READ_FILE, seq=5, session=3, size=100)
    assert r.data == bytes([Err.INVALID_SESSION])
    burst = answer(server, Op.BURST_READ_FILE, seq=6, offset=0, size=MAX_DATA)
    assert [b.seq for b in burst] == [7, 8, 9] and burst[-1].burst_complete == 1  # bounded: the client continues
    burst = answer(server, Op.BURST_READ_FILE, seq=10, offset=3 * MAX_DATA)
    assert burst[-1].opcode == Op.NAK and burst[-1].data == bytes([Err.EOF]) and burst[-1].offset == 1024
    got = b"".join(b.data for b in burst[:-1])
    assert got == content[3 * MAX_DATA :]
    assert answer(server, Op.TERMINATE_SESSION, seq=20)[0].opcode == Op.ACK
    assert answer(server, Op.TERMINATE_SESSION, seq=21)[0].data == bytes([Err.INVALID_SESSION])


def test_ftp_crc_write_refusal_unknown_and_a_repeated_request(root):
    server = FtpServer(root)
    [r] = answer(server, Op.CALC_FILE_CRC32, b"/flight.tlog")
    assert struct.unpack("<I", r.data)[0] == crc32((root / "flight.tlog").read_bytes())
    assert crc32(b"123456789") == 0x2DFD2D88  # not zlib's 0xCBF43926: no inversions (PX4's crc32part; the PX4 parity test checks a file)
    assert answer(server, Op.CALC_FILE_CRC32, b"/nope", seq=2)[0].data == bytes([Err.FILE_NOT_FOUND])
    for op in (Op.CREATE_FILE, Op.REMOVE_FILE, Op.WRITE_FILE, Op.RENAME):
        assert answer(server, op, b"/x", seq=op)[0].data == bytes([Err.FILE_PROTECTED])
    assert answer(server, 77, seq=30)[0].data == bytes([Err.UNKNOWN_COMMAND])
    first = server.handle(request(Op.OPEN_FILE_RO, b"/flight.tlog", seq=40))
    assert server.handle(request(Op.OPEN_FILE_RO, b"/flight.tlog", seq=40)) == first  # a lost reply, resent
    with pytest.raises(FtpFormatError, match="shorter than"):
        server.handle(b"\1\2")
    assert answer(FtpServer(None), Op.LIST_DIRECTORY, b"/")[0].data == bytes([Err.FILE_NOT_FOUND])


# --- log download ---------------------------------------------------------------------------------


def test_log_download_lists_and_serves_the_tlog(tmp_path):
    tlog = tmp_path / "f.tlog"
    tlog.write_bytes(struct.pack(">Q", 1_700_000_000_123_456) + bytes(300))
    logs = LogServer(tlog)
    [entry] = logs.request_list(0, 0xFFFF)
    assert (entry.id, entry.num_logs, entry.last_log_num, entry.time_utc, entry.size) == (0, 1, 1, 1_700_000_000, 308)
    tlog.write_bytes(tlog.read_bytes() + bytes(500))  # the log grows; the listed size is served
    first = logs.request_data(0, 0, 0xFFFFFFFF)
    rest = []
    while logs.downloading:
        rest += logs.pump()
    data = first + rest
    assert [d.ofs for d in data] == list(range(0, 308, DATA_LEN)) and sum(d.count for d in data) == 308
    assert logs.request_data(0, 400, 90) == [] and logs.request_data(5, 0, 90) == []  # beyond the end, no such log: silence
    assert [d.count for d in logs.request_data(0, 100, 50)] == [90] and [d.count for d in logs.request_data(0, 0, 0)] == [90]
    assert [(d.ofs, d.count) for d in logs.request_data(0, 298, 90)] == [(298, 10)]  # the end of the listed size
    logs.request_data(0, 0, 1000)
    logs.request_end()
    assert not logs.downloading and logs.pump() == []
    logs.erase()
    assert tlog.exists()  # the user's run record is kept
    assert [(e.num_logs, e.size) for e in LogServer(None).request_list(0, 0xFFFF)] == [(0, 0)]


# --- shell ----------------------------------------------------------------------------------------


@pytest.fixture
def params():
    return plant_params(load_vehicle(PAPER_VEHICLE_FILE))


def test_shell_answers_as_pxh(params):
    sh = Shell(params, lambda: codec.PX4_FLIGHT_SW_VERSION)
    assert sh.feed(b"\n") == b"\n" + PROMPT.encode()
    out = sh.feed(b"ver all\n").decode()
    assert out.startswith("ver all\nHW arch: ") and version_lines(codec.PX4_FLIGHT_SW_VERSION)["fw"] + "\n" in out and out.endswith(PROMPT)
    out = sh.feed(b"param show MPC_XY_VEL_MAX\n").decode()
    i = params.index("MPC_XY_VEL_MAX")
    n = len(params)
    assert out == (f"param show MPC_XY_VEL_MAX\nSymbols: x = used, + = saved, * = unsaved\n"
                   f"x   MPC_XY_VEL_MAX [{i},{i}] : {params['MPC_XY_VEL_MAX']:.4f}\n\n {n}/{n} parameters used.\n{PROMPT}")  # fmt: skip
    assert sh.feed(b"param show NOPE_X\n").decode().count("x   ") == 0
    assert sh.feed(b"foo\n").decode() == f"foo\nInvalid command: foo\ntype 'help' for a list of commands\n{PROMPT}"
    assert sh.feed(b"ver") == b"" and "Error, not enough parameters." in sh.feed(b"\n").decode()  # a line in two messages
    lines = version_lines(0x011000FF, "6.18.44-generic")  # PX4 v1.16.0 SITL on that kernel printed these two
    assert lines["fw"] == "PX4 version: Release 1.16.0 (17826047)" and lines["osver"] == "OS version: Release 6.18.44 (101854463)"
    msgs = list(replies(b"x" * 150))
    assert [m.count for m in msgs] == [70, 70, 10] and all(m.flags == mavlink.SERIAL_CONTROL_FLAG_REPLY for m in msgs)


# --- calibration, body frame ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("params7", "armed", "result"),
    [((1, 0, 0, 0, 0, 0, 0), False, mavlink.MAV_RESULT_ACCEPTED),  # gyro
     ((0, 0, 1, 0, 0, 0, 0), False, mavlink.MAV_RESULT_ACCEPTED),  # baro
     ((0, 0, 0, 0, 1, 0, 0), False, mavlink.MAV_RESULT_ACCEPTED),  # accel
     ((0, 0, 0, 0, 2, 0, 0), False, mavlink.MAV_RESULT_ACCEPTED),  # level
     ((1, 0, 0, 0, 0, 0, 0), True, mavlink.MAV_RESULT_TEMPORARILY_REJECTED),
     ((0, 0, 0, 0, 0, 0, 9), False, mavlink.MAV_RESULT_UNSUPPORTED)],
)  # fmt: skip
def test_preflight_calibration_answers(params7, armed, result):
    assert calibration_result(tuple(float(p) for p in params7), armed) == result


def _target(frame, vx=0.0, vy=0.0, vz=0.0, mask=0b0000_1001_1100_0111):
    return wire(mavlink.MAVLink_set_position_target_local_ned_message(0, 1, 1, frame, mask, 1, 2, 3, vx, vy, vz, 0, 0, 0, 0.5, 0))


def test_body_frame_velocity_is_turned_by_the_heading():
    sp = codec.decode_position_target(_target(mavlink.MAV_FRAME_BODY_NED, vx=2.0, vz=-0.5), yaw_rad=math.pi / 2)
    assert sp.pos_ned_m == (None, None, None)
    assert sp.vel_ned_m_s == pytest.approx((0.0, 2.0, -0.5), abs=1e-9)  # forward at yaw 90 deg is east
    assert sp.yaw_rad == pytest.approx(0.5)
    for frame in (mavlink.MAV_FRAME_LOCAL_OFFSET_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
        with pytest.raises(Refused, match=f"frame {frame} not supported"):
            codec.decode_position_target(_target(frame, vx=1.0), yaw_rad=0.0)
    with pytest.raises(Refused, match="neither"):  # BODY_NED does not use positions
        codec.decode_position_target(_target(mavlink.MAV_FRAME_BODY_NED, mask=0b0000_1001_1111_1000))


# --- the plant's hooks ----------------------------------------------------------------------------


def test_the_plant_answers_its_services_on_the_asking_link(tmp_path, params):
    (tmp_path / "a.tlog").write_bytes(bytes(200))
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    config = PlantConfig(model="paper", log_path=tmp_path / "a.tlog", ftp_root=tmp_path)
    plant = Plant(config, vehicle, params, Autopilot(params))
    plant.handle(API, wire(mavlink.MAVLink_file_transfer_protocol_message(0, 1, 1, list(request(Op.LIST_DIRECTORY, b"/")))))
    plant.handle(API, wire(mavlink.MAVLink_serial_control_message(10, 6, 0, 0, 4, list(b"foo\n".ljust(70, b"\0")))))
    plant.handle(API, wire(mavlink.MAVLink_log_request_list_message(1, 1, 0, 0xFFFF)))
    plant.handle(API, wire(mavlink.MAVLink_statustext_message(6, b"hello")))
    plant.handle(API, wire(mavlink.MAVLink_command_long_message(1, 1, 241, 0, 1, 0, 0, 0, 0, 0, 0)))
    kinds = [m.get_type() for m in plant.outbox[API]]
    assert kinds[0] == "FILE_TRANSFER_PROTOCOL" and "SERIAL_CONTROL" in kinds and "LOG_ENTRY" in kinds
    assert FtpPayload.unpack(plant.outbox[API][0].payload).data.startswith(b"S\0S\0Fa.tlog\t200")
    assert plant.outbox[1] == []  # nothing on the other link
    ack = [m for m in plant.outbox[API] if m.get_type() == "COMMAND_ACK"][0]
    assert (ack.command, ack.result) == (241, mavlink.MAV_RESULT_ACCEPTED)
    assert plant.counters.statustexts_in == 1 and plant.counters.internal_errors == 0
    plant.handle(API, wire(mavlink.MAVLink_log_request_data_message(1, 1, 0, 0, 0xFFFFFFFF)))
    assert sum(m.count for m in plant.outbox[API] if m.get_type() == "LOG_DATA") + sum(m.count for m in plant.service_output(API)) == 200


def test_an_ftp_root_that_is_no_folder_is_one_line(tmp_path, capsys):
    from sitl_plant.cli import main

    args = ["--ftp-root", str(tmp_path / "nope"), "--quiet", "--gcs-bind", "none", "--api-bind", "127.0.0.1:0", "--duration", "0.1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sitl-plant: error: --ftp-root {tmp_path / 'nope'}: not a folder"]
