"""Fuzzed MAVLink frames of every kind, seeded (issue 14's list): random bytes, truncated and
bit-flipped frames, valid-CRC frames of every common.xml message with random field values,
MAVLink 1 frames, wrong lengths and flags, and frames signed with the wrong key."""

from __future__ import annotations

import random
import socket
import struct
import time

import numpy as np

from pymavlink.dialects.v20 import common as mavlink

_INT_RANGES = {
    "int8_t": (-(2**7), 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1), "int32_t": (-(2**31), 2**31 - 1), "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1), "uint64_t": (0, 2**64 - 1), "uint8_t_mavlink_version": (0, 255),
}  # fmt: skip
_FLOATS = (0.0, -0.0, 1.0, -1.0, 1e-30, 3.4e38, float("nan"), float("inf"), float("-inf"))


def _value(rng: random.Random, ftype: str):
    if ftype in ("float", "double"):
        return rng.choice(_FLOATS) if rng.random() < 0.3 else rng.uniform(-1e6, 1e6)
    lo, hi = _INT_RANGES[ftype]
    return rng.choice((lo, hi, 0, 1)) if rng.random() < 0.3 else rng.randint(lo, hi)


_CLASSES = list(mavlink.mavlink_map.values())


def _array_lengths(cls: type) -> dict[str, int]:
    """Each field's array length (0: a scalar) by name: pymavlink keeps ``array_lengths`` in wire
    order (``ordered_fieldnames``) but ``fieldtypes`` and the constructor's arguments in
    declaration order (``fieldnames``), which differ wherever a message's fields are not sorted by
    size or it has extension fields."""
    return dict(zip(cls.ordered_fieldnames, cls.array_lengths))


def random_fields(rng: random.Random, cls: type, nprng: np.random.Generator) -> list:
    """Random values (within their types) for the fields of message class ``cls``, in the order
    its constructor takes them."""
    lengths = _array_lengths(cls)
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        length = lengths[name]
        if ftype == "char":  # a string: up to its array length of any bytes (one byte if a scalar)
            args.append(rng.randbytes(rng.randrange(length + 1 if length else 2)))
        elif length:  # arrays: drawn at once
            if ftype in ("float", "double"):
                args.append(nprng.uniform(-1e6, 1e6, length).tolist())
            else:
                lo, hi = _INT_RANGES[ftype]
                dtype = np.uint64 if ftype == "uint64_t" else np.int64
                args.append([int(v) for v in nprng.integers(lo, hi, length, dtype=dtype, endpoint=True)])
        else:
            args.append(_value(rng, ftype))
    return args


def random_message(rng: random.Random, nprng: np.random.Generator | None = None, cls: type | None = None) -> mavlink.MAVLink_message:
    """A message of a random common.xml type (or of ``cls``) with random field values (within
    their types)."""
    nprng = nprng or np.random.default_rng(rng.randrange(2**32))
    cls = cls or rng.choice(_CLASSES)
    return cls(*random_fields(rng, cls, nprng))


