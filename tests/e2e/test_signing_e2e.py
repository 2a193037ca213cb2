"""A signed flight (issue 14): both processes with --signing-key, in lockstep, with an intruder
sending unsigned and forged commands at the plant during the flight. Measured before signing: a
second client's forced disarm at 6.5 m was accepted and the vehicle fell."""

from __future__ import annotations

import socket
import subprocess
import time
from functools import partial
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from helpers.flights import ENV, PY, arc_hold_mission, fly
from helpers.fuzz import AFTER_THE_FUZZ, FUZZ_FRAMES, fuzz_the_offboard
from offboard.replay import TlogReader
from offboard.signing import ACCEPTED_UNSIGNED

KEY = bytes(range(1, 33))
ARMED = "armed: flying the mission"
ROUNDS = 5  # of the intruder's attacks
REPLAYS = 4  # frames of each process recorded in an earlier flight and sent again in each round
HOLD = 4 << 16 | 3 << 24  # PX4's custom mode Auto/Hold


def records(path, without: frozenset[int] = frozenset()) -> list[tuple[float, bytes]]:
    reader = TlogReader(path)
    out = [(r.time_s, bytes(r.msg.get_msgbuf())) for r in reader if r.msg.get_msgId() not in without]
    assert not reader.damages
    return out


def first_sent(path: Path, sysid: int, count: int) -> list[bytes]:
    """The first ``count`` frames system ``sysid`` sent, from a tlog of an earlier flight."""
    return [frame for _, frame in records(path) if frame[5] == sysid][:count]


def intrude(ctx, offboard_frames: list[bytes] = (), vehicle_frames: list[bytes] = ()) -> None:
    """Once armed, at the plant: unsigned frames from another system, and frames forged with the
    offboard's ids and another key: a forced disarm, a mode change to Hold, a 30 deg roll
    setpoint; the offboard's own ``offboard_frames``, sent again. At the offboard: frames with the
    vehicle's ids (1/1), unsigned and forged, announcing Hold and acknowledging a command; the
    vehicle's ``vehicle_frames``, sent again."""
    ctx.wait_for(ARMED)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plain = mavlink.MAVLink(None, srcSystem=200, srcComponent=190)
    forged = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
    forged.signing.secret_key, forged.signing.sign_outgoing = bytes(32 * [9]), True
    forged.signing.timestamp = 10**14  # far ahead: pymavlink's check would lock the real stream out
    attacks = [
        mavlink.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0),
        mavlink.MAVLink_command_long_message(1, 1, 176, 0, 1, 4, 3, 0, 0, 0, 0),
        mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 0b00000111, [0.966, 0.259, 0, 0], 0, 0, 0, 0.5),
    ]
    vehicle_plain = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    vehicle_forged = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    vehicle_forged.signing.secret_key, vehicle_forged.signing.sign_outgoing = bytes(32 * [9]), True
    vehicle_forged.signing.timestamp = 10**14
    fakes = [
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x81, HOLD, 4, 3),
        mavlink.MAVLink_command_ack_message(176, 0, 0, 0, 245, 191),
    ]
    try:
        for _ in range(ROUNDS):
            for msg in attacks:
                for mav in (plain, forged):
                    sock.sendto(msg.pack(mav), ("127.0.0.1", ctx.plant_port))
            for frame in offboard_frames:
                sock.sendto(frame, ("127.0.0.1", ctx.plant_port))
            for msg in fakes:
                for mav in (vehicle_plain, vehicle_forged):
                    sock.sendto(msg.pack(mav), ("127.0.0.1", ctx.offboard_port))
                    mav.seq = (mav.seq + 1) & 0xFF
            for frame in vehicle_frames:
                sock.sendto(frame, ("127.0.0.1", ctx.offboard_port))
    finally:
        sock.close()


