"""offboard.link against a stranger on the link (issue 14), over real loopback UDP: once the
offboard knows its vehicle (``MavLink.trusted``, set by the flight from the first autopilot
heartbeat), nobody else's datagram changes where it sends, signed or not; a vehicle's signed
frame sent again is refused."""

from __future__ import annotations

import socket

import pytest
from pymavlink.dialects.v20 import common as mavlink

from offboard.demo import free_udp_ports
from offboard.link import MavLink
from offboard.signing import SigningKey, SigningSession, signing_timestamp

KEY = bytes(range(1, 33))
T0_US = 1_796_000_000_000_000  # a Unix time in 2026, microseconds


class Peer:
    """A socket of its own speaking MAVLink as ``sysid``/``compid``, signing with ``secret`` if given."""

    def __init__(self, sysid: int, compid: int, secret: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.3)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        if secret is not None:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = secret, True
            self.mav.signing.timestamp = signing_timestamp(T0_US) + 1

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()  # type: ignore[no-any-return]

    def packet(self, msg: mavlink.MAVLink_message) -> bytes:
        """``msg`` packed with our next sequence number."""
        packet = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        return packet

    def heard(self) -> list[tuple[int, str]]:
        """(source system, type) of everything that reached us."""
        parser = mavlink.MAVLink(None)
        out = []
        while True:
            try:
                data = self.sock.recv(65535)
            except (TimeoutError, socket.timeout):
                return out
            out += [(m.get_srcSystem(), m.get_type()) for m in parser.parse_buffer(data) or []]

    def close(self) -> None:
        self.sock.close()


def autopilot_heartbeat(custom_mode: int = 6 << 16) -> mavlink.MAVLink_message:  # PX4 Offboard
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0x81, custom_mode, 4, 3)


def drain(link: MavLink) -> list[tuple[int, int, str]]:
    """(system, component, type) of every message the link hands over now."""
    out = []
    while (msg := link.recv(0.2)) is not None:
        out.append((msg.get_srcSystem(), msg.get_srcComponent(), msg.get_type()))
    return out


@pytest.fixture(params=["unsigned", "signed"])
def flying(request):
    """An offboard link on a free port that has heard its vehicle (1/1) and trusts it."""
    signed = request.param == "signed"
    (port,) = free_udp_ports(1)
    session = SigningSession(SigningKey(KEY), lambda: T0_US) if signed else None
    link = MavLink(f"udpin:127.0.0.1:{port}", signing=session)
    vehicle, stranger = Peer(1, 1, KEY if signed else None), Peer(200, 1)
    vehicle.sock.sendto(vehicle.packet(autopilot_heartbeat()), ("127.0.0.1", port))
    assert drain(link) == [(1, 1, "HEARTBEAT")]
    link.trusted = (1, 1)  # as Flight does on the vehicle's first autopilot heartbeat
    yield link, vehicle, stranger, ("127.0.0.1", port), signed
    link.close()
    vehicle.close()
    stranger.close()


def our_heartbeat() -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)


HOLD = autopilot_heartbeat(4 << 16 | 3 << 24)  # PX4's Hold, as an intruder would announce it


def test_another_systems_datagrams_do_not_move_where_the_offboard_sends(flying):
    link, vehicle, stranger, address, signed = flying
    stranger.sock.sendto(stranger.packet(HOLD), address)
    stranger.sock.sendto(stranger.packet(mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0)), address)
    handed = drain(link)
    link.send(our_heartbeat())
    assert vehicle.heard() == [(245, "HEARTBEAT")]  # the vehicle still gets what we send ...
    assert stranger.heard() == []  # ... and the stranger nothing
    if signed:  # its HEARTBEAT refused; its RADIO_STATUS taken unsigned (as PX4 does), which proves nothing
        assert handed == [(200, 1, "RADIO_STATUS")] and link.stats.refused == {"unsigned": 1}
    else:  # handed over under the stranger's ids, which the flight ignores (not its target)
        assert handed == [(200, 1, "HEARTBEAT"), (200, 1, "RADIO_STATUS")]


def test_with_signing_frames_forged_with_the_vehicles_ids_do_not_move_it_either(flying):
    link, vehicle, _, address, signed = flying
    impostor = Peer(1, 1) if not signed else Peer(1, 1, bytes(32 * [9]))  # unsigned; signed with another key
    try:
        impostor.sock.sendto(impostor.packet(HOLD), address)
        impostor.sock.sendto(impostor.packet(mavlink.MAVLink_command_ack_message(176, 0, 0, 0, 245, 191)), address)
        if signed:
            unsigned = Peer(1, 1)
            unsigned.sock.sendto(unsigned.packet(HOLD), address)
            unsigned.sock.sendto(unsigned.packet(mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0)), address)
            unsigned.close()
        handed = drain(link)
        link.send(our_heartbeat())
        if signed:
            assert handed == [(1, 1, "RADIO_STATUS")] and link.stats.refused == {"bad_signature": 2, "unsigned": 1}
            assert vehicle.heard() == [(245, "HEARTBEAT")] and impostor.heard() == []
        else:  # the risk of flying unsigned (docs/offboard.md): the impostor is the vehicle now
            assert handed == [(1, 1, "HEARTBEAT"), (1, 1, "COMMAND_ACK")]
            assert vehicle.heard() == [] and impostor.heard() == [(245, "HEARTBEAT")]
    finally:
        impostor.close()


def test_only_the_vehicle_moves_the_offboards_peer(flying):
    """The vehicle's own new address (a restarted plant) is followed: only others are ignored."""
    link, vehicle, stranger, address, _ = flying
    stranger.sock.sendto(stranger.packet(autopilot_heartbeat()), address)
    drain(link)
    moved = Peer(1, 1, vehicle.mav.signing.secret_key)
    moved.mav.signing.timestamp = vehicle.mav.signing.timestamp + 100
    moved.mav.seq = vehicle.mav.seq
    moved.sock.sendto(moved.packet(autopilot_heartbeat()), address)
    assert drain(link) == [(1, 1, "HEARTBEAT")]
    link.send(our_heartbeat())
    assert (245, "HEARTBEAT") in moved.heard() and stranger.heard() == []
    moved.close()


@pytest.mark.parametrize("flying", ["signed"], indirect=True)
def test_the_vehicles_signed_frame_sent_again_is_refused(flying):
    link, vehicle, stranger, address, _ = flying
    first = vehicle.packet(mavlink.MAVLink_attitude_message(100, 0.1, 0.2, 0.3, 0, 0, 0))
    vehicle.sock.sendto(first, address)
    stranger.sock.sendto(first, address)  # at once: a copy (as a duplicating link makes), dropped
    assert drain(link) == [(1, 1, "ATTITUDE")] and link.stats.duplicates == 1
    for i in range(80):  # the vehicle goes on, beyond the duplicate filter's window
        vehicle.sock.sendto(vehicle.packet(mavlink.MAVLink_attitude_message(101 + i, 0.1, 0.2, 0.3, 0, 0, 0)), address)
    assert len(drain(link)) == 80
    stranger.sock.sendto(first, address)  # recorded and sent again
    assert drain(link) == [] and link.stats.refused == {"replayed": 1}
    link.send(our_heartbeat())
    assert stranger.heard() == [] and vehicle.heard()[-1] == (245, "HEARTBEAT")