class Fuzzer:
    """Frames to throw at a process, seeded: ``datagrams(n)`` packs n frames into UDP datagrams.

    A pool of valid frames is drawn once (every common.xml message type, random field values,
    random sources and sequence numbers; unsigned MAVLink 2, MAVLink 1, and signed with a key
    nobody has); each fuzzed frame is then one of them as it is, truncated, with a bit flipped,
    with a wrong length or unknown flags, or random bytes.
    """

    def __init__(self, seed: int, *, pool: int = 3000, sysid_choices: tuple[int, ...] = (1, 2, 200, 245, 255)) -> None:
        self.rng = random.Random(seed)
        self.nprng = np.random.default_rng(seed)
        self.sysid_choices = sysid_choices
        plain, v1 = mavlink.MAVLink(None), mavlink.MAVLink(None)
        forger = mavlink.MAVLink(None)
        forger.signing.secret_key = self.rng.randbytes(32)
        forger.signing.sign_outgoing = True
        forger.signing.timestamp = 10**13
        self.valid = [self._pack(plain) for _ in range(pool)]
        self.v1 = [self._pack(v1, v1=True) for _ in range(pool // 6)]
        self.forged = [self._pack(forger) for _ in range(pool // 3)]

    def _pack(self, mav: mavlink.MAVLink, *, v1: bool = False) -> bytes:
        rng = self.rng
        while True:
            msg = random_message(rng, self.nprng)
            mav.srcSystem, mav.srcComponent = rng.choice(self.sysid_choices), rng.choice((1, 190, 191, 0))
            mav.seq = rng.randrange(256)
            try:
                return msg.pack(mav, force_mavlink1=v1)
            except (struct.error, OverflowError, ValueError, TypeError, mavlink.MAVError):
                continue  # a value its field cannot carry (pymavlink refuses to pack it): draw again

    def frame(self) -> bytes:
        rng = self.rng
        kind = rng.randrange(8)
        if kind == 0:  # random bytes
            return rng.randbytes(rng.randrange(1, 300))
        if kind == 3:  # MAVLink 1
            return rng.choice(self.v1)
        if kind == 6:  # signed with a key nobody has
            return rng.choice(self.forged)
        f = rng.choice(self.valid)
        if kind == 1:  # truncated
            return f[: rng.randrange(1, len(f))]
        if kind == 2:  # a bit flipped
            b = bytearray(f)
            bit = rng.randrange(len(b) * 8)
            b[bit // 8] ^= 1 << (bit % 8)
            return bytes(b)
        if kind == 4:  # a wrong payload length in the header
            return f[:1] + bytes([rng.randrange(256)]) + f[2:]
        if kind == 5:  # unknown incompatibility flags
            return f[:2] + bytes([rng.randrange(2, 256)]) + f[3:]
        return f  # a valid unsigned frame of any message with random fields

    def datagrams(self, n_frames: int, per_datagram: int = 8) -> list[bytes]:
        """``n_frames`` frames packed ``per_datagram`` at a time into UDP datagrams."""
        out = []
        for start in range(0, n_frames, per_datagram):
            out.append(b"".join(self.frame() for _ in range(min(per_datagram, n_frames - start))))
        return out


#: Frames a fuzz test sends at a process's receiving socket (issue 14: at least 10^5).
FUZZ_FRAMES = 100_000


#: System ids of everyone but the vehicle (1): a fuzz from strangers (the offboard's own 245 too).
STRANGERS = (2, 200, 245, 255)


#: ``offboard fly``'s wait for its vehicle when a fuzz comes first: the offboard parses the fuzz and
#: the plant is started after it, which on a loaded machine (make test's workers on two cores)
#: took more than the default 10 s once; how soon a vehicle is found is not what these flights test
AFTER_THE_FUZZ = ("--heartbeat-timeout", "60")


def fuzz_the_offboard(ctx, *, sysid_choices: tuple[int, ...] = (1, 2, 200, 245, 255)) -> None:  # noqa: ANN001
    """FUZZ_FRAMES frames of every kind at the offboard of a flight (``helpers.flights.fly``'s
    context), while it waits for its vehicle (during the flight they would be a flood that starves
    it: that is not what is tested); valid frames from ``sysid_choices`` (the vehicle's 1 among
    them by default: forged, as far as an unsigned offboard can tell)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        fuzz = Fuzzer(14, sysid_choices=sysid_choices).datagrams(FUZZ_FRAMES)
        for start in range(0, len(fuzz), 200):
            for datagram in fuzz[start:start + 200]:
                sock.sendto(datagram, ("127.0.0.1", ctx.offboard_port))
            time.sleep(0.05)  # paced: the kernel's buffer holds a few hundred, the offboard parses ~40 000 frames/s
    finally:
        sock.close()
