"""MAVLink 2 message signing, as the MAVLink spec and PX4 do it (pure but for the key file).

Both processes use it: ``offboard fly --signing-key FILE`` and ``sitl-plant --signing-key FILE``.

- **The key** is 32 secret bytes shared by both ends. A key file holds them alone (32 bytes) or
  in PX4's layout (``mavlink/mavlink-signing-key.bin``: the 32 bytes, then the last timestamp
  as a little-endian uint64: 40 bytes).
- **Outgoing** frames carry the 13-byte signature: link id, a 48-bit timestamp in 10 µs units
  since 2015-01-01 UTC that increases with every frame sent and never falls behind the newest
  timestamp accepted, and the first 6 bytes of SHA-256(key, header, payload, CRC, link id,
  timestamp). pymavlink's packer signs (``MAVLink.signing``); :meth:`SigningSession.stamp`
  keeps its timestamp on our clock.
- **Incoming** frames are verified by :class:`SignatureCheck` *before* any state is touched: an
  unsigned frame is refused unless its message is one PX4 accepts unsigned
  (:data:`ACCEPTED_UNSIGNED`: RADIO_STATUS, ADSB_VEHICLE, COLLISION); a bad signature is refused
  and changes nothing; a good one must carry a timestamp above the last of its stream (system,
  component, link id), and a stream not seen before must not be more than a minute behind our
  timestamp. pymavlink's own ``check_signature`` stores the stream's timestamp before it
  checks the hash, so a forged frame with a high timestamp would lock the real stream out;
  here only a verified frame moves a stream on.
- **The timestamp is persisted** in the key file (PX4's layout) when a process closes cleanly
  (:func:`persist`: the newest of all its sessions, written once), and a session never signs
  below it. The spec's one-minute window alone (PX4 keeps only that) would let frames from the
  last minute before a restart be replayed into it as new streams; here the persisted timestamp
  is also a **floor** for incoming streams: a stream not seen before must start above it
  (``SignatureCheck.floor``), so nothing recorded before a clean restart can be replayed into
  it. (A killed process persists nothing: its last run's frames stay replayable for a minute
  above the timestamp persisted before.) A peer whose clock lags the floor is refused until
  it signs above the newest timestamp it has accepted from us, as the spec asks of it. In
  lockstep the clock is the simulation's alone (a signed lockstep flight sends the same bytes
  every time) and nothing is persisted nor used as a floor: a lockstep run is a reproducible
  experiment, not a vehicle to protect.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pymavlink.dialects.v20.common import MAVLink

KEY_BYTES = 32
PX4_KEY_FILE_BYTES = 40  # the key, then the timestamp (uint64, little-endian)
#: 2015-01-01T00:00:00Z, the origin of signing timestamps (Unix seconds).
SIGNING_EPOCH_UNIX_S = 1_420_070_400
#: Timestamp units per second (10 µs).
TICKS_PER_S = 100_000
#: A new stream may start this far behind our timestamp (one minute, the spec's rule).
NEW_STREAM_WINDOW = 60 * TICKS_PER_S
SIGNATURE_BYTES = 13
MAVLINK2_STX = 0xFD
IFLAG_SIGNED = 0x01
#: Message ids PX4 accepts unsigned on a signing link (mavlink_sign_control.cpp): RADIO_STATUS,
#: ADSB_VEHICLE, COLLISION.
ACCEPTED_UNSIGNED = frozenset({109, 246, 247})
#: SETUP_SIGNING's message id.
SETUP_SIGNING_ID = 256


class SigningKeyError(ValueError):
    """A key file that cannot be read or is not a key (the message names the file)."""


def signing_timestamp(unix_us: int) -> int:
    """The signing timestamp (10 µs since 2015-01-01) of a Unix time in microseconds."""
    return max(0, (unix_us - SIGNING_EPOCH_UNIX_S * 1_000_000) // 10)


@dataclass(frozen=True)
class SigningKey:
    """A secret key and the timestamp persisted with it (0: none)."""

    secret: bytes
    timestamp: int = 0

    def __post_init__(self) -> None:
        if len(self.secret) != KEY_BYTES:
            raise SigningKeyError(f"a MAVLink signing key is {KEY_BYTES} bytes, got {len(self.secret)}")

    @property
    def disables(self) -> bool:
        """All-zero key and timestamp: SETUP_SIGNING's way of switching signing off."""
        return self.timestamp == 0 and not any(self.secret)


