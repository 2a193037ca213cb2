"""What a log holds, collected in one pass: ``LogScan`` takes the messages one by one (pure) and
answers questions about the whole log (the vehicle, who armed it, when it entered OFFBOARD).

Series are kept as plain tuples of numbers, not pymavlink objects, so a long log costs little
memory.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from offboard import codec
from offboard.flight.guards import heading_reset_deg, lost_estimates, missing_estimates, sensor_health_changes
from offboard.missions.geo import mission_offset_ned
from offboard.model import px4_modes
from offboard.model.messages import MAVLinkMessage
from offboard.replay.reader import TlogReader

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


def px4_mode_name(custom_mode: int) -> str:
    """PX4's name of a HEARTBEAT custom_mode (``main << 16 | sub << 24``), by ``offboard.codec``."""
    return codec.px4_mode_name(*px4_modes.main_sub(custom_mode))


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
        """How many interleaved sequence counters the source showed (class docstring)."""
        return self.counters_seen

    def add(self, seq: int) -> None:
        """One packet's sequence number (class docstring: which counter it continues)."""
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
        """One message of the stream at log time ``t_s`` (its gaps measured)."""
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
        """The mean rate over the stream's span (NaN with fewer than two messages)."""
        span = self.last_s - self.first_s
        return (self.count - 1) / span if self.count > 1 and span > 0 else math.nan


@dataclass(frozen=True)
class Event:
    """Something that happened at a time: a mode change, arming, a failsafe, a STATUSTEXT."""

    time_s: float  # tlog time, Unix seconds
    kind: str  # "mode", "armed", "disarmed", "status", "failsafe", "text", "estimator", "health"
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
    attitude_targets: dict[int, list[tuple]] = field(default_factory=dict)  # vehicle -> (tb_ms, q0..q3, thrust, n, t_s)
    position_targets: dict[int, list[tuple]] = field(default_factory=dict)  # vehicle -> (tb_ms, x, y, z, yaw, t_s)
    set_attitude: dict[int, list[tuple]] = field(default_factory=dict)  # target -> (tb_ms, mask, q0..q3, p, q, r, thrust, src, t_s, n)
    set_actuator: dict[int, list[tuple]] = field(default_factory=dict)  # target -> (tb_ms, c0..c3, src, t_s, n)
    commands: list[tuple] = field(default_factory=list)  # (n, t_s, src, target system, command, param1)
    acks: list[tuple] = field(default_factory=list)  # (n, t_s, src, target system, command, result)
    params: dict[int, dict[str, float]] = field(default_factory=dict)  # sysid -> name -> last value
    home_positions: dict[int, list[tuple]] = field(default_factory=dict)  # sysid -> (n, lat deg, lon deg, alt m, x, y, z)
    events: list[Event] = field(default_factory=list)
    _status: dict[int, codec.VehicleStatus] = field(default_factory=dict)  # sysid -> latest heartbeat
    _estimates: dict[int, tuple[str, ...]] = field(default_factory=dict)  # sysid -> what its estimator no longer vouches for
    _health: dict[int, dict[str, bool]] = field(default_factory=dict)  # sysid -> sensor -> healthy (SYS_STATUS)
    _text_chunks: dict[tuple[int, int], list[str]] = field(default_factory=dict)

    def add(self, t_s: float, msg: MAVLinkMessage) -> None:
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

    def _estimator_status(self, t_s: float, src: tuple[int, int], msg) -> None:
        """An event when the estimator stops (or starts again) vouching for what the law reads
        (``offboard.flight.guards``: what ``offboard fly`` ends ESTIMATE_LOST on)."""
        flags = int(msg.flags)
        lost = lost_estimates(flags)
        if lost != self._estimates.get(src[0], ()):
            text = missing_estimates(flags) or f"the vehicle's estimator vouches again for every estimate the law reads (ESTIMATOR_STATUS flags 0x{flags:x})"
            self.events.append(Event(t_s, "estimator", text, src[0]))
        self._estimates[src[0]] = lost

    def _sys_status(self, t_s: float, src: tuple[int, int], msg) -> None:
        """An event per sensor whose SYS_STATUS health changes (as ``offboard fly`` reports them)."""
        health, lines = sensor_health_changes(self._health.get(src[0]), int(msg.onboard_control_sensors_present),
                                              int(msg.onboard_control_sensors_enabled), int(msg.onboard_control_sensors_health))  # fmt: skip
        self._health[src[0]] = health
        self.events.extend(Event(t_s, "health", line, src[0]) for line in lines)

    def _attitude(self, t_s: float, src: tuple[int, int], msg) -> None:
        series = self.attitude.setdefault(src[0], [])
        row = (int(msg.time_boot_ms), msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed, t_s, self.messages)
        if series:
            jump = heading_reset_deg(series[-1], row)
            if jump is not None:
                self.events.append(Event(t_s, "estimator", f"heading reset by {jump:+.1f} deg (ATTITUDE's yaw jumped, its body rates "
                                         "did not turn it: the estimator re-aligned its heading)", src[0]))  # fmt: skip
        series.append(row)

    def _local_position(self, t_s: float, src: tuple[int, int], msg) -> None:
        self.local_position.setdefault(src[0], []).append(
            (int(msg.time_boot_ms), msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, t_s, self.messages)
        )

    def _attitude_target(self, t_s: float, src: tuple[int, int], msg) -> None:
        q = msg.q
        self.attitude_targets.setdefault(src[0], []).append((int(msg.time_boot_ms), q[0], q[1], q[2], q[3], msg.thrust, self.messages, t_s))

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
        """What a (system, component) is by its heartbeat: vehicle, ground station, onboard controller."""
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
    "ESTIMATOR_STATUS": LogScan._estimator_status,
    "SYS_STATUS": LogScan._sys_status,
}


def scan_log(reader: TlogReader) -> LogScan:
    """Read a whole log into a ``LogScan``."""
    scan = LogScan()
    for logged in reader:
        scan.add(logged.time_s, logged.msg)
    return scan


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
    homes = scan.home_positions.get(sysid)
    if not homes:
        return None
    arm = arm_accepted(scan, sysid)
    before = [h for h in homes if arm is not None and h[0] < arm[0]]
    _n, lat, lon, alt, x, y, z = before[-1] if before else homes[0]
    return mission_offset_ned(mission_home, (lat, lon, alt), (x, y, z))


def offboard_start_s(scan: LogScan, sysid: int) -> float | None:
    """tlog time at which the vehicle first entered OFFBOARD, if it did."""
    for event in scan.events:
        if event.system == sysid and event.kind == "mode" and event.text == OFFBOARD_MODE_NAME:
            return event.time_s
    return None

