"""10^5 fuzzed frames of every kind at each of the plant's receiving sockets (issue 14): no crash, no state
change of the disarmed vehicle, still answering; without signing and with it (every fuzzed frame
then refused before handling, and counted). At an unsigned offboard too, and another autopilot's
heartbeat during its flight. (The signed offboard's: tests/e2e/test_signing_e2e.py.)"""

from __future__ import annotations

import socket
import subprocess
import time
from functools import partial

import pytest

from pymavlink.dialects.v20 import common as mavlink

from helpers.flights import ENV, PY, arc_hold_mission, fly, free_udp_ports
from helpers.fuzz import AFTER_THE_FUZZ, FUZZ_FRAMES, STRANGERS, Fuzzer, fuzz_the_offboard
from offboard.replay import TlogReader

WATCHED = ("MPC_XY_VEL_MAX", "COM_OF_LOSS_T", "SIM_MASS", "MAV_SYS_ID")


KEY = bytes(range(40, 72))
#: how often a request is sent again while its answer is awaited (QGroundControl: 1 s for parameters)
RESEND_S = 1.0


class Client:
    def __init__(self, port: int, key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.address = ("127.0.0.1", port)
        self.mav = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
        self.parser = mavlink.MAVLink(None)
        if key is not None:  # sign what we send, as the spec says (timestamps in 10 us since 2015)
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = key, True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.address)

    def wait_for(self, kind: str, timeout_s: float = 10.0, where=lambda m: True, resend=None):  # a loaded machine: slow, not wrong
        """The first ``kind`` message that passes ``where``; ``resend`` (the request it answers) is sent
        again every ``RESEND_S`` meanwhile, as a ground station retries: a request that reaches
        the plant's socket while the fuzz still fills its buffer is dropped by the kernel."""
        deadline = time.monotonic() + timeout_s
        next_send = time.monotonic() + RESEND_S
        while time.monotonic() < deadline:
            if resend is not None and time.monotonic() >= next_send:
                self.send(resend)
                next_send += RESEND_S
            try:
                data = self.sock.recv(65535)
            except socket.timeout:
                continue
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == kind and where(m):
                    return m
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def state(self) -> dict:
        beat = self.wait_for("HEARTBEAT", where=lambda m: m.get_srcSystem() == 1)
        values = {}
        for name in WATCHED:
            request = mavlink.MAVLink_param_request_read_message(1, 1, name.encode(), -1)
            self.send(request)
            values[name] = self.wait_for("PARAM_VALUE", where=lambda m, n=name: m.param_id == n, resend=request).param_value
        return {"base_mode": beat.base_mode, "custom_mode": beat.custom_mode, "status": beat.system_status, **values}


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_the_plant_survives_the_fuzz_unchanged(tmp_path, signed):
    port, gcs_port = free_udp_ports(2)
    signing: list[str] = []
    if signed:
        (tmp_path / "key.bin").write_bytes(KEY)
        signing = ["--signing-key", str(tmp_path / "key.bin")]
    plant = subprocess.Popen([PY, "-m", "sitl_plant.cli", "--api-bind", f"127.0.0.1:{port}", "--api-remote", "none",
                              "--gcs-bind", f"127.0.0.1:{gcs_port}", "--gcs-remote", "none", *signing], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env=ENV)  # fmt: skip
    client = Client(port, KEY if signed else None)
    fuzzer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert plant.stderr.readline().startswith("sitl-plant:")
        client.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3))
        before = client.state()
        assert not before["base_mode"] & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        # at the API link; unsigned, at the ground station's too, in turns (a signing plant
        # refuses what the fuzz sends either link by the same check: once is enough)
        datagrams = {port: Fuzzer(20).datagrams(FUZZ_FRAMES)}
        if not signed:
            datagrams[gcs_port] = Fuzzer(21).datagrams(FUZZ_FRAMES)
        for start in range(0, len(datagrams[port]), 200):
            for to, batches in datagrams.items():
                for d in batches[start:start + 200]:
                    fuzzer.sendto(d, ("127.0.0.1", to))
                # paced by the plant: the kernel's buffer holds a few hundred datagrams, and a
                # plant slowed by a loaded machine (or by a hash a frame, signing) would lose
                # the rest, and the floors below with them
                _wait_until_read(to)
        client.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3))  # talk last: the plant answers us
        after = client.state()  # still answering
        assert after == before  # disarmed, same mode, same parameters
    finally:
        fuzzer.close()
        client.sock.close()
        plant.terminate()
        _, err = plant.communicate(timeout=30)
    assert plant.returncode == 0, err
    assert "Traceback" not in err and "raised an error" not in err, err
    print(f"\n{err.strip()}")
    bad = int(err.split("bad packets ")[1].split(",")[0])  # both links'
    gcs_bad = int(err.split("sitl-plant: gcs link in ")[1].split("bad packets ")[1].split()[0])
    assert bad - gcs_bad > (0 if signed else FUZZ_FRAMES // 10)  # the fuzz got there
    assert signed or gcs_bad > FUZZ_FRAMES // 10
    if signed:  # what parsed was refused before handling (the fuzz holds no frame signed with the key)
        refused = int(err.split("sitl-plant: refused ")[1].split(" frames")[0])
        assert refused > FUZZ_FRAMES // 50 and bad + refused > FUZZ_FRAMES // 10


def _receive_queue_bytes(port: int) -> int | None:
    """The bytes waiting in the receive queue of the UDP socket bound to 127.0.0.1:port
    (/proc/net/udp's rx_queue, Linux); None where it cannot be read."""
    try:
        rows = open("/proc/net/udp").read().splitlines()[1:]
    except OSError:
        return None
    local = f"0100007F:{port:04X}"
    for row in rows:
        fields = row.split()
        if fields[1] == local:
            return int(fields[4].split(":")[1], 16)
    return None


def _wait_until_read(port: int, timeout_s: float = 10.0) -> None:
    """Until the plant has read what was sent to its socket at ``port`` (or, without /proc, a pause)."""
    deadline = time.monotonic() + timeout_s
    while True:
        waiting = _receive_queue_bytes(port)
        if waiting is None:
            time.sleep(0.06)
            return
        if waiting == 0:
            return
        assert time.monotonic() < deadline, f"the plant left {waiting} bytes unread at port {port} for {timeout_s} s"
        time.sleep(0.002)


STRANGER = 7  # another autopilot's system id
HOLD = 4 << 16 | 3 << 24  # PX4's custom mode Auto/Hold
ROUNDS = 5


def stranger(ctx) -> None:
    """Once armed, at the offboard: another autopilot (system 7) announcing itself armed in
    Hold, then disarmed, and acknowledging a mode change."""
    ctx.wait_for("armed: flying the mission")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other = mavlink.MAVLink(None, srcSystem=STRANGER, srcComponent=1)
    frames = [
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x81 | 0x40, HOLD, 4, 3),
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x01, HOLD, 3, 3),
        mavlink.MAVLink_command_ack_message(176, 0, 0, 0, 245, 191),
    ]
    try:
        for _ in range(ROUNDS):  # at once: the flight is in lockstep, a few simulated seconds a tenth of a second
            for msg in frames:
                sock.sendto(msg.pack(other), ("127.0.0.1", ctx.offboard_port))
    finally:
        sock.close()