def load_key(path: str | Path) -> SigningKey:
    """Read a key file: 32 bytes, or PX4's 40 (key + uint64 timestamp)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise SigningKeyError(f"--signing-key {path}: is a folder, expected a key file") from None
    except OSError as exc:
        raise SigningKeyError(f"--signing-key {path}: cannot read the key: {exc.strerror}") from None
    if len(data) == KEY_BYTES:
        key = SigningKey(data)
    elif len(data) == PX4_KEY_FILE_BYTES:
        key = SigningKey(data[:KEY_BYTES], int.from_bytes(data[KEY_BYTES:], "little"))
    else:
        raise SigningKeyError(f"--signing-key {path}: {len(data)} bytes; a MAVLink signing key file holds the "
                              f"{KEY_BYTES}-byte key, or PX4's {PX4_KEY_FILE_BYTES} (the key and a timestamp)")
    if key.disables:
        raise SigningKeyError(f"--signing-key {path}: an all-zero key, which switches signing off")
    return key


def save_key(path: str | Path, key: SigningKey) -> None:
    """Write ``key`` in PX4's 40-byte layout, readable by its owner only, replacing the file whole."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, key.secret + key.timestamp.to_bytes(8, "little"))
    finally:
        os.close(fd)
    os.replace(tmp, path)


class Verdict(StrEnum):
    """What :meth:`SignatureCheck.check` decided about one frame."""

    SIGNED = "signed"  # verified: accepted
    UNSIGNED_ALLOWED = "unsigned_allowed"  # unsigned, of a message accepted unsigned
    UNSIGNED = "unsigned"  # refused
    BAD_SIGNATURE = "bad_signature"  # refused: not signed with our key (forged, corrupted)
    REPLAYED = "replayed"  # refused: a timestamp not above its stream's last
    STALE_STREAM = "stale_stream"  # refused: a new stream more than a minute behind us

    @property
    def accepted(self) -> bool:
        """Whether a frame with this verdict is handled (signed with the key, or unsigned and allowed)."""
        return self in (Verdict.SIGNED, Verdict.UNSIGNED_ALLOWED)


def is_signed(frame: bytes | bytearray) -> bool:
    """Whether ``frame`` is a MAVLink 2 frame with the signed flag."""
    return len(frame) > 2 and frame[0] == MAVLINK2_STX and bool(frame[2] & IFLAG_SIGNED)


@dataclass
class SignatureCheck:
    """Verifies incoming frames against one key (module docstring for the rules).

    ``timestamp`` is our side's newest timestamp (the local clock's, or the newest verified);
    ``floor`` the timestamp persisted before a restart, which a new stream must start above;
    ``counts`` how many frames got each verdict.
    """

    secret: bytes
    timestamp: int = 0
    floor: int = 0
    accepted_unsigned: frozenset[int] = ACCEPTED_UNSIGNED
    streams: dict[tuple[int, int, int], int] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=lambda: {v.value: 0 for v in Verdict})

    def check(self, frame: bytes | bytearray, msg_id: int, sysid: int, compid: int) -> Verdict:
        """The verdict on one incoming frame (module docstring for the rules), counted."""
        verdict = self._verdict(bytes(frame), msg_id, sysid, compid)
        self.counts[verdict.value] += 1
        return verdict

    def _verdict(self, frame: bytes, msg_id: int, sysid: int, compid: int) -> Verdict:
        if not is_signed(frame) or len(frame) < SIGNATURE_BYTES + 12:
            return Verdict.UNSIGNED_ALLOWED if msg_id in self.accepted_unsigned else Verdict.UNSIGNED
        expected = hashlib.sha256(self.secret + frame[:-6]).digest()[:6]
        if expected != frame[-6:]:
            return Verdict.BAD_SIGNATURE  # checked first: a forgery moves no stream on
        link_id = frame[-SIGNATURE_BYTES]
        timestamp = int.from_bytes(frame[-12:-6], "little")
        stream = (sysid, compid, link_id)
        last = self.streams.get(stream)
        if timestamp <= (self.floor if last is None else last):
            return Verdict.REPLAYED  # (below the floor: recorded before our restart)
        if last is None and timestamp + NEW_STREAM_WINDOW < self.timestamp:
            return Verdict.STALE_STREAM
        self.streams[stream] = timestamp
        self.timestamp = max(self.timestamp, timestamp)
        return Verdict.SIGNED

    @property
    def refused(self) -> int:
        """How many frames were refused so far."""
        return sum(n for v, n in self.counts.items() if not Verdict(v).accepted)


