"""offboard.model.mavfast packs the hot messages byte for byte as pymavlink does (issue 16)."""

from __future__ import annotations

import math
import random

import pytest
from pymavlink.dialects.v20 import common as mavlink
from pymavlink.generator.mavcrc import x25crc_slow

from offboard.model import mavfast


def _samples(rng: random.Random) -> list[mavlink.MAVLink_message]:
    f = lambda: rng.uniform(-50, 50)  # noqa: E731
    return [
        mavlink.MAVLink_attitude_message(rng.randrange(2**32), f(), f(), f(), f(), f(), f()),
        mavlink.MAVLink_attitude_message(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # all zeros: one payload byte kept
        mavlink.MAVLink_local_position_ned_message(rng.randrange(2**32), f(), f(), f(), f(), f(), 0.0),  # trailing zeros cut
        mavlink.MAVLink_set_attitude_target_message(rng.randrange(2**32), 1, 1, 0b111, [f(), f(), f(), f()], f(), 0.0, math.nan, 0.45),
        mavlink.MAVLink_set_actuator_control_target_message(rng.randrange(2**63), 0, 1, 1, [f() for _ in range(8)]),
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
        mavlink.MAVLink_heartbeat_message(2, 12, 0x81, 6 << 16, 4, 3),
        mavlink.MAVLink_extended_sys_state_message(0, rng.randrange(5)),
    ]


def _mav(signed: bool, sysid: int = 1) -> mavlink.MAVLink:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    if signed:
        mav.signing.secret_key = bytes(range(32))
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 3
        mav.signing.timestamp = 123_456_789
    return mav


def test_crc_is_mavlinks():
    rng = random.Random(1)
    for n in (0, 1, 7, 64, 300):
        data = bytes(rng.randrange(256) for _ in range(n))
        assert mavfast.x25crc(data) == x25crc_slow(data).crc


@pytest.mark.parametrize("signed", [False, True])
def test_every_hot_message_packs_as_pymavlink_does(signed):
    rng = random.Random(2)
    ours, theirs = _mav(signed), _mav(signed)
    kinds = set()
    for _ in range(40):  # sequence numbers wrap past 255, signing timestamps advance
        for msg in _samples(rng):
            assert type(msg) in mavfast.HOT
            kinds.add(type(msg))
            a, b = mavfast.pack(msg, ours), msg.pack(theirs)
            assert a == b, msg.get_type()
            for mav in (ours, theirs):
                mav.seq = (mav.seq + 1) & 0xFF
    assert kinds == set(mavfast.HOT_TYPES)
    assert ours.signing.timestamp == theirs.signing.timestamp
    # and pymavlink parses (and, signed, verifies) what we packed
    parser = _mav(signed, sysid=9)
    frame = mavfast.pack(_samples(rng)[0], ours)
    parsed = parser.parse_buffer(frame)
    assert parsed and parsed[0].get_type() == "ATTITUDE" and parsed[0].get_crc() is not None


def test_other_messages_fall_back_to_pymavlink():
    msg = mavlink.MAVLink_statustext_message(4, b"hello")
    assert type(msg) not in mavfast.HOT
    assert mavfast.pack(msg, _mav(False)) == msg.pack(_mav(False))


def test_a_value_out_of_range_raises_as_pymavlink_does():
    msg = mavlink.MAVLink_attitude_message(2**32, 0, 0, 0, 0, 0, 0)
    with pytest.raises(Exception) as theirs:
        msg.pack(_mav(False))
    with pytest.raises(type(theirs.value)):
        mavfast.pack(msg, _mav(False))


def _same(a: mavlink.MAVLink_message, b: mavlink.MAVLink_message) -> None:
    assert type(a) is type(b)
    assert bytes(a.get_msgbuf()) == bytes(b.get_msgbuf()) and bytes(a._payload) == bytes(b._payload)
    assert (a.get_crc(), a._signed, a.get_seq(), a.get_srcSystem(), a.get_srcComponent()) == \
           (b.get_crc(), b._signed, b.get_seq(), b.get_srcSystem(), b.get_srcComponent())  # fmt: skip
    assert vars(a._header) == vars(b._header)
    da, db = a.to_dict(), b.to_dict()
    assert repr(da) == repr(db)  # NaN compares equal as text


def _datagram(rng: random.Random, mav: mavlink.MAVLink, messages: list) -> bytes:
    out = b""
    for msg in messages:
        out += msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
    return out


@pytest.mark.parametrize("signed", [False, True])
def test_datagrams_parse_as_pymavlink_parses_them(signed):
    rng = random.Random(4)
    mav = _mav(signed)
    text = mavlink.MAVLink_statustext_message(4, b"between")
    cases = []
    for _ in range(20):
        hot = _samples(rng)
        cases += [
            _datagram(rng, mav, hot),  # all hot
            _datagram(rng, mav, hot[:2] + [text] + hot[2:]),  # another message in the middle: pymavlink from there
            _datagram(rng, mav, hot[:3]) + b"\x01\x02garbage",  # a bad tail
        ]
    damaged = bytearray(_datagram(rng, mav, _samples(rng)[:2]))
    damaged[12] ^= 0xFF  # a CRC error in the first frame
    cases.append(bytes(damaged))
    cases.append(_datagram(rng, mav, _samples(rng))[:-5])  # a truncated last frame
    raised = 0
    for data in cases:
        fast, slow = mavlink.MAVLink(None), mavlink.MAVLink(None)
        try:
            theirs = slow.parse_buffer(data) or []
        except mavlink.MAVError as exc:  # pymavlink gives up on the datagram (the links count it bad): so do we
            with pytest.raises(type(exc), match=str(exc)):
                mavfast.parse_datagram(fast, data)
            raised += 1
            continue
        ours = mavfast.parse_datagram(fast, data)
        assert len(ours) == len(theirs) and ours, data.hex()
        for a, b in zip(ours, theirs, strict=True):
            if b.get_type() == "BAD_DATA":
                assert a.get_type() == "BAD_DATA" and bytes(a.data) == bytes(b.data)
            else:
                _same(a, b)
        assert fast.total_packets_received == slow.total_packets_received
        assert fast.signing.sig_count == slow.signing.sig_count
    assert 0 < raised < len(cases)


def test_a_parser_that_verifies_signatures_keeps_pymavlinks_path():
    rng = random.Random(5)
    data = _datagram(rng, _mav(True), _samples(rng))
    checking = _mav(True, sysid=9)
    checking.signing.sign_outgoing = False
    ours = mavfast.parse_datagram(checking, data)
    assert [m.get_type() for m in ours] == [m.get_type() for m in _samples(rng)]
    assert all(m._signed for m in ours)  # verified by pymavlink
