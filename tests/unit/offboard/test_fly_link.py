"""offboard.link over real loopback UDP: tlog, duplicates, loss from sequence numbers, bad bytes."""

from __future__ import annotations

import socket

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from offboard.demo import free_udp_ports
from offboard.link import LinkError, MavLink


def vehicle_packet(seq: int, t_ms: int = 0, kind: str = "attitude") -> bytes:
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    packer.seq = seq
    if kind == "attitude":
        return mavlink.MAVLink_attitude_message(t_ms, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(packer)
    return mavlink.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3).pack(packer)


@pytest.fixture
def pair(tmp_path):
    (port,) = free_udp_ports(1)
    clock = {"us": 1_600_000_000_000_000}
    link = MavLink(f"udpin:127.0.0.1:{port}", tlog_path=tmp_path / "link.tlog", log_time_us=lambda: clock["us"])
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(2.0)
    yield link, peer, ("127.0.0.1", port), clock
    link.close()
    peer.close()


def test_sent_and_received_are_logged_in_handling_order(pair, tmp_path):
    link, peer, addr, clock = pair
    peer.sendto(vehicle_packet(0, 100), addr)
    msg = link.recv(2.0)
    assert msg is not None and msg.get_type() == "ATTITUDE" and msg.time_boot_ms == 100
    clock["us"] += 50_000
    link.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
    data, _ = peer.recvfrom(1000)  # udpin answers whoever talked
    assert mavlink.MAVLink(None).parse_buffer(data)[0].get_srcSystem() == 245
    link.close()
    log = mavutil.mavlink_connection(str(tmp_path / "link.tlog"), dialect="common")
    first, second = log.recv_match(), log.recv_match()
    assert (first.get_type(), first.get_srcSystem()) == ("ATTITUDE", 1)
    assert (second.get_type(), second.get_srcSystem()) == ("HEARTBEAT", 245)
    assert second._timestamp - first._timestamp == pytest.approx(0.05)  # the injected clock
    assert log.recv_match() is None
    assert link.stats.sent == 1 and link.stats.received == 1


def test_repeated_packets_are_duplicates_not_news(pair):
    link, peer, addr, _ = pair
    packet = vehicle_packet(7, 100)
    for _ in range(3):  # a lockstep plant's keepalive resends the same bytes
        peer.sendto(packet, addr)
    assert link.recv(2.0) is not None
    assert link.recv(0.3) is None
    assert link.stats.received == 1 and link.stats.duplicates == 2 and link.stats.lost == 0


def test_a_keepalive_heartbeat_far_behind_the_latest_number_is_still_a_duplicate(pair):
    """A lockstep plant that waits resends its latest HEARTBEAT byte for byte, however many packets
    (parameters, telemetry) it sent since: 70 in one run, past the 64-packet window of the
    sequence check, and the copies were logged as news (two lockstep runs' logs then differed by
    how long the design took)."""
    link, peer, addr, _ = pair
    heartbeat = vehicle_packet(0, kind="heartbeat")
    peer.sendto(heartbeat, addr)
    for seq in range(1, 101):
        peer.sendto(vehicle_packet(seq, seq), addr)
    for _ in range(3):
        peer.sendto(heartbeat, addr)
    peer.sendto(vehicle_packet(101, kind="heartbeat"), addr)  # the next one: news
    got = []
    while (msg := link.recv(0.3)) is not None:
        got.append((msg.get_type(), msg.get_seq()))
    assert got.count(("HEARTBEAT", 0)) == 1 and got[-1] == ("HEARTBEAT", 101) and len(got) == 102, got
    assert link.stats.duplicates == 3 and link.stats.lost == 0


def test_loss_is_counted_from_sequence_gaps(pair):
    link, peer, addr, _ = pair
    for seq in (0, 1, 4, 5):
        peer.sendto(vehicle_packet(seq, seq), addr)
    got = [link.recv(2.0) for _ in range(4)]
    assert all(m is not None for m in got)
    assert link.stats.lost == 2


def test_a_late_packet_or_second_sequence_is_not_loss(pair):
    link, peer, addr, _ = pair
    for seq, t in ((10, 1), (11, 2), (3, 3), (12, 4)):
        peer.sendto(vehicle_packet(seq, t, "heartbeat" if seq == 3 else "attitude"), addr)
    got = [link.recv(2.0) for _ in range(4)]
    assert [m.get_type() for m in got] == ["ATTITUDE", "ATTITUDE", "HEARTBEAT", "ATTITUDE"]
    assert link.stats.lost == 0 and link.stats.duplicates == 0


def test_bad_bytes_are_counted_and_the_next_datagram_still_parses(pair):
    link, peer, addr, _ = pair
    good = vehicle_packet(0, 5)
    corrupted = bytearray(good)
    corrupted[-1] ^= 0xFF  # CRC broken
    peer.sendto(bytes(corrupted), addr)
    peer.sendto(good[:10], addr)  # truncated
    peer.sendto(b"\x00junk\xfd", addr)
    peer.sendto(vehicle_packet(1, 6), addr)
    msg = link.recv(2.0)
    assert msg is not None and msg.time_boot_ms == 6
    assert link.stats.bad >= 1 and link.stats.received == 1


def test_recv_times_out_with_none(pair):
    link, *_ = pair
    assert link.recv(0.05) is None


@pytest.mark.parametrize("connect", ["nonsense", "http://example.com"])
def test_bad_connection_strings_are_user_errors(connect):
    with pytest.raises(LinkError, match="expected a pymavlink connection string"):
        MavLink(connect)


def test_an_unwritable_log_is_a_user_error(tmp_path):
    (port,) = free_udp_ports(1)
    with pytest.raises(LinkError, match="cannot write the log"):
        MavLink(f"udpin:127.0.0.1:{port}", tlog_path=tmp_path / "missing-dir" / "x.tlog")


def test_a_burst_larger_than_linuxs_default_buffer_is_received_whole(pair):
    """The vehicle streams hundreds of datagrams a second until the unread streams are off: an
    offboard that did not read for a while must find them all, not Linux's 208 kB default's worth
    (the kernel caps the buffer at net.core.rmem_max; this burst fits any cap above 1 MB)."""
    link, peer, addr, _ = pair
    asked = link.conn.port.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    try:
        rmem_max = int(open("/proc/sys/net/core/rmem_max").read())
    except OSError:
        rmem_max = 0
    if rmem_max and rmem_max < (1 << 20):
        pytest.skip(f"net.core.rmem_max is {rmem_max} here: no buffer above the default to ask for")
    burst = 4000  # ~0.9 MB of ATTITUDE datagrams, each ~1 kB of kernel buffer: 4x the default
    for seq in range(burst):
        peer.sendto(vehicle_packet(seq % 256, seq), addr)
    got = 0
    while link.recv(0.2) is not None:
        got += 1
    assert got == burst, f"{burst - got} of {burst} datagrams dropped with a {asked} B receive buffer"
