"""Protocol details a PX4 client relies on: MPC_THR_MIN published, TIMESYNC replies never tc1 = 0,
lockstep keepalives resending the logged bytes (real UDP on 127.0.0.1)."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant.autopilot import Autopilot
from offboard.model.tlog import TlogWriter
from sitl_plant.link import Endpoint, Link
from sitl_plant.params import plant_params
from sitl_plant.server import API, Plant, PlantConfig, run_lockstep
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

_SENDER = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
_PARSER = mavlink.MAVLink(None)


def wire(msg):
    return _PARSER.parse_buffer(msg.pack(_SENDER))[0]


def make_plant(lockstep: bool = True) -> Plant:
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    return Plant(PlantConfig(lockstep=lockstep), vehicle, params, Autopilot(params))


def test_mpc_thr_min_is_published_with_px4_default():
    plant = make_plant()
    assert plant.params["MPC_THR_MIN"] == pytest.approx(0.12, abs=1e-7)
    plant.handle(API, wire(mavlink.MAVLink_param_request_read_message(1, 1, b"MPC_THR_MIN", -1)))
    (reply,) = plant.outbox[API]
    assert reply.get_type() == "PARAM_VALUE" and reply.param_id == "MPC_THR_MIN"
    assert reply.param_value == pytest.approx(0.12, abs=1e-7) and reply.param_count == len(plant.params)


def test_timesync_reply_at_time_zero_is_a_reply():
    plant = make_plant()
    assert plant.time_us == 0
    plant.handle(API, wire(mavlink.MAVLink_timesync_message(0, 987654321)))
    (reply,) = plant.outbox[API]
    assert reply.get_type() == "TIMESYNC" and reply.tc1 != 0 and reply.ts1 == 987654321
    plant.outbox[API].clear()
    plant.advance(plant.tick_steps)
    plant.handle(API, wire(mavlink.MAVLink_timesync_message(0, 5)))
    assert plant.outbox[API][0].tc1 == plant.time_us * 1000  # simulation time in ns after time 0


def _received(sock: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(sock.recv(65535))
        except BlockingIOError:
            return out


def test_lockstep_keepalives_resend_the_logged_bytes(tmp_path):
    """Nobody answers: the plant's datagrams after the first are byte-identical copies of the
    logged telemetry and heartbeat, and the tlog holds each packet once."""
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    client.setblocking(False)
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), client.getsockname(), 1, 1)
    link = Link([endpoint], TlogWriter(tmp_path / "plant.tlog"), plant.epoch_us)
    datagrams: list[bytes] = []

    def three_or_timeout() -> bool:  # the first and two keepalives (0.4 s), however loaded the machine
        datagrams.extend(_received(client))
        return len(datagrams) >= 3 or time.monotonic() - start > 10.0

    try:
        start = time.monotonic()
        run_lockstep(plant, link, stop=three_or_timeout, keepalive_s=0.2)
    finally:
        link.close()
    datagrams.extend(_received(client))
    client.close()
    first, repeats = datagrams[0], datagrams[1:]
    assert len(repeats) >= 2  # at 0.2 s and 0.4 s (and 0.6 s)
    kinds = [m.get_type() for m in mavlink.MAVLink(None).parse_buffer(first)]
    assert "HEARTBEAT" in kinds and "ATTITUDE" in kinds and "LOCAL_POSITION_NED" in kinds
    assert all(d == first for d in repeats)  # the whole first datagram (with its heartbeat) again
    logged = (tmp_path / "plant.tlog").read_bytes()
    assert logged.count(first[:20]) == 1 and endpoint.packer.seq == len(kinds)


def test_keepalive_heartbeat_is_the_latest_sent_when_telemetry_has_none(tmp_path):
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.setblocking(False)
    endpoint = Endpoint("api", ("127.0.0.1", 0), peer.getsockname(), 1, 1)
    link = Link([endpoint], None, lambda: 0)
    try:
        beat = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)
        link.send(0, [beat])
        imu = mavlink.MAVLink_highres_imu_message(50_000, *([0.0] * 13), 0, 0)  # has a field named id (= 0)
        link.send(0, [mavlink.MAVLink_attitude_message(50, 0, 0, 0, 0, 0, 0), imu], remember="telemetry")
        sent = _received(peer)
        seq = endpoint.packer.seq
        time.sleep(0.01)
        link.resend_remembered()
        link.send_keepalive(0, [mavlink.MAVLINK_MSG_ID_HEARTBEAT])
        time.sleep(0.05)
        again = _received(peer)
    finally:
        link.close()
        peer.close()
    assert again == [sent[1], sent[0]]  # the telemetry, then the heartbeat it lacked: same bytes
    assert endpoint.packer.seq == seq  # no sequence number spent


def test_setpoints_older_than_the_newest_flown_are_refused_unless_the_sender_restarted():
    """A link that duplicates and reorders: a setpoint stamped before the newest one flown from its
    sender (within a second) is refused and counted; one far behind is a restarted sender."""
    plant = make_plant()

    def roll(stamp_ms: int, roll_rad: float, sysid: int = 245) -> bool:
        """Send a roll setpoint; whether the plant now flies it."""
        import math

        q = [math.cos(roll_rad / 2), math.sin(roll_rad / 2), 0.0, 0.0]
        msg = mavlink.MAVLink_set_attitude_target_message(stamp_ms, 1, 1, 0b00000111, q, 0, 0, 0, 0.5)
        sender = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=191)
        plant.handle(API, _PARSER.parse_buffer(msg.pack(sender))[0])
        latest = plant.autopilot.last_setpoint
        return latest is not None and abs(latest.q_wxyz[1] - q[1]) < 1e-6

    assert roll(1000, 0.1) and roll(1050, 0.2)
    assert not roll(1020, 0.3)  # reordered: refused
    assert plant.counters.refusals.get("out-of-order") == 1
    assert roll(1050, 0.25)  # the same stamp again (a repeat): taken
    assert roll(1030, 0.3, sysid=246)  # another sender has its own newest
    assert roll(10, 0.35)  # 1040 ms behind: the sender's clock restarted
