"""The offboard link's loss counter against PX4's dialect: frames of message ids common.xml lacks
(LINK_NODE_STATUS, TIME_ESTIMATE_TO_TARGET, CURRENT_MODE ... PX4 v1.16 sends them) use sequence
numbers too and must not count as lost (before: each counted 255 lost, lost > received)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from offboard.codec import frame_header
from offboard.link import MavLink
from sitl_plant import codec


@pytest.fixture
def link():
    with MavLink("udpin:127.0.0.1:0") as conn:
        yield conn


def px4_like_stream(n: int, drop: set[int] = frozenset()) -> list[bytes]:
    """``n`` packets of one source, every third of PX4's dialect; indices in ``drop`` are lost."""
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    dialect = (codec.link_node_status(1, 2, 3), codec.time_estimate_to_target(), codec.current_mode(1 << 16, 1 << 16))
    out = []
    for i in range(n):
        msg = dialect[i // 3 % 3] if i % 3 == 2 else mavlink.MAVLink_attitude_message(i, 0, 0, 0, 0, 0, 0)
        packet = msg.pack(packer)
        packer.seq = (packer.seq + 1) & 0xFF
        if i not in drop:
            out.append(packet)
    return out


def test_dialect_frames_advance_the_sequence_and_are_not_lost(link):
    for packet in px4_like_stream(600):  # through two wraps of the 8-bit sequence
        link._parse(packet)
    s = link.stats
    assert (s.received, s.lost, s.bad, s.duplicates) == (600, 0, 0, 0)
    assert s.unknown == 200 and s.received_by_type["ATTITUDE"] == 400
    # the flight is handed only what it can read
    kinds = {link.recv(0.0).get_type() for _ in range(400)}
    assert kinds == {"ATTITUDE"} and link.recv(0.0) is None


def test_real_gaps_are_still_counted_whatever_the_dialect(link):
    for packet in px4_like_stream(90, drop={10, 11, 50}):  # an ATTITUDE and a dialect frame among them
        link._parse(packet)
    assert (link.stats.received, link.stats.lost) == (87, 3)


def test_frame_header_reads_sequence_and_source_from_the_bytes():
    packer = mavlink.MAVLink(None, srcSystem=42, srcComponent=7)
    packer.seq = 200
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    (msg,) = parser.parse_buffer(codec.link_node_status(1, 2, 3).pack(packer))
    assert isinstance(msg, mavlink.MAVLink_unknown)
    assert (msg.get_seq(), msg.get_srcSystem()) == (0, 0)  # what pymavlink leaves: the cause of the bug
    assert frame_header(msg) == (200, 42, 7)


def test_a_reordering_duplicating_link_counts_only_what_never_came(link):
    """Issue 14: duplicated and reordered datagrams made the offboard count 2 034 "lost" when none
    was dropped. Seeded: each packet late by up to 5 places, one in ten twice, 1 in 20 dropped."""
    import random

    rng = random.Random(14)
    stream = px4_like_stream(2000)
    dropped = {i for i in range(1, 2000) if rng.random() < 0.05}
    kept = [(i + rng.uniform(0, 5), p) for i, p in enumerate(stream) if i not in dropped]
    kept += [(t + rng.uniform(0, 3), p) for t, p in kept if rng.random() < 0.1]  # duplicates
    for _, packet in sorted(kept, key=lambda tp: tp[0]):
        link._parse(packet)
    s = link.stats
    assert s.lost == len(dropped)
    assert s.received == 2000 - len(dropped)  # every copy was dropped as a duplicate