class SigningSession:
    """One process's signing on one link: the key, our clock, the incoming check.

    Parameters
    ----------
    key : SigningKey
    clock_us : callable
        Microseconds since the Unix epoch on our clock (the simulation's in lockstep).
    link_id : int
        Our link id in the signatures we send.
    key_path : Path or None
        Where the timestamp is persisted on :meth:`close` (None: nowhere, as in lockstep), and
        whether the key's persisted timestamp is a floor for incoming streams.
    lockstep : bool
        Sign on our clock alone. Otherwise, as the spec asks, the next timestamp is also above
        the newest one accepted from the other side, which in lockstep would make our bytes
        depend on how many wall-clock keepalive repeats the peer happened to answer.
    """

    def __init__(self, key: SigningKey, clock_us: Callable[[], int], *, link_id: int = 0,
                 key_path: str | Path | None = None, lockstep: bool = False) -> None:  # fmt: skip
        self.key = key
        self.clock_us = clock_us
        self.link_id = link_id
        self.lockstep = lockstep
        self.key_path = None if key_path is None else Path(key_path)
        start = max(key.timestamp, signing_timestamp(clock_us())) if self.key_path is not None else signing_timestamp(clock_us())
        self.check = SignatureCheck(key.secret, timestamp=start, floor=self._floor(key))
        self._sent = start  # the timestamp of the last frame we signed

    def _floor(self, key: SigningKey) -> int:
        return key.timestamp if self.key_path is not None else 0

    def now(self) -> int:
        """The timestamp to sign the next frame with: our clock's, and never at or below the last
        sent or the newest accepted."""
        self._sent = max(self._sent + 1, signing_timestamp(self.clock_us()))
        if not self.lockstep:
            self._sent = max(self._sent, self.check.timestamp)
        self.check.timestamp = max(self.check.timestamp, self._sent)
        return self._sent

    def stamp(self, packer: MAVLink) -> None:
        """Ready pymavlink's packer to sign the next frame with :meth:`now` (it signs with
        ``signing.timestamp`` and then adds one)."""
        signing = packer.signing
        signing.secret_key = self.key.secret
        signing.link_id = self.link_id
        signing.sign_outgoing = True
        signing.timestamp = self.now()

    def rekey(self, key: SigningKey) -> None:
        """A new key (SETUP_SIGNING): streams start afresh; the timestamp is the key's or ours."""
        self.key = key
        self.check = SignatureCheck(key.secret, timestamp=max(key.timestamp, self._sent), floor=self._floor(key))

    @property
    def newest(self) -> int:
        """The newest timestamp we signed or accepted."""
        return max(self._sent, self.check.timestamp)

    def close(self) -> None:
        """Persist the newest timestamp with the key (PX4's layout), if there is a key file."""
        persist([self])


def persist(sessions: Iterable[SigningSession]) -> None:
    """Write each key file of ``sessions`` once, with the newest timestamp of the sessions that
    share it (the plant's links share one file: written per session, the last closed would win,
    not the highest). Sessions without a key file persist nothing."""
    newest: dict[Path, tuple[int, bytes]] = {}
    for s in sessions:
        if s.key_path is not None:
            best = newest.get(s.key_path)
            if best is None or s.newest > best[0]:
                newest[s.key_path] = (s.newest, s.key.secret)
    for path, (timestamp, secret) in newest.items():
        save_key(path, SigningKey(secret, timestamp))