def test_a_signed_lockstep_flight_refuses_the_intruder_and_the_fuzz_and_is_bit_identical(tmp_path):
    key = tmp_path / "key.bin"
    key.write_bytes(KEY)
    mission = arc_hold_mission(tmp_path / "arc-hold.toml")  # the intruder's rounds reach a flying offboard
    signed = ("--signing-key", str(key))
    b = fly(tmp_path, mission, name="quiet", fly_args=signed, plant_args=signed)
    # what each process sent early in the quiet flight, the attacked one sends too (the same
    # bytes: that is what is asserted below), and has sent by the time it is armed: a replay
    replays = {"offboard_frames": first_sent(b.tlog, 245, REPLAYS), "vehicle_frames": first_sent(b.plant_tlog, 1, REPLAYS)}
    assert all(len(frames) == REPLAYS for frames in replays.values())
    a = fly(tmp_path, mission, name="attacked", fly_args=(*signed, *AFTER_THE_FUZZ), plant_args=signed, before_plant=fuzz_the_offboard,
            during=partial(intrude, **replays), quiet_plant=False)  # fmt: skip
    assert a.returncode == b.returncode == 0, a.stderr + b.stderr
    assert a.status == "complete" and a.summary["disarmed"]
    # what was refused left no trace: the attacked flight is the quiet one, byte for byte (but the
    # fuzz's RADIO_STATUS, ADSB_VEHICLE and COLLISION frames, which PX4 takes unsigned: logged)
    assert records(a.tlog, without=ACCEPTED_UNSIGNED) == records(b.tlog)
    assert a.plant_tlog.read_bytes() == b.plant_tlog.read_bytes()
    # every frame either process sent is signed (the quiet flight's log holds nothing else)
    data = b.plant_tlog.read_bytes()
    frames = 0
    i = 0
    while i < len(data):
        length = data[i + 9] + 12 + (13 if data[i + 10] & 1 else 0)
        frame = data[i + 8:i + 8 + length]
        assert frame[2] & 1, f"an unsigned frame in the plant's log at byte {i}"
        frames += 1
        i += 8 + length
    assert frames > 100
    m = a.summary["messages"]
    print(f"\nthe offboard under fuzz: {m}")
    seen = m["bad"] + sum(m["refused"].values()) + m["duplicates"]
    assert seen > FUZZ_FRAMES // 4  # the fuzz reached it (and was refused, never handled)
    # the intruder's frames at the offboard were refused too (the fuzz is refused as unsigned and
    # badly signed as well, and some of it is lost in the kernel: those counts are at least ours),
    # and every replay is counted as one: the fuzz holds no frame signed with the key
    assert m["refused"]["replayed"] == ROUNDS * REPLAYS
    assert m["refused"]["unsigned"] >= ROUNDS * 2 and m["refused"]["bad_signature"] >= ROUNDS * 2
    # the plant counted each of the intruder's frames (the quiet flight's plant refused none)
    n = 2 * ROUNDS * 3
    assert (f"refused {n + ROUNDS * REPLAYS} frames before handling (bad_signature {n // 2}, replayed {ROUNDS * REPLAYS}, "
            f"unsigned {n // 2}; system 200: {n // 2}, system 245: {n // 2 + ROUNDS * REPLAYS})") in a.plant_stderr, a.plant_stderr
    # the log of a signed flight replays
    replayed = subprocess.run([PY, "-m", "offboard.cli", "replay", str(a.tlog), "--run-dir", str(tmp_path / "replay"),
                               "--no-plots", "--json"], capture_output=True, text=True, env=ENV, timeout=120)  # fmt: skip
    assert replayed.returncode == 0, replayed.stderr


def test_the_plant_reports_the_frames_it_refused(tmp_path):
    key = tmp_path / "key.bin"
    key.write_bytes(KEY)
    port_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    port_sock.bind(("127.0.0.1", 0))
    port = port_sock.getsockname()[1]
    port_sock.close()
    plant = subprocess.Popen([PY, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{port}", "--api-remote", "none",
                              "--gcs-bind", "none", "--lockstep", "--signing-key", str(key)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV)  # fmt: skip
    try:
        banner = plant.stderr.readline()  # printed once the links are up and the signals handled
        assert banner.startswith("sitl-plant:"), banner
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        mav = mavlink.MAVLink(None, srcSystem=200, srcComponent=190)
        for _ in range(7):
            sock.sendto(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0).pack(mav), ("127.0.0.1", port))
        sock.close()
        time.sleep(0.5)
    finally:
        plant.terminate()
        _, err = plant.communicate(timeout=20)
    assert plant.returncode == 0, err
    assert "refused 7 frames before handling (unsigned 7; system 200: 7)" in err, err
