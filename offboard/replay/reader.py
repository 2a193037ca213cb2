"""The tlog reader: a MAVLink telemetry log (tlog) read message by message, past damage.

A tlog is a sequence of records, each an 8-byte big-endian timestamp (microseconds since the
Unix epoch) followed by one MAVLink packet, as ``sitl-plant --log``, ``offboard fly --log``,
QGroundControl and MAVProxy write them. ``TlogReader`` is the one loader of this file kind: the
packets are decoded by pymavlink's own tlog reader (``mavutil.mavlogfile``), never by a parser of
ours; what we add is knowing *where* a log is damaged and carrying on after it:

- a record whose packet fails its checksum (pymavlink's ``BAD_DATA``), a timestamp more than
  three days from its predecessor (pymavlink's own plausibility bound), or bytes the parser
  cannot make a packet of, mark a **damage** at the byte offset where that record starts;
- reading resumes at the next offset holding a plausible timestamp and a packet that pymavlink
  accepts with a valid checksum; a log that ends mid-packet is read up to its last whole
  record. Each damage is reported (``Damage``); nothing raises for a damaged log;
- a file holding no MAVLink packet at all (or a ULog, a DataFlash log) is not a tlog:
  ``LogFormatError``.

``mavutil.mavlogfile`` is what ``mavutil.mavlink_connection(path)`` returns for a tlog; it is
called directly because ``mavlink_connection`` guesses from the path (a name with ``/bin/`` in
it is *executed*, ``.bin`` is read as DataFlash, ``host:port`` opens a socket).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from offboard.errors import LogFormatError
from offboard.model.messages import MAVLinkMessage

MAX_TIMESTAMP_JUMP_US = 3 * 24 * 3600 * 1_000_000  # pymavlink's bound for a plausible tlog stamp
_STAMP = struct.Struct(">Q")
_MARKERS = re.compile(b"[\xfd\xfe]")  # MAVLink 2 and MAVLink 1 start-of-packet
_SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED
ULOG_MAGIC = b"ULog"
DATAFLASH_MAGIC = b"\xa3\x95"


@dataclass(frozen=True)
class Damage:
    """A damaged span of a log.

    Attributes
    ----------
    offset : int
        Byte where the first unreadable record starts.
    resumed_at : int or None
        Byte of the next whole record read after it; None when nothing readable follows (the
        log ends mid-packet or in garbage).
    reason : str
    """

    offset: int
    resumed_at: int | None
    reason: str

    @property
    def skipped_bytes(self) -> int | None:
        """How many bytes were skipped to resume (None: the log ended there)."""
        return None if self.resumed_at is None else self.resumed_at - self.offset


@dataclass(frozen=True)
class LoggedMessage:
    """One record of a tlog: its timestamp (Unix seconds), byte offset and pymavlink message."""

    time_s: float
    offset: int
    msg: MAVLinkMessage


def _packet_length(data: bytes | memoryview, i: int) -> int | None:
    """Length of the MAVLink packet starting at ``data[i]`` from its header, or None."""
    if i + 2 > len(data):
        return None
    if data[i] == 0xFE:
        return data[i + 1] + 8
    if i + 3 > len(data):
        return None
    return data[i + 1] + 12 + (13 if data[i + 2] & _SIGNED else 0)


class TlogReader:
    """Iterate over the messages of a tlog, reading past damage (module docstring).

    Parameters
    ----------
    path : str or Path
    progress : callable(fraction) or None
        Called with the fraction of the file read, about every 1 %.

    Attributes
    ----------
    size_bytes : int
    damages : list of Damage
        Filled while iterating.
    records : int
        Whole records read (including messages of unknown type).

    Raises
    ------
    LogFormatError
        The file cannot be opened, is empty, or holds no MAVLink packet (on iteration).
    """

    def __init__(self, path: str | Path, progress: Callable[[float], None] | None = None) -> None:
        self.path = Path(path)
        self.progress = progress
        self.damages: list[Damage] = []
        self.records = 0
        try:
            self.size_bytes = self.path.stat().st_size
            with self.path.open("rb") as fh:
                head = fh.read(16)
        except OSError as exc:
            raise LogFormatError(f"{self.path}: cannot read the log: {exc.strerror}") from None
        if self.path.is_dir():
            raise LogFormatError(f"{self.path}: is a folder, expected a .tlog file")
        if self.size_bytes == 0:
            raise LogFormatError(f"{self.path}: empty file, expected a MAVLink telemetry log (.tlog)")
        if head.startswith(ULOG_MAGIC):
            raise LogFormatError(f"{self.path}: a PX4 ULog (.ulg), expected a MAVLink telemetry log (.tlog); "
                                 "convert it or record a tlog with the ground station")
        if head.startswith(DATAFLASH_MAGIC):
            raise LogFormatError(f"{self.path}: an ArduPilot DataFlash log, expected a MAVLink telemetry log (.tlog)")
        self._data: bytes | None = None  # whole file, loaded only to resynchronise after damage

    def describe_damage(self) -> str:
        """One line saying where the log is damaged ('' if it is not)."""
        if not self.damages:
            return ""
        first = self.damages[0]
        where = f"{self.path}: damaged at byte {first.offset} of {self.size_bytes} ({first.reason})"
        if len(self.damages) == 1:
            if first.resumed_at is None:
                return f"{where}; read {self.records} messages up to there, the rest ({self.size_bytes - first.offset} bytes) is lost"
            return f"{where}; skipped {first.skipped_bytes} bytes, resumed at byte {first.resumed_at}; read {self.records} messages"
        lost = sum(d.skipped_bytes if d.skipped_bytes is not None else self.size_bytes - d.offset for d in self.damages)
        return f"{where} and in {len(self.damages) - 1} more places; {lost} bytes skipped in all; read {self.records} messages"

    def _open(self) -> mavutil.mavlogfile:
        try:
            conn = mavutil.mavlogfile(str(self.path), robust_parsing=True)
        except OSError as exc:
            raise LogFormatError(f"{self.path}: cannot read the log: {exc.strerror}") from None
        # MAVLink 2 parser from the first byte on (it reads MAVLink 1 packets too); pymavlink
        # would otherwise decide from the first packet only.
        conn.auto_mavlink_version(bytes([253]))
        return conn

    def _load(self) -> bytes:
        if self._data is None:
            self._data = self.path.read_bytes()
        return self._data

    def _packet_ok(self, data: bytes, i: int) -> bool:
        """Whether a whole, known, checksum-valid MAVLink packet starts at ``data[i]``."""
        length = _packet_length(data, i)
        if length is None or i + length > len(data):
            return False
        parser = mavutil.mavlink.MAVLink(None)
        parser.robust_parsing = True
        try:
            msgs = parser.parse_buffer(data[i : i + length]) or []
        except Exception:  # noqa: BLE001 - pymavlink raises assorted errors on junk
            return False
        return len(msgs) == 1 and not msgs[0].get_type().startswith(("BAD_DATA", "UNKNOWN"))

    def _next_record(self, start: int, last_time_us: int | None) -> int | None:
        """Offset of the first plausible whole record at or after ``start``."""
        data = self._load()
        for match in _MARKERS.finditer(data, start + 8):
            i = match.start()
            p = i - 8
            (stamp,) = _STAMP.unpack_from(data, p)
            if last_time_us is not None and abs(stamp - last_time_us) > MAX_TIMESTAMP_JUMP_US:
                continue
            if self._packet_ok(data, i):
                return p
        return None

    def _initial_time_us(self, records: int = 5) -> int | None:
        """Median stamp of the first records (framed by their headers), the reference against
        which even the first record's timestamp is judged; None if they do not frame."""
        with self.path.open("rb") as fh:
            head = fh.read(records * (8 + 280))
        stamps, p = [], 0
        for _ in range(records):
            if p + 8 > len(head):
                break
            length = _packet_length(head, p + 8)
            if length is None or head[p + 8] not in (0xFD, 0xFE):
                break
            stamps.append(_STAMP.unpack_from(head, p)[0])
            p += 8 + length
        return int(np.median(stamps)) if len(stamps) >= 3 else None

    @staticmethod
    def _seek(conn: mavutil.mavlogfile, offset: int) -> None:
        """Restart pymavlink's reader at a record boundary with an empty parse buffer."""
        conn.f.seek(offset)
        mav = conn.mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavutil.mavlink.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False

    def __iter__(self) -> Iterator[LoggedMessage]:
        conn = self._open()
        size = self.size_bytes
        step = max(size // 100, 1)
        next_report = step
        last_time_us = self._initial_time_us()
        try:
            while True:
                start = conn.f.tell()
                if start >= size:
                    break
                if self.progress is not None and start >= next_report:
                    self.progress(start / size)
                    next_report = start + step
                msg = conn.recv_match()
                reason = ""
                if msg is None:
                    reason = "bytes that are not a MAVLink packet"
                elif msg.get_type() == "BAD_DATA":
                    reason = "a packet fails its checksum or is garbled"
                else:
                    stamp_us = int(round(msg._timestamp * 1e6))
                    if last_time_us is not None and abs(stamp_us - last_time_us) > MAX_TIMESTAMP_JUMP_US:
                        reason = "an implausible timestamp"
                if reason:
                    resume = self._next_record(start + 1, last_time_us)
                    if resume is None and not self.records and not self.damages:
                        raise LogFormatError(
                            f"{self.path}: not a MAVLink telemetry log (.tlog): no MAVLink packet found in {size} bytes "
                            "(a tlog is 8-byte timestamps each followed by a MAVLink packet)"
                        )
                    if resume is None and msg is None and size - start < 8 + 280:
                        # a truncated last record: say so precisely
                        self.damages.append(Damage(start, None, f"the log ends mid-packet, {size - start} bytes into its last record"))
                    else:
                        self.damages.append(Damage(start, resume, reason))
                    if resume is None:
                        break
                    self._seek(conn, resume)
                    continue
                last_time_us = stamp_us
                self.records += 1
                yield LoggedMessage(msg._timestamp, start, msg)
        finally:
            conn.close()
        if self.progress is not None:
            self.progress(1.0)
