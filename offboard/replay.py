"""Flight logs read back: a MAVLink telemetry log (tlog) into a ``FlightRecord`` and a report.

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

Everything after reading is pure: ``LogScan`` collects, message by message, the series and
statistics a report needs, and ``build_record`` turns them into the aligned ``FlightRecord``
that ``offboard.metrics`` and ``offboard.plots`` take.

``mavutil.mavlogfile`` is what ``mavutil.mavlink_connection(path)`` returns for a tlog; it is
called directly because ``mavlink_connection`` guesses from the path (a name with ``/bin/`` in
it is *executed*, ``.bin`` is read as DataFlash, ``host:port`` opens a socket).
"""

from __future__ import annotations

import math
import re
import struct
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from offboard import codec
from offboard.errors import LogFormatError, ParameterFileError
from offboard.record import COLUMNS, FlightRecord, FlightStatus
from offboard.trajectory.base import Phase, Trajectory
from offboard.controller.params import ControllerParams
from offboard.model.rotations import euler_from_quat

MAX_TIMESTAMP_JUMP_US = 3 * 24 * 3600 * 1_000_000  # pymavlink's bound for a plausible tlog stamp
_STAMP = struct.Struct(">Q")
_MARKERS = re.compile(b"[\xfd\xfe]")  # MAVLink 2 and MAVLink 1 start-of-packet
_SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED
ULOG_MAGIC = b"ULog"
DATAFLASH_MAGIC = b"\xa3\x95"

# MAVLink enum values used below (common.xml)
MAV_AUTOPILOT_INVALID = mavlink.MAV_AUTOPILOT_INVALID
MAV_TYPE_GCS = mavlink.MAV_TYPE_GCS
MAV_TYPE_ONBOARD_CONTROLLER = mavlink.MAV_TYPE_ONBOARD_CONTROLLER
MAV_SEVERITY_CRITICAL = mavlink.MAV_SEVERITY_CRITICAL
MAV_CMD_COMPONENT_ARM_DISARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
SEVERITY_NAMES = ("EMERGENCY", "ALERT", "CRITICAL", "ERROR", "WARNING", "NOTICE", "INFO", "DEBUG")
OFFBOARD_MODE_NAME = codec.px4_mode_name(codec.PX4_MAIN_MODE_OFFBOARD, 0)

# POSITION_TARGET_LOCAL_NED type_mask bits: position x, y, z ignored; yaw ignored
_POS_IGNORE = 0b111
_YAW_IGNORE = 1 << 10


# --- reading --------------------------------------------------------------------------------------


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
        return None if self.resumed_at is None else self.resumed_at - self.offset


@dataclass(frozen=True)
class LoggedMessage:
    """One record of a tlog: its timestamp (Unix seconds), byte offset and pymavlink message."""

    time_s: float
    offset: int
    msg: object