def test_an_unsigned_offboard_survives_the_fuzz_and_ignores_a_stranger(tmp_path):
    """10^5 frames from strangers' system ids at an unsigned offboard waiting for its vehicle
    (``--target-system 1``): no crash, and it still answers: the flight completes. During the
    flight, another autopilot's HEARTBEATs (armed in Hold, then disarmed) and COMMAND_ACK reach
    it: its own filter (offboard/flight/mission.py, ``from_vehicle``) takes none of them for the
    vehicle's, and the mission goes on. (Without signing, frames forged with the vehicle's ids
    are the vehicle's as far as the offboard can tell (docs/plant.md, 'Who may talk to the
    vehicle'); the signed flight of tests/e2e/test_signing_e2e.py takes the fuzz with them too.)"""
    # the arc, then a hold: the stranger's frames reach an offboard still flying (after the arc alone
    # a round sent as the flight ended was never read: 9 of 15 frames once)
    mission = arc_hold_mission(tmp_path / "arc-hold.toml")
    flown = fly(tmp_path, mission, name="fuzzed", fly_args=("--target-system", "1", *AFTER_THE_FUZZ),
                before_plant=partial(fuzz_the_offboard, sysid_choices=STRANGERS), during=stranger)  # fmt: skip
    assert flown.returncode == 0 and flown.status == "complete" and flown.summary["disarmed"], flown.stderr
    assert "Traceback" not in flown.stderr, flown.stderr
    m = flown.summary["messages"]
    print(f"\nthe unsigned offboard under fuzz: bad {m['bad']}, received {m['received']}")
    assert m["bad"] + sum(m["refused"].values()) + m["duplicates"] > FUZZ_FRAMES // 10  # the fuzz reached it
    heard = [r for r in TlogReader(flown.tlog) if r.msg.get_srcSystem() == STRANGER]
    assert len(heard) == ROUNDS * len(("armed", "disarmed", "ack"))  # the stranger's reached it (logged), and changed nothing
