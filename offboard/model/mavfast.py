"""MAVLink 2 packing of the hot messages with pre-built ``struct`` packers (issue 16).

pymavlink's ``msg.pack(mav)`` builds a header object, a bytearray and its CRC in a pure-Python
loop over every byte (``x25crc`` without the optional ``fastcrc``): about half of the cost of a
lockstep cycle's messages. ``pack(msg, mav)`` writes the same bytes for the messages on the loop's
hot path (``HOT``) with one pre-built ``struct.Struct`` for the payload, one for the header and the
CRC-16/MCRF4XX in C (``binascii.crc_hqx`` on the bit-reversed bytes: the reflected CRC is the
plain one of the reflected input), and falls back to pymavlink for every other message.

What stays pymavlink's: the wire format (MAVLink 2, trailing zeros of the payload cut, at least
one byte kept), the sequence number, system and component ids read from ``mav`` (the caller still
advances ``mav.seq``, as with ``msg.pack``), the CRC with the message's crc_extra, and signing
when ``mav.signing.sign_outgoing`` (link id, 48-bit timestamp then incremented, SHA-256 of the
secret key and the frame, first 6 bytes). ``tests/unit/offboard/test_mavfast.py`` checks every
hot message equal byte for byte to pymavlink's own packing, signed and unsigned.
"""

from __future__ import annotations

import binascii
import hashlib
import struct
from typing import Any
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

_REVERSE8 = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))
_HEADER = struct.Struct("<BBBBBBBHB")
_U16 = struct.Struct("<H")
_U64 = struct.Struct("<Q")
_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED


def x25crc(data: bytes) -> int:
    """CRC-16/MCRF4XX (MAVLink's ``x25crc``) of ``data``, in C (the 16-bit result bit-reversed a
    byte at a time: a table of all 65 536 took 30 ms of every process's start)."""
    crc = binascii.crc_hqx(data.translate(_REVERSE8), 0xFFFF)
    return _REVERSE8[crc & 0xFF] << 8 | _REVERSE8[crc >> 8]


class _Packer:
    """One message type: its payload ``struct``, crc_extra and a field getter in wire order."""

    __slots__ = ("msg_id", "crc_extra", "payload", "values", "id_bytes")

    def __init__(self, cls: Any) -> None:  # a pymavlink message class (untyped)
        self.msg_id = cls.id
        self.crc_extra = cls.crc_extra
        self.payload = cls.unpacker
        self.id_bytes = (cls.id & 0xFFFF, cls.id >> 16)
        names = list(cls.ordered_fieldnames)
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        arrays = [n for n in names if lengths[n] and cls.fieldtypes[cls.fieldnames.index(n)] != "char"]
        if not arrays:
            scalars = names

            def values(msg: mavlink.MAVLink_message) -> tuple:
                return tuple(getattr(msg, n) for n in scalars)
        else:

            def values(msg: mavlink.MAVLink_message) -> tuple:
                out: list = []
                for n in names:
                    v = getattr(msg, n)
                    if n in arrays:
                        out.extend(v[: lengths[n]])
                    else:
                        out.append(v)
                return tuple(out)

        self.values: Callable[[mavlink.MAVLink_message], tuple] = values


#: The messages of the loop's hot path: the plant's telemetry, the offboard's setpoints and both
#: sides' heartbeats (and what a lockstep cycle carries besides: EXTENDED_SYS_STATE, the offboard's
#: actuator setpoint).
HOT_TYPES = (
    mavlink.MAVLink_attitude_message,
    mavlink.MAVLink_local_position_ned_message,
    mavlink.MAVLink_set_attitude_target_message,
    mavlink.MAVLink_set_actuator_control_target_message,
    mavlink.MAVLink_heartbeat_message,
    mavlink.MAVLink_extended_sys_state_message,
)
HOT: dict[type, _Packer] = {cls: _Packer(cls) for cls in HOT_TYPES}