def px4_mode_name(custom_mode: int) -> str:
    """PX4's name of a HEARTBEAT custom_mode (``main << 16 | sub << 24``), by ``offboard.codec``."""
    return codec.px4_mode_name((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


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


# --- what a log holds: one pass, accumulated -------------------------------------------------------


@dataclass
class SeqCounter:
    """Packet loss of one source from its sequence numbers.

    A log may hold several interleaved counters of one (system, component): a plant logging
    both of its links, a ground station merging two radios. A packet continues the counter it
    follows exactly; else, if a counter carried its very sequence number among its last 64
    packets, it is a repeat (a resent keepalive, a late copy); else it continues, after a gap
    counted as lost, the closest counter active in the last 512 packets (within half the
    sequence space); else it starts a new counter. Counters silent for 1024 packets are
    forgotten.
    """

    received: int = 0
    lost: int = 0
    duplicates: int = 0
    counters_seen: int = 0
    _counters: list[_Counter] = field(default_factory=list)

    RECENT = 64
    ACTIVE = 512
    FORGET = 1024

    @property
    def streams(self) -> int:
        return self.counters_seen

    def add(self, seq: int) -> None:
        index = self.received
        self.received += 1
        live = [c for c in self._counters if index - c.index <= self.FORGET]
        if len(live) != len(self._counters):
            self._counters = live
        for c in live:
            if (seq - c.seq - 1) % 256 == 0:
                c.advance(seq, index)
                return
        for c in live:
            if seq in c.recent:
                self.duplicates += 1
                return
        best, best_gap = None, 128
        for c in live:
            gap = (seq - c.seq - 1) % 256
            if gap < best_gap and index - c.index <= self.ACTIVE:
                best, best_gap = c, gap
        if best is None:
            counter = _Counter(seq, index)
            counter.recent.append(seq)
            self._counters.append(counter)
            self.counters_seen += 1
            return
        self.lost += best_gap
        best.advance(seq, index)


@dataclass
class _Counter:
    seq: int
    index: int
    recent: deque = field(default_factory=lambda: deque(maxlen=SeqCounter.RECENT))

    def advance(self, seq: int, index: int) -> None:
        self.seq, self.index = seq, index
        self.recent.append(seq)


@dataclass
class StreamStats:
    """Count, span and largest gap of one message type from one source (tlog time)."""

    count: int = 0
    first_s: float = math.nan
    last_s: float = math.nan
    max_gap_s: float = 0.0
    max_gap_at_s: float = math.nan  # when the largest gap began (tlog time)

    def add(self, t_s: float) -> None:
        if self.count:
            gap = t_s - self.last_s
            if gap > self.max_gap_s:
                self.max_gap_s, self.max_gap_at_s = gap, self.last_s
        else:
            self.first_s = t_s
        self.count += 1
        self.last_s = t_s

    @property
    def rate_hz(self) -> float:
        span = self.last_s - self.first_s
        return (self.count - 1) / span if self.count > 1 and span > 0 else math.nan


@dataclass(frozen=True)
class Event:
    """Something that happened at a time: a mode change, arming, a failsafe, a STATUSTEXT."""

    time_s: float  # tlog time, Unix seconds
    kind: str  # "mode", "armed", "disarmed", "status", "failsafe", "text"
    text: str
    system: int = 0


@dataclass
class LogScan:
    """Everything a report needs from a log, collected message by message (pure).

    Series are kept per source system as plain tuples of numbers, not as pymavlink objects,
    so a long log costs little memory.
    """

    first_time_s: float = math.nan
    last_time_s: float = math.nan
    messages: int = 0
    unknown_messages: int = 0
    streams: dict[tuple[int, int, str], StreamStats] = field(default_factory=dict)
    seq: dict[tuple[int, int], SeqCounter] = field(default_factory=dict)
    heartbeat_kind: dict[tuple[int, int], tuple[int, int]] = field(default_factory=dict)  # (type, autopilot)
    attitude: dict[int, list[tuple]] = field(default_factory=dict)  # sysid -> (tb_ms, roll, pitch, yaw, p, q, r, t_s, n)
    local_position: dict[int, list[tuple]] = field(default_factory=dict)  # sysid -> (tb_ms, x, y, z, vx, vy, vz, t_s, n)
    attitude_targets: dict[int, list[tuple]] = field(default_factory=dict)  # vehicle -> (tb_ms, q0..q3, thrust, t_s)
    position_targets: dict[int, list[tuple]] = field(default_factory=dict)  # vehicle -> (tb_ms, x, y, z, yaw, t_s)
    set_attitude: dict[int, list[tuple]] = field(default_factory=dict)  # target -> (tb_ms, mask, q0..q3, p, q, r, thrust, src, t_s, n)
    set_actuator: dict[int, list[tuple]] = field(default_factory=dict)  # target -> (tb_ms, c0..c3, src, t_s, n)
    commands: list[tuple] = field(default_factory=list)  # (n, t_s, src, target system, command, param1)
    acks: list[tuple] = field(default_factory=list)  # (n, t_s, src, target system, command, result)
    params: dict[int, dict[str, float]] = field(default_factory=dict)  # sysid -> name -> last value
    home_positions: dict[int, list[tuple]] = field(default_factory=dict)  # sysid -> (n, lat deg, lon deg, alt m, x, y, z)
    events: list[Event] = field(default_factory=list)
    _status: dict[int, codec.VehicleStatus] = field(default_factory=dict)  # sysid -> latest heartbeat
    _text_chunks: dict[tuple[int, int], list[str]] = field(default_factory=dict)

    def add(self, t_s: float, msg: object) -> None:
        """Take one message (pymavlink object) logged at tlog time ``t_s``."""
        kind = msg.get_type()
        if self.messages == 0:
            self.first_time_s = t_s
        self.messages += 1
        self.last_time_s = t_s
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        seq = msg.get_seq()
        if kind.startswith("UNKNOWN"):
            # another dialect's message (PX4 sends LINK_NODE_STATUS, CURRENT_MODE ...): pymavlink
            # leaves its header 0/0, seq 0; it is the sender's, and uses one of its sequence numbers
            self.unknown_messages += 1
            seq, src = codec.frame_header(msg)[0], codec.frame_header(msg)[1:]
        key = (src[0], src[1], kind)
        stream = self.streams.get(key)
        if stream is None:
            stream = self.streams[key] = StreamStats()
        stream.add(t_s)
        counter = self.seq.get(src)
        if counter is None:
            counter = self.seq[src] = SeqCounter()
        counter.add(seq)
        handler = _HANDLERS.get(kind)
        if handler is not None:
            handler(self, t_s, src, msg)

    # -- handlers, one per message type of interest --

    def _heartbeat(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.heartbeat_kind.setdefault(src, (int(msg.type), int(msg.autopilot)))
        if not codec.is_autopilot_heartbeat(msg):
            return
        status = codec.vehicle_status(msg)
        before = self._status.get(src[0])
        self._status[src[0]] = status
        mode = status.mode_name if status.custom_mode_enabled else f"base_mode {int(msg.base_mode)}"
        if before is None or (before.main_mode, before.sub_mode, before.custom_mode_enabled) != (
            status.main_mode, status.sub_mode, status.custom_mode_enabled
        ):
            self.events.append(Event(t_s, "mode", mode, src[0]))
        if before is None and status.armed or before is not None and before.armed != status.armed:
            text = "armed" if status.armed else "disarmed"
            self.events.append(Event(t_s, text, text, src[0]))
        if status.critical and (before is None or not before.critical):
            label = "EMERGENCY" if status.system_status == mavlink.MAV_STATE_EMERGENCY else "CRITICAL"
            self.events.append(Event(t_s, "failsafe", f"system status {label}", src[0]))

    def _statustext(self, t_s: float, src: tuple[int, int], msg) -> None:
        raw = msg.text
        text = raw.split("\x00", 1)[0] if isinstance(raw, str) else bytes(raw).split(b"\x00", 1)[0].decode("utf-8", "replace")
        chunk_id = int(getattr(msg, "id", 0) or 0)
        if chunk_id:  # MAVLink 2 long text: chunks share an id; the last is shorter than 50 bytes
            parts = self._text_chunks.setdefault((src[0], chunk_id), [])
            parts.append(text)
            if len(text) >= 50:
                return
            text = "".join(self._text_chunks.pop((src[0], chunk_id)))
        severity = int(msg.severity)
        label = SEVERITY_NAMES[severity] if 0 <= severity < len(SEVERITY_NAMES) else str(severity)
        # PX4 sends its refusals of a command ("Arming denied: ...", "Disarming denied: not landed")
        # as CRITICAL too: a refused command is not the vehicle failing safe
        failsafe = "failsafe" in text.lower() or (severity <= MAV_SEVERITY_CRITICAL and "denied" not in text.lower())
        self.events.append(Event(t_s, "failsafe" if failsafe else "text", f"[{label}] {text}", src[0]))

    def _attitude(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.attitude.setdefault(src[0], []).append(
            (int(msg.time_boot_ms), msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed, t_s, self.messages)
        )

    def _local_position(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.local_position.setdefault(src[0], []).append(
            (int(msg.time_boot_ms), msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, t_s, self.messages)
        )

    def _attitude_target(self, t_s: float, src: tuple[int, int], msg) -> None:
        q = msg.q
        self.attitude_targets.setdefault(src[0], []).append((int(msg.time_boot_ms), q[0], q[1], q[2], q[3], msg.thrust, t_s))

    def _position_target(self, t_s: float, src: tuple[int, int], msg) -> None:
        mask = int(msg.type_mask)
        nan = math.nan
        pos = (nan, nan, nan) if mask & _POS_IGNORE else (msg.x, msg.y, msg.z)
        if not any(math.isfinite(p) for p in pos):
            return  # no position targeted (PX4 and the plant send NaN while attitude is flown): no reference
        yaw = nan if mask & _YAW_IGNORE else msg.yaw
        self.position_targets.setdefault(src[0], []).append((int(msg.time_boot_ms), *pos, yaw, t_s))

    def _set_attitude_target(self, t_s: float, src: tuple[int, int], msg) -> None:
        q = msg.q
        self.set_attitude.setdefault(int(msg.target_system), []).append((
            int(msg.time_boot_ms), int(msg.type_mask), q[0], q[1], q[2], q[3],
            msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate, msg.thrust, src, t_s, self.messages,
        ))  # fmt: skip

    def _set_actuator_target(self, t_s: float, src: tuple[int, int], msg) -> None:
        if int(msg.group_mlx) != 0:
            return
        c = msg.controls
        tb_ms = int(msg.time_usec) // 1000
        self.set_actuator.setdefault(int(msg.target_system), []).append((tb_ms, c[0], c[1], c[2], c[3], src, t_s, self.messages))

    def _command(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.commands.append((self.messages, t_s, src, int(msg.target_system), int(msg.command), float(msg.param1)))

    def _command_ack(self, t_s: float, src: tuple[int, int], msg) -> None:
        target = int(getattr(msg, "target_system", 0) or 0)
        self.acks.append((self.messages, t_s, src, target, int(msg.command), int(msg.result)))

    def _home_position(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.home_positions.setdefault(src[0], []).append(
            (self.messages, msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0, float(msg.x), float(msg.y), float(msg.z))
        )  # as offboard.flight reads it

    def _param_value(self, t_s: float, src: tuple[int, int], msg) -> None:
        name, value = codec.param_value(msg)  # PX4 sends integers as their bytes in the float
        self.params.setdefault(src[0], {})[name] = value

    # -- questions about the whole log --

    def vehicle_sysid(self) -> int | None:
        """The vehicle: the system with an autopilot heartbeat and the most ATTITUDE messages."""
        autopilots = {s for (s, _), (kind, ap) in self.heartbeat_kind.items()
                      if ap != MAV_AUTOPILOT_INVALID and kind not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER)}  # fmt: skip
        candidates = [s for s in self.attitude if s in self.local_position]
        if not candidates:
            return None
        return max(candidates, key=lambda s: (s in autopilots, len(self.attitude[s])))

    def role(self, src: tuple[int, int]) -> str:
        kind = self.heartbeat_kind.get(src)
        if kind is None:
            return "no heartbeat"
        return {MAV_TYPE_GCS: "ground station", MAV_TYPE_ONBOARD_CONTROLLER: "onboard controller"}.get(
            kind[0], "vehicle" if kind[1] != MAV_AUTOPILOT_INVALID else f"MAV_TYPE {kind[0]}")


_HANDLERS: dict[str, Callable[[LogScan, float, tuple[int, int], object], None]] = {
    "HEARTBEAT": LogScan._heartbeat,
    "STATUSTEXT": LogScan._statustext,
    "ATTITUDE": LogScan._attitude,
    "LOCAL_POSITION_NED": LogScan._local_position,
    "ATTITUDE_TARGET": LogScan._attitude_target,
    "POSITION_TARGET_LOCAL_NED": LogScan._position_target,
    "SET_ATTITUDE_TARGET": LogScan._set_attitude_target,
    "SET_ACTUATOR_CONTROL_TARGET": LogScan._set_actuator_target,
    "PARAM_VALUE": LogScan._param_value,
    "HOME_POSITION": LogScan._home_position,
    "COMMAND_LONG": LogScan._command,
    "COMMAND_INT": LogScan._command,
    "COMMAND_ACK": LogScan._command_ack,
}


def scan_log(reader: TlogReader) -> LogScan:
    """Read a whole log into a ``LogScan``."""
    scan = LogScan()
    for logged in reader:
        scan.add(logged.time_s, logged.msg)
    return scan


# --- the aligned series ------------------------------------------------------------------------------


@dataclass(frozen=True)
class SetpointSeries:
    """The commands sent to the vehicle, one row per sample (``time_boot_ms`` echoes telemetry).

    ``kind`` is ``"attitude"`` (SET_ATTITUDE_TARGET), ``"actuator"`` (SET_ACTUATOR_CONTROL_TARGET),
    ``"attitude_target"`` (the vehicle's own ATTITUDE_TARGET report, for logs without the
    commands) or ``""`` (none). ``values`` columns: attitude: type_mask, q0..q3, p, q, r, thrust;
    actuator: c0..c3; attitude_target: q0..q3, thrust. ``source`` is the sender (system,
    component), (0, 0) for the vehicle's own report.
    """

    kind: str
    time_boot_ms: np.ndarray
    time_s: np.ndarray  # tlog time
    values: np.ndarray
    source: tuple[int, int] = (0, 0)
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # message number in the log

    def __len__(self) -> int:
        return len(self.time_boot_ms)


def _unique_by_time(rows: list[tuple]) -> list[tuple]:
    """First row of each ``time_boot_ms`` (a plant logs each telemetry message once per link),
    in time order."""
    seen: set[int] = set()
    out = []
    for row in rows:
        if row[0] not in seen:
            seen.add(row[0])
            out.append(row)
    out.sort(key=lambda r: r[0])
    return out


def _mission_window(scan: LogScan, sysid: int) -> tuple[float, float]:
    """Message numbers bounding the mission: the accepted arm of ``sysid`` (else the start) and
    the first MAV_CMD_NAV_LAND after it (else the end)."""
    arm = arm_accepted(scan, sysid)
    first = arm[0] if arm is not None else -math.inf
    lands = [c[0] for c in scan.commands if c[4] == mavlink.MAV_CMD_NAV_LAND and c[0] > first and c[3] in (sysid, 0)]
    return first, (min(lands) if lands else math.inf)


def setpoints_for(scan: LogScan, sysid: int) -> SetpointSeries:
    """The command stream to vehicle ``sysid`` (targeted at it or broadcast), the longer of the
    attitude and actuator streams; else the vehicle's ATTITUDE_TARGET reports."""
    att = scan.set_attitude.get(sysid, []) + scan.set_attitude.get(0, [])
    act = scan.set_actuator.get(sysid, []) + scan.set_actuator.get(0, [])
    if att or act:
        # the stream of the mission: between the accepted arm and the landing command, since an
        # actuator flight keeps a level attitude target going while the vehicle lands, which in a
        # long landing (PX4's: slower near the ground, ~3 s to detect it) outnumbers its setpoints
        first, last = _mission_window(scan, sysid)
        n_att = sum(1 for r in att if first < r[-1] < last)
        n_act = sum(1 for r in act if first < r[-1] < last)
        rows, kind, width = (att, "attitude", 9) if n_att >= n_act else (act, "actuator", 4)
        sources: dict[tuple[int, int], int] = {}
        for row in rows:
            sources[row[-3]] = sources.get(row[-3], 0) + 1
        source = max(sources, key=sources.__getitem__)  # the controller (others: a GCS, a test)
        rows = _unique_by_time([r for r in rows if r[-3] == source])
        return SetpointSeries(
            kind,
            np.array([r[0] for r in rows], dtype=np.int64),
            np.array([r[-2] for r in rows]),
            np.array([r[1 : 1 + width] for r in rows], dtype=float).reshape(-1, width),
            source,
            np.array([r[-1] for r in rows], dtype=np.int64),
        )
    rows = _unique_by_time(scan.attitude_targets.get(sysid, []))
    if rows:
        return SetpointSeries(
            "attitude_target",
            np.array([r[0] for r in rows], dtype=np.int64),
            np.array([r[-1] for r in rows]),
            np.array([r[1:6] for r in rows], dtype=float),
        )
    return SetpointSeries("", np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 0)))


def arm_accepted(scan: LogScan, sysid: int) -> tuple[int, float] | None:
    """(message number, tlog time) of the first accepted arm of vehicle ``sysid``: the
    COMMAND_ACK (ACCEPTED) of a MAV_CMD_COMPONENT_ARM_DISARM with param1 = 1 sent to it."""
    asked: set[tuple[int, int]] = set()  # who asked to arm
    for command in scan.commands:
        if command[3] in (sysid, 0) and command[4] == MAV_CMD_COMPONENT_ARM_DISARM and command[5] == 1.0:
            asked.add(command[2])
    for n, t_s, src, target, cmd, result in scan.acks:
        if src[0] == sysid and cmd == MAV_CMD_COMPONENT_ARM_DISARM and result == 0 and any(a[0] == target for a in asked):
            return n, t_s
    return None


def logged_mission_offset(scan: LogScan, sysid: int, mission_home: tuple[float, float, float]) -> tuple[float, float, float] | None:
    """Where a geo-referenced mission's origin lay in vehicle ``sysid``'s local frame (NED, m),
    from the vehicle's HOME_POSITION in the log, as ``offboard fly`` places it before arming.

    The HOME_POSITION used is the last one logged before the accepted arm (the flight aligns the
    mission before it streams and arms; PX4 may move its home when it arms), else the first.
    None when the log holds no HOME_POSITION from the vehicle.
    """
    from offboard.missions.geo import mission_offset_ned

    homes = scan.home_positions.get(sysid)
    if not homes:
        return None
    arm = arm_accepted(scan, sysid)
    before = [h for h in homes if arm is not None and h[0] < arm[0]]
    _n, lat, lon, alt, x, y, z = before[-1] if before else homes[0]
    return mission_offset_ned(mission_home, (lat, lon, alt), (x, y, z))


def _latest(times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Index of the latest ``times`` entry at or before each of ``at`` (-1: none yet)."""
    return np.searchsorted(times, at, side="right") - 1


def offboard_start_s(scan: LogScan, sysid: int) -> float | None:
    """tlog time at which the vehicle first entered OFFBOARD, if it did."""
    for event in scan.events:
        if event.system == sysid and event.kind == "mode" and event.text == OFFBOARD_MODE_NAME:
            return event.time_s
    return None


def mode_phases(scan: LogScan, sysid: int, t0_s: float) -> list[Phase]:
    """The vehicle's flight modes as report phases, times relative to ``t0_s`` (tlog time)."""
    changes = [(e.time_s - t0_s, e.text) for e in scan.events if e.system == sysid and e.kind == "mode"]
    end = scan.last_time_s - t0_s
    phases: list[Phase] = []
    counts: dict[str, int] = {}
    for k, (start, name) in enumerate(changes):
        stop = changes[k + 1][0] if k + 1 < len(changes) else end + 1e-9
        counts[name] = counts.get(name, 0) + 1
        label = name if counts[name] == 1 else f"{name} {counts[name]}"
        if stop > max(start, 0.0):
            phases.append(Phase(label, max(start, 0.0), stop))
    return phases


@dataclass(frozen=True)
class Scaling:
    """The vehicle's published scaling of normalised setpoints (``SIM_THR_MAX`` etc.), or NaN."""

    thrust_max_n: float = math.nan
    torque_roll_pitch_max_nm: float = math.nan
    torque_yaw_max_nm: float = math.nan

    @classmethod
    def from_params(cls, params: dict[str, float]) -> Scaling:
        return cls(
            params.get("SIM_THR_MAX", math.nan),
            params.get("SIM_TQ_RP_MAX", math.nan),
            params.get("SIM_TQ_Y_MAX", math.nan),
        )


def sample_numbers(elapsed_s: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Sample numbers n of commands logged ``elapsed_s`` after the first, one command a sample.

    ``rint(elapsed / To)``, exact in lockstep. In real time a command goes out late now and then
    (the scheduler's jitter, a busy machine): one more than half a period late rounds onto the
    next sample's number, which then appears twice while its own number is "missing". Two
    commands never share a sample, so a collision is undone by moving the earlier one back to a
    free number (it was late), else the later one on (it was early); a real gap (no command for
    whole periods, a telemetry outage) keeps its numbers.
    """
    n = np.rint(np.asarray(elapsed_s, dtype=float) / sample_time_s).astype(np.int64)
    for k in range(len(n) - 1):
        if n[k + 1] != n[k]:
            continue
        if k == 0 and n[k] > 0 or k > 0 and n[k - 1] < n[k] - 1:
            n[k] -= 1
        elif k + 2 >= len(n) or n[k + 2] > n[k + 1] + 1:
            n[k + 1] += 1
    return n


def _mission_rows(scan: LogScan, vehicle: int, setpoints: SetpointSeries, sample_time_s: float | None,
                  duration_s: float | None) -> tuple[np.ndarray, np.ndarray, float]:
    """(rows of ``setpoints`` flown as the mission, their sample numbers n, To).

    The mission starts with the first command sent after the vehicle accepted the arm command
    (``offboard fly`` starts mission time there), or, without one in the log, with the first
    command once the vehicle reports OFFBOARD. n counts sample periods from there
    (``sample_numbers``: tlog time / To, exact in lockstep, the tick count in real time). It ends after
    ``duration_s`` (the mission's), or when the controller sends its next command (land,
    mode) or the vehicle leaves OFFBOARD.
    """
    count = len(setpoints)
    arm = arm_accepted(scan, vehicle)
    start = 0
    if arm is not None:
        start = int(np.searchsorted(setpoints.index, arm[0], side="right"))
        if setpoints.kind == "attitude":
            # A plant's log may hold, after the ack, the last pre-mission setpoint the controller
            # sent before it read the ack: the vehicle's own attitude, zero rates, zero thrust.
            for _ in range(3):
                if start < count and not np.any(setpoints.values[start, 5:9]):
                    start += 1
    else:
        entered = offboard_start_s(scan, vehicle)
        if entered is not None:
            start = int(np.searchsorted(setpoints.time_s, entered, side="left"))
    if start >= count:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), sample_time_s or math.nan
    if sample_time_s is None:
        # the mean command period (whole milliseconds): exact in lockstep, robust to real-time jitter
        span = setpoints.time_s[-1] - setpoints.time_s[start]
        sample_time_s = round(1000.0 * span / (count - start - 1)) / 1000.0 if count - start > 1 else math.nan
        if not sample_time_s > 0:
            sample_time_s = 0.05
    n = sample_numbers(setpoints.time_s[start:] - setpoints.time_s[start], sample_time_s)
    rows = np.arange(start, count)
    if duration_s is not None:
        keep = n <= int(round(duration_s / sample_time_s))
    else:
        stop_index = np.iinfo(np.int64).max
        for idx, _t, src, target, _cmd, _p1 in scan.commands:
            if src == setpoints.source and target in (vehicle, 0) and idx > setpoints.index[start]:
                stop_index = idx
                break
        keep = setpoints.index[start:] < stop_index
        left = [e.time_s for e in scan.events if e.system == vehicle and e.kind == "mode" and e.time_s > setpoints.time_s[start]
                and e.text != OFFBOARD_MODE_NAME]
        if left:
            keep &= setpoints.time_s[start:] < left[0]
    return rows[keep], n[keep], sample_time_s


def build_record(
    scan: LogScan,
    *,
    sysid: int | None = None,
    trajectory: Trajectory | None = None,
    sample_time_s: float | None = None,
    scaling: Scaling | None = None,
    source: str = "",
) -> FlightRecord:
    """The aligned series of a log: one row per control sample.

    With the commands of a controller in the log (SET_ATTITUDE_TARGET or
    SET_ACTUATOR_CONTROL_TARGET), the rows are the mission's samples (``_mission_rows``), at
    ``t_s = n To`` as ``offboard fly`` counts them; the state of a row is the ATTITUDE and
    LOCAL_POSITION_NED its command answered (same ``time_boot_ms``; else the latest before).
    Without commands (a log from another system) the rows are every LOCAL_POSITION_NED, with the
    latest ATTITUDE, ``t_s`` from the first. References: the mission ``trajectory`` when given,
    else the vehicle's POSITION_TARGET_LOCAL_NED; the attitude reference and thrust are the
    commands' (q -> x7ez, x9ez, yaw; ``thrust * SIM_THR_MAX``), or the vehicle's ATTITUDE_TARGET.
    Columns a log cannot fill are NaN (torques and tau_tilde of attitude commands: ``rerun``
    recomputes them).

    Raises
    ------
    LogFormatError
        No system in the log reports both ATTITUDE and LOCAL_POSITION_NED.
    """
    vehicle = scan.vehicle_sysid() if sysid is None else sysid
    if vehicle is None or vehicle not in scan.attitude or vehicle not in scan.local_position:
        who = "any system" if sysid is None else f"system {sysid}"
        raise LogFormatError(f"{source or 'the log'}: no ATTITUDE and LOCAL_POSITION_NED from {who}; nothing to replay")
    scaling = Scaling.from_params(scan.params.get(vehicle, {})) if scaling is None else scaling
    setpoints = setpoints_for(scan, vehicle)
    commanded = setpoints.kind in ("attitude", "actuator")
    duration = trajectory.duration_s if trajectory is not None else None
    if commanded:
        rows, n_samples, to = _mission_rows(scan, vehicle, setpoints, sample_time_s, duration)
        grid = setpoints.time_boot_ms[rows]
        t_s = n_samples * to
        log_time = setpoints.time_s[rows]
    else:
        rows = np.zeros(0, dtype=np.int64)
        pos = np.array(_unique_by_time(scan.local_position[vehicle]), dtype=float)
        grid = pos[:, 0].astype(np.int64)
        t_s = (grid - grid[0]) / 1000.0
        log_time = pos[:, 7]
        if duration is not None:
            keep = t_s <= duration + 1e-9
            grid, t_s, log_time = grid[keep], t_s[keep], log_time[keep]
        to = sample_time_s if sample_time_s is not None else math.nan
    i_att, i_pos, att, pos = _telemetry_rows(scan, vehicle, grid, setpoints.index[rows] if commanded else None)
    keep = (i_att >= 0) & (i_pos >= 0)
    grid, t_s, log_time, i_att, i_pos = grid[keep], t_s[keep], log_time[keep], i_att[keep], i_pos[keep]
    if commanded:
        rows = rows[keep]
    n = len(grid)
    nan3 = np.full((n, 3), np.nan)
    columns: dict[str, np.ndarray] = {
        "t_s": np.asarray(t_s, dtype=float),
        "pos_ned_m": pos[i_pos, 1:4],
        "vel_ned_m_s": pos[i_pos, 4:7],
        "euler_rad": att[i_att, 1:4],
        "ref_pos_ned_m": nan3.copy(),
        "ref_yaw_rad": np.full(n, np.nan),
        "ref_euler_rad": nan3.copy(),
        "thrust_n": np.full(n, np.nan),
        "torques_nm": nan3.copy(),
        "tau_tilde": nan3.copy(),
    }
    reference_source = "none"
    if trajectory is not None:
        reference_source = "mission"
        for k, t in enumerate(columns["t_s"]):
            ref = trajectory.reference(float(t))
            columns["ref_pos_ned_m"][k] = ref.pos_ned_m
            columns["ref_yaw_rad"][k] = ref.yaw_rad
    elif scan.position_targets.get(vehicle):
        targets = np.array(_unique_by_time(scan.position_targets[vehicle]), dtype=float)
        j = _latest(targets[:, 0], grid)
        ok = j >= 0
        if ok.any():  # targets the vehicle flew during the samples (not only after them, e.g. landing)
            reference_source = "POSITION_TARGET_LOCAL_NED"
            columns["ref_pos_ned_m"][ok] = targets[j[ok], 1:4]
            columns["ref_yaw_rad"][ok] = targets[j[ok], 4]

    if len(setpoints) and n:
        j = rows if commanded else _latest(setpoints.time_boot_ms, grid)
        ok = j >= 0
        v = setpoints.values[j[ok]]
        if setpoints.kind in ("attitude", "attitude_target"):
            q = v[:, 1:5] if setpoints.kind == "attitude" else v[:, 0:4]
            thrust = v[:, 8] if setpoints.kind == "attitude" else v[:, 4]
            mask = v[:, 0].astype(int) if setpoints.kind == "attitude" else np.zeros(len(v), dtype=int)
            euler = np.array([euler_from_quat(row) for row in q]).reshape(-1, 3)
            euler[(mask & 128) != 0] = np.nan  # attitude ignored
            columns["ref_euler_rad"][ok] = euler
            columns["thrust_n"][ok] = np.where((mask & 64) != 0, np.nan, thrust * scaling.thrust_max_n)
        else:
            columns["thrust_n"][ok] = v[:, 3] * scaling.thrust_max_n
            columns["torques_nm"][ok] = v[:, 0:3] * np.array(
                [scaling.torque_roll_pitch_max_nm, scaling.torque_roll_pitch_max_nm, scaling.torque_yaw_max_nm]
            )

    t0_log = float(log_time[0] - columns["t_s"][0]) if n else scan.first_time_s
    phases = trajectory.phases() if trajectory is not None else mode_phases(scan, vehicle, t0_log)
    status, detail = FlightStatus.COMPLETE, ""
    end_log = float(log_time[-1]) if n else scan.last_time_s
    failsafes = [e for e in scan.events if e.kind == "failsafe" and e.system == vehicle and e.time_s <= end_log + 1.0]
    if failsafes:
        status, detail = FlightStatus.FAILSAFE, f"at t = {failsafes[0].time_s - t0_log:.2f} s: {failsafes[0].text}"
    return FlightRecord(
        columns={name: columns[name] for name in COLUMNS},
        phases=phases,
        status=status,
        status_detail=detail,
        meta={
            "source": source,
            "vehicle_sysid": vehicle,
            "commands": setpoints.kind or "none",
            "commands_from": list(setpoints.source) if commanded else None,
            "references": reference_source,
            "sample_time_s": to,
            "start_log_time_s": t0_log,
            "thrust_max_n": scaling.thrust_max_n,
            "setpoint_rows": rows,  # rows of setpoints_for(scan, vehicle) behind each sample
            "time_boot_ms": grid,
        },
    )


# --- the report on the log itself -----------------------------------------------------------------


@dataclass(frozen=True)
class SourceStats:
    """Packets of one (system, component) and their loss from sequence numbers."""

    system: int
    component: int
    role: str
    received: int
    lost: int
    duplicates: int
    counters: int  # interleaved sequence counters (a plant logging two links has 2)

    @property
    def loss_percent(self) -> float:
        total = self.received + self.lost
        return 100.0 * self.lost / total if total else 0.0


@dataclass(frozen=True)
class MessageRate:
    """One message type from one source: count, mean rate and the largest gap (tlog time)."""

    system: int
    component: int
    message: str
    count: int
    rate_hz: float
    max_gap_s: float
    max_gap_at_s: float  # relative to the record's t = 0


@dataclass(frozen=True)
class LogReport:
    """What the log says about the link and the vehicle, beside the tracking figures."""

    path: str
    size_bytes: int
    messages: int
    unknown_messages: int
    start_unix_s: float
    duration_s: float
    damages: list[Damage]
    sources: list[SourceStats]
    rates: list[MessageRate]
    events: list[Event]  # times relative to the record's t = 0
    vehicle_sysid: int | None

    def to_dict(self) -> dict:
        return {
            "path": self.path,
            "size_bytes": self.size_bytes,
            "messages": self.messages,
            "unknown_messages": self.unknown_messages,
            "start_unix_s": self.start_unix_s,
            "duration_s": self.duration_s,
            "vehicle_sysid": self.vehicle_sysid,
            "damages": [{"offset": d.offset, "resumed_at": d.resumed_at, "reason": d.reason} for d in self.damages],
            "sources": [dict(vars(s), loss_percent=s.loss_percent) for s in self.sources],
            "rates": [vars(r) for r in self.rates],
            "events": [vars(e) for e in self.events],
        }


def log_report(reader: TlogReader, scan: LogScan, t0_log_s: float) -> LogReport:
    """Statistics and events of a scanned log; times relative to ``t0_log_s`` (tlog time)."""
    vehicle = scan.vehicle_sysid()
    sources = [
        SourceStats(s, c, scan.role((s, c)), k.received, k.lost, k.duplicates, k.streams)
        for (s, c), k in sorted(scan.seq.items())
    ]
    rates = [
        MessageRate(s, c, m, st.count, st.rate_hz, st.max_gap_s, st.max_gap_at_s - t0_log_s)
        for (s, c, m), st in sorted(scan.streams.items())
    ]
    events = [Event(e.time_s - t0_log_s, e.kind, e.text, e.system) for e in scan.events]
    return LogReport(
        path=str(reader.path),
        size_bytes=reader.size_bytes,
        messages=scan.messages,
        unknown_messages=scan.unknown_messages,
        start_unix_s=scan.first_time_s,
        duration_s=scan.last_time_s - scan.first_time_s if scan.messages else 0.0,
        damages=list(reader.damages),
        sources=sources,
        rates=rates,
        events=events,
        vehicle_sysid=vehicle,
    )


def format_log_report(report: LogReport, all_rates: bool = False) -> str:
    """Plain-text tables: sources and loss, message rates and gaps, events."""
    lines = [f"log {report.path}: {report.size_bytes} bytes, {report.messages} messages"
             + (f" ({report.unknown_messages} of unknown type)" if report.unknown_messages else "")
             + f", {report.duration_s:.2f} s, vehicle system {report.vehicle_sysid}"]
    for d in report.damages:
        resumed = "nothing readable after it" if d.resumed_at is None else f"resumed at byte {d.resumed_at}"
        lines.append(f"  damaged at byte {d.offset}: {d.reason}; {resumed}")
    lines.append("")
    lines.append(f"{'source':<10} {'role':<20} {'received':>9} {'lost':>7} {'loss %':>7} {'dup':>5} {'counters':>8}")
    for s in report.sources:
        lines.append(f"{s.system:>3}/{s.component:<6} {s.role:<20} {s.received:>9} {s.lost:>7} {s.loss_percent:>7.2f} "
                     f"{s.duplicates:>5} {s.counters:>8}")
    lines.append("")
    lines.append(f"{'source':<10} {'message':<30} {'count':>7} {'rate Hz':>8} {'max gap s':>10} {'at t s':>8}")
    shown = report.rates if all_rates else [r for r in report.rates if r.count > 1]
    for r in shown:
        lines.append(f"{r.system:>3}/{r.component:<6} {r.message:<30} {r.count:>7} {r.rate_hz:>8.2f} "
                     f"{r.max_gap_s:>10.3f} {r.max_gap_at_s:>8.2f}")
    if report.events:
        lines.append("")
        lines.append("events (t s, system):")
        for e in report.events:
            lines.append(f"  {e.time_s:9.2f}  {e.system:>3}  {e.kind:<9} {e.text}")
    return "\n".join(lines)


# --- streaming a log again ---------------------------------------------------------------------------


def stream_log(
    messages: Iterator[LoggedMessage],
    send: Callable[[bytes], None],
    *,
    speed: float = 1.0,
    systems: set[int] | None = None,
    clock: Callable[[], float] | None = None,
    sleep: Callable[[float], None] | None = None,
) -> int:
    """Re-send logged messages in their original timing (``speed`` times faster).

    Only the messages of ``systems`` (default: all) are sent, each once: a plant logs every
    telemetry message once per link, so a message identical to one already sent at the same
    tlog time by the same source is skipped. Packets are re-packed with one sequence counter
    per source, as a single live link would carry them. Unknown message types are passed on
    unchanged.

    Returns
    -------
    int
        Messages sent.
    """
    import time

    clock = time.monotonic if clock is None else clock
    sleep = time.sleep if sleep is None else sleep
    packers: dict[tuple[int, int], object] = {}
    sent_now: set[tuple[int, int, int, bytes]] = set()
    now_stamp = math.nan
    t_first = math.nan
    wall_first = 0.0
    count = 0
    for logged in messages:
        msg = logged.msg
        kind = msg.get_type()
        if kind == "BAD_DATA":
            continue
        src = codec.frame_header(msg)[1:] if kind.startswith("UNKNOWN") else (msg.get_srcSystem(), msg.get_srcComponent())
        if systems is not None and src[0] not in systems:
            continue
        if logged.time_s != now_stamp:
            now_stamp = logged.time_s
            sent_now.clear()
        payload = bytes(msg.get_payload()) if hasattr(msg, "get_payload") and msg.get_payload() is not None else b""
        key = (src[0], src[1], msg.get_msgId(), payload)
        if key in sent_now:
            continue
        sent_now.add(key)
        if math.isnan(t_first):
            t_first, wall_first = logged.time_s, clock()
        due = wall_first + (logged.time_s - t_first) / speed
        wait = due - clock()
        if wait > 0:
            sleep(wait)
        if kind.startswith("UNKNOWN"):
            send(bytes(msg.get_msgbuf()))
        else:
            packer = packers.get(src)
            if packer is None:
                packer = packers[src] = mavutil.mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
            send(bytes(msg.pack(packer)))
            packer.seq = (packer.seq + 1) % 256
        count += 1
    return count


# --- re-running the controller on the recorded telemetry ---------------------------------------------

#: The setpoint fields compared, per output kind (message units).
RERUN_FIELDS = {
    "attitude": ("q_w", "q_x", "q_y", "q_z", "roll_rate_rad_s", "pitch_rate_rad_s", "yaw_rate_rad_s", "thrust_norm"),
    "actuator": ("roll_torque_norm", "pitch_torque_norm", "yaw_torque_norm", "thrust_norm"),
}


@dataclass(frozen=True)
class RerunResult:
    """The controller fed the recorded telemetry sample by sample, against the logged commands.

    Attributes
    ----------
    output : str
        ``attitude`` or ``actuator``: the commands compared.
    fields : tuple of str
        Names of the compared message fields (``RERUN_FIELDS``).
    logged, rerun : ndarray (samples, fields)
        The logged fields, and the re-run's as the message would carry them (float32).
    record : FlightRecord
        The re-run as a flight record: the logged state and the re-run's law outputs (u, the
        angle references, eq. 16 torques, tau_tilde), as ``offboard fly`` records a flight.
    gaps : int
        Missing samples in the log (the controller in flight stepped on them; the re-run cannot).
    """

    output: str
    fields: tuple[str, ...]
    t_s: np.ndarray
    logged: np.ndarray
    rerun: np.ndarray
    record: FlightRecord
    gaps: int

    @property
    def difference(self) -> np.ndarray:
        return np.abs(self.rerun.astype(np.float64) - self.logged.astype(np.float64))

    @property
    def max_difference(self) -> dict[str, float]:
        d = self.difference
        return {name: float(np.max(d[:, i])) if len(d) else 0.0 for i, name in enumerate(self.fields)}

    @property
    def mismatched_samples(self) -> int:
        return int(np.count_nonzero(np.any(self.rerun != self.logged, axis=1)))

    @property
    def exact(self) -> bool:
        """Every compared field equal to the logged one after float32 rounding."""
        return len(self.t_s) > 0 and self.mismatched_samples == 0

    def first_mismatch(self) -> tuple[float, str, float, float] | None:
        """(t_s, field, logged, re-run) of the first difference, or None."""
        rows = np.nonzero(np.any(self.rerun != self.logged, axis=1))[0]
        if not len(rows):
            return None
        k = int(rows[0])
        i = int(np.argmax(self.rerun[k] != self.logged[k]))
        return float(self.t_s[k]), self.fields[i], float(self.logged[k, i]), float(self.rerun[k, i])

    def to_dict(self) -> dict:
        first = self.first_mismatch()
        return {
            "output": self.output,
            "samples": int(len(self.t_s)),
            "exact": self.exact,
            "mismatched_samples": self.mismatched_samples,
            "max_difference": self.max_difference,
            "first_mismatch": None if first is None else dict(zip(("t_s", "field", "logged", "rerun"), first)),
            "missing_samples": self.gaps,
        }


def _telemetry_rows(scan: LogScan, vehicle: int, time_boot_ms: np.ndarray, before: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the ATTITUDE and LOCAL_POSITION_NED behind each sample (-1: none yet), and
    the two tables (``LogScan`` row layout) they index.

    With ``before`` (the message numbers of the commands) a sample's telemetry is the latest
    finite ATTITUDE and LOCAL_POSITION_NED logged before its command: what the controller had
    handled when it sampled (``offboard fly`` logs a message as it handles it), exact in real
    time too; this is used when those ATTITUDEs carry the ``time_boot_ms`` the commands echo
    (the controller's own log). Otherwise, the latest at or before ``time_boot_ms``.
    """
    def table(rows: list[tuple], dedupe: bool) -> np.ndarray:
        arr = np.array(_unique_by_time(rows) if dedupe else rows, dtype=float).reshape(-1, 9)
        return arr[np.all(np.isfinite(arr[:, 1:7]), axis=1)]

    if before is not None:
        att = table(scan.attitude[vehicle], False)
        pos = table(scan.local_position[vehicle], False)
        i_att = np.searchsorted(att[:, 8], before, side="left") - 1
        echoed = (i_att >= 0) & (att[np.maximum(i_att, 0), 0] == time_boot_ms)
        if len(echoed) and np.mean(echoed) >= 0.99:
            # offboard fly samples the attitude of the position's own instant when it has it
            # (``Flight._sample``): an ATTITUDE newer than the position may be logged before the
            # command that answered an older one; the command's echo names which it was
            for j in np.flatnonzero(~echoed & (i_att >= 0)):
                for k in range(int(i_att[j]) - 1, max(int(i_att[j]) - codec.RECENT_ATTITUDES, -1), -1):
                    if att[k, 0] == time_boot_ms[j]:
                        i_att[j] = k
                        break
            return i_att, np.searchsorted(pos[:, 8], before, side="left") - 1, att, pos  # type: ignore[return-value]
        # not the controller's own log (a plant's, in real time: telemetry newer than what the
        # command answered is logged before it): the command's echo of time_boot_ms decides
    att = table(scan.attitude[vehicle], True)
    pos = table(scan.local_position[vehicle], True)
    return _latest(att[:, 0], time_boot_ms), _latest(pos[:, 0], time_boot_ms), att, pos  # type: ignore[return-value]


class _Msg:
    """A telemetry message rebuilt from a scanned row, with the fields the codec reads."""

    def __init__(self, **fields: float) -> None:
        self.__dict__.update(fields)


def rerun_controller(
    scan: LogScan,
    record: FlightRecord,
    params: ControllerParams,
    trajectory: Trajectory,
    scaling: codec.Scaling,
    model: str = "rigid-body",
    encoding: str | None = None,
    kind: str = "paper",
) -> RerunResult:
    """Feed the controller the telemetry of ``record``'s samples, as ``offboard fly`` did.

    ``encoding``: the ``offboard fly --output`` that was flown when the message alone does not say
    (``rates`` travels in SET_ATTITUDE_TARGET like ``attitude``); None: the message's kind.

    Each sample: the ATTITUDE and LOCAL_POSITION_NED the logged command answered become the
    controller's state by ``offboard.codec.measured_state``, the references are the mission's at
    ``t`` and ``t + To``, the controller (``offboard.controllers.make_controller``, as ``offboard
    fly`` builds it) steps, and its command becomes the message fields by
    ``codec.command_setpoint`` (the encoding ``offboard fly`` sends) and ``codec.setpoint_fields``,
    rounded to float32 as the message carries them.

    Parameters
    ----------
    scan : LogScan
    record : FlightRecord
        From ``build_record`` on the same scan, with the mission's trajectory.
    params : ControllerParams
        The controller to run (the flight's, or another to compare).
    trajectory : Trajectory
    scaling : offboard.codec.Scaling
        The vehicle's scaling the commands were normalised by.
    model : str
        ``rigid-body`` or ``paper`` (the attitude and torque forms).
    kind : str
        Which controller flew (``paper``, ``se3``, ``px4``).
    """
    from offboard.controllers import make_controller
    from offboard.record import RecordBuilder, control_row

    output = record.meta.get("commands")
    if output not in RERUN_FIELDS:
        raise LogFormatError(f"{record.meta.get('source') or 'the log'}: no controller commands to compare with "
                             "(SET_ATTITUDE_TARGET or SET_ACTUATOR_CONTROL_TARGET)")
    vehicle = int(record.meta["vehicle_sysid"])  # type: ignore[arg-type]
    setpoints = setpoints_for(scan, vehicle)
    rows = np.asarray(record.meta["setpoint_rows"], dtype=np.int64)
    grid = np.asarray(record.meta["time_boot_ms"], dtype=np.int64)
    i_att, i_pos, att_table, pos_table = _telemetry_rows(scan, vehicle, grid, setpoints.index[rows])
    att, pos = att_table[i_att], pos_table[i_pos]
    to = params.sample_time_s
    controller = make_controller(kind, params, vehicle_model=model)
    t_all = record["t_s"]
    builder = RecordBuilder()
    logged = setpoints.values[rows]
    logged = logged[:, 1:9] if output == "attitude" else logged[:, 0:4]
    rerun = np.full(logged.shape, np.nan, dtype=np.float32)
    for k in range(len(rows)):
        a, p = att[k], pos[k]
        measured = codec.measured_state(
            _Msg(time_boot_ms=int(a[0]), roll=a[1], pitch=a[2], yaw=a[3], rollspeed=a[4], pitchspeed=a[5], yawspeed=a[6]),
            _Msg(time_boot_ms=int(p[0]), x=p[1], y=p[2], z=p[3], vx=p[4], vy=p[5], vz=p[6]),
        )
        t = float(t_all[k])
        ref_n, ref_n1 = trajectory.reference(t), trajectory.reference(t + to)
        command = controller.step(measured, ref_n, ref_n1)
        builder.append(**control_row(t, measured, ref_n, command))
        if not command.is_finite():
            continue
        sp = codec.command_setpoint(command, scaling, output=encoding or output, model=model, controller=controller.name)
        rerun[k] = np.array(codec.setpoint_fields(sp), dtype=np.float32)
    steps = np.diff(np.rint(t_all / to).astype(np.int64)) if len(t_all) > 1 else np.zeros(0, dtype=np.int64)
    gaps = int(np.sum(np.maximum(steps - 1, 0)))
    rerun_record = builder.build(phases=record.phases, meta={**record.meta, "rerun": True})
    return RerunResult(encoding or output, RERUN_FIELDS[output], np.asarray(t_all, dtype=float), logged.astype(np.float32), rerun,
                       rerun_record, gaps)  # fmt: skip


def format_rerun(result: RerunResult, label: str) -> str:
    """The comparison table: per field, logged and re-run ranges, largest and RMS difference."""
    d = result.difference
    if not len(d):
        return f"re-run ({label}): no mission samples in the log to compare"
    lines = [f"re-run ({label}): {len(result.t_s)} samples of {result.output} commands; "
             + ("outputs equal the log exactly (to float32)" if result.exact
                else f"{result.mismatched_samples} samples differ")]
    if result.gaps:
        lines.append(f"  note: {result.gaps} samples are missing from the log; the re-run's memory differs after them")
    lines.append(f"  {'field':<18} {'logged min':>11} {'logged max':>11} {'re-run min':>11} {'re-run max':>11} {'max |diff|':>11} {'rms diff':>10}")
    for i, name in enumerate(result.fields):
        lo, ro = result.logged[:, i].astype(float), result.rerun[:, i].astype(float)
        rms = float(np.sqrt(np.nanmean(d[:, i] ** 2))) if len(d) else 0.0
        lines.append(f"  {name:<18} {np.nanmin(lo):>11.5g} {np.nanmax(lo):>11.5g} {np.nanmin(ro):>11.5g} {np.nanmax(ro):>11.5g} "
                     f"{np.nanmax(d[:, i]):>11.3g} {rms:>10.3g}")
    first = result.first_mismatch()
    if first is not None:
        lines.append(f"  first difference at t = {first[0]:.2f} s in {first[1]}: logged {first[2]:.7g}, re-run {first[3]:.7g}")
    return "\n".join(lines)


def flight_controller(
    vehicle_params: dict[str, float],
    scaling: object,
    *,
    model: str = "rigid-body",
    output: str = "attitude",
    controller_file: Path | None = None,
    summary: dict | None = None,
) -> tuple[object, str]:
    """The controller to re-run, and where it came from (docs/replay.md).

    - ``controller_file`` given: that file as ``offboard fly --controller FILE`` would fly it on
      this vehicle (``offboard.flight.resolve_controller``: the file's mass and inertia, thrust
      bounded by the vehicle, its tilt limit or 35 degrees);
    - else the flight's own ``summary.json`` (``summary``): the controller file it names
      (``controller_file``; null or absent: the paper's file believing the vehicle's SIM_*
      values) resolved as ``offboard fly`` resolved it, then overridden by the resolved
      controller the summary records, field by field (older summaries lack some fields);
    - else ``offboard fly``'s default: the paper's file believing the vehicle's SIM_* values,
      read back from the PARAM_VALUE messages in the log, with (attitude output on a rigid body)
      the gains designed for the vehicle's inner loop from the same parameters.

    Returns
    -------
    (ControllerParams, str)
    """
    from offboard.controller import PAPER_CONTROLLER_FILE, ActionLimits, ControllerGains, load_controller
    from offboard.flight import ControllerChoice, resolve_controller

    if controller_file is not None:
        choice = ControllerChoice(base=load_controller(controller_file), from_file=True)
        return resolve_controller(choice, model, vehicle_params, scaling)[0], f"{controller_file} (as offboard fly --controller flies it)"
    recorded = (summary or {}).get("controller")
    flown_file = (summary or {}).get("controller_file")
    flown_choice = (summary or {}).get("controller_choice")
    # offboard fly's default designs the gains where the design applies (offboard.commands.fly)
    default_tuned = model == "rigid-body" and output == "attitude"
    tuned = flown_choice == "tuned" or (flown_choice is None and default_tuned and not isinstance(recorded, dict))
    choice = ControllerChoice(base=load_controller(PAPER_CONTROLLER_FILE), tuned=tuned)
    file_note = f"{PAPER_CONTROLLER_FILE.name} believing the vehicle's SIM_* values" + (", gains designed for it" if choice.tuned else "")
    if isinstance(flown_file, str) and flown_file:
        if Path(flown_file).is_file():
            choice = ControllerChoice(base=load_controller(flown_file), from_file=True)
            file_note = f"controller file {flown_file}"
        elif isinstance(recorded, dict):
            file_note = f"controller file {flown_file} no longer there: the values summary.json records"
        else:
            raise ParameterFileError(f"summary.json: the flight's controller file {flown_file} no longer exists and the "
                                     "summary records no controller; pass --controller FILE (a copy of it)")
    params = resolve_controller(choice, model, vehicle_params, scaling)[0]
    if not isinstance(recorded, dict):
        if summary is not None and "controller_file" in summary:
            return params, f"the flight's ({file_note}, named in summary.json)"
        return params, f"offboard fly's default ({PAPER_CONTROLLER_FILE.name}, the vehicle's SIM_* values from the log)"
    changes: dict[str, object] = {}
    for key in ("sample_time_s", "mass_kg", "arm_length_m", "gravity_m_s2", "euler_rate_form", "drag_to_thrust_m", "yaw_aware",
                "integral_gain_per_s", "integral_limit_m_s", "velocity_integral_gain_per_s2", "velocity_integral_limit_m_s2",
                "tilt_lead", "linear_drag_n_s_m"):  # fmt: skip
        if key in recorded and recorded[key] is not None:
            changes[key] = recorded[key]
    if "inertia_kg_m2" in recorded:
        changes["inertia_kg_m2"] = tuple(float(v) for v in recorded["inertia_kg_m2"])
    if "reference_lead_s2" in recorded:
        changes["reference_lead_s2"] = tuple(float(v) for v in recorded["reference_lead_s2"])
    if isinstance(recorded.get("gains"), dict):
        changes["gains"] = ControllerGains(**{k: float(v) for k, v in recorded["gains"].items()})
    if any(k in recorded for k in ("thrust_min_n", "thrust_max_n", "tilt_max_deg")):
        tilt = recorded.get("tilt_max_deg")
        changes["limits"] = ActionLimits(
            thrust_min_n=recorded.get("thrust_min_n"),
            thrust_max_n=recorded.get("thrust_max_n"),
            tilt_max_rad=None if tilt is None else math.radians(float(tilt)),
            tilt_cone=bool(recorded.get("tilt_cone", False)),
            speed_xy_max_m_s=recorded.get("speed_xy_max_m_s"),
            speed_up_max_m_s=recorded.get("speed_up_max_m_s"),
            speed_down_max_m_s=recorded.get("speed_down_max_m_s"),
            yaw_rate_max_rad_s=recorded.get("yaw_rate_max_rad_s"),
        )
    return params.with_changes(**changes), f"the flight's (summary.json beside the log; {file_note})"  # type: ignore[attr-defined]


def rerun_panels(result: RerunResult, thrust_max_n: float) -> list[tuple[str, np.ndarray, np.ndarray, tuple[str, ...]]]:
    """The comparison figure's panels in physical units (``offboard.plots.comparison_figure``)."""
    def euler_deg(values: np.ndarray) -> np.ndarray:
        return np.degrees(np.array([euler_from_quat(q) for q in values[:, 0:4]]).reshape(-1, 3))

    scale = thrust_max_n if math.isfinite(thrust_max_n) else 1.0
    thrust_label = "u [N]" if math.isfinite(thrust_max_n) else "thrust (normalised)"
    logged, rerun = result.logged.astype(float), result.rerun.astype(float)
    if result.output in ("attitude", "rates"):  # both SET_ATTITUDE_TARGET
        a, b = euler_deg(logged), euler_deg(rerun)
        return [
            ("x7ez roll ref [deg]", a[:, 0], b[:, 0], ("roll",)),
            ("x9ez pitch ref [deg]", a[:, 1], b[:, 1], ("pitch",)),
            ("yaw ref [deg]", a[:, 2], b[:, 2], ("yaw",)),
            ("body rate refs [rad/s]", logged[:, 4:7], rerun[:, 4:7], ("p", "q", "r")),
            (thrust_label, logged[:, 7] * scale, rerun[:, 7] * scale, ("u",)),
        ]
    return [
        ("torques (normalised)", logged[:, 0:3], rerun[:, 0:3], ("roll", "pitch", "yaw")),
        (thrust_label, logged[:, 3] * scale, rerun[:, 3] * scale, ("u",)),
    ]