def pack(msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
    """``msg.pack(mav)``'s bytes: pre-built for the ``HOT`` types, pymavlink's for the others.

    Raises what ``msg.pack`` raises for a value out of its field's range (``struct.error``)."""
    p = HOT.get(type(msg))
    if p is None:
        return msg.pack(mav)
    payload = p.payload.pack(*p.values(msg)).rstrip(b"\x00") or b"\x00"
    signing = mav.signing
    signed = signing.sign_outgoing
    header = _HEADER.pack(0xFD, len(payload), _SIGNED if signed else 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, *p.id_bytes)
    body = header[1:] + payload
    frame = header + payload + _U16.pack(x25crc(body + bytes((p.crc_extra,))))
    if signed:
        frame += bytes((signing.link_id,)) + _U64.pack(signing.timestamp)[:6]
        signing.timestamp += 1
        frame += hashlib.sha256(signing.secret_key + frame).digest()[:6]
    return frame


# --- parsing -------------------------------------------------------------------------------------


class _Unpacker:
    """One message type: its payload ``struct`` and pymavlink's field order, arrays regrouped."""

    __slots__ = ("cls", "crc_extra", "size", "unpack", "plan")

    def __init__(self, cls: Any) -> None:  # a pymavlink message class (untyped)
        self.cls = cls
        self.crc_extra = bytes((cls.crc_extra,))
        self.size = cls.unpacker.size
        self.unpack = cls.unpacker.unpack
        lengths = cls.lengths
        # (start, length) in the unpacked tuple of each constructor argument, as pymavlink's decode
        self.plan = tuple((sum(lengths[:order]), lengths[order]) for order in cls.orders)

    def fields(self, payload: bytes) -> list:
        t = self.unpack(payload)
        out: list = []
        for start, length in self.plan:
            v = t[start]
            if length == 1 or isinstance(v, bytes):
                out.append(v.rstrip(b"\x00") if isinstance(v, bytes) else v)
            else:
                out.append(list(t[start : start + length]))
        return out


UNPACKERS: dict[int, _Unpacker] = {cls.id: _Unpacker(cls) for cls in HOT_TYPES}


def parse_datagram(parser: mavlink.MAVLink, data: bytes) -> list[mavlink.MAVLink_message]:
    """``parser.parse_buffer(data) or []`` for one whole datagram, on a parser holding no partial
    frame: the leading frames of the ``HOT`` types decoded here (checked CRC, pymavlink's message
    objects with the same fields, header, buffer and CRC), the rest from the first other frame on
    by pymavlink. A parser with a signing key (pymavlink then verifies signatures) gets
    pymavlink's path throughout.

    Raises what ``parse_buffer`` raises."""
    out: list[mavlink.MAVLink_message] = []
    i, n = 0, len(data)
    if parser.signing.secret_key is None and not parser.buf:
        while n - i >= 12 and data[i] == 0xFD:
            mlen, flags = data[i + 1], data[i + 2]
            if flags & ~_SIGNED:
                break
            sig = 13 if flags else 0
            end = i + 12 + mlen + sig
            u = UNPACKERS.get(data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16)
            if u is None or end > n:
                break
            crc_at = i + 10 + mlen
            crc = data[crc_at] | data[crc_at + 1] << 8
            if crc != x25crc(data[i + 1 : crc_at] + u.crc_extra):
                break  # pymavlink says what is wrong
            payload = data[i + 10 : crc_at]
            if mlen < u.size:
                payload += bytes(u.size - mlen)
            m = u.cls(*u.fields(payload[: u.size]))
            frame = bytearray(data[i:end])
            m._signed = False
            m._msgbuf = frame
            m._payload = frame[6 : -(2 + sig)]
            m._crc = crc
            m._header = mavlink.MAVLink_header(u.cls.id, flags, data[i + 3], mlen, data[i + 4], data[i + 5], data[i + 6])
            if sig:
                parser.signing.sig_count += 1
            parser.total_packets_received += 1
            parser.total_bytes_received += end - i
            out.append(m)
            i = end
    if i < n:
        out += parser.parse_buffer(data[i:] if i else data) or []
    return out
