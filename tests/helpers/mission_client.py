"""A ground station's side of the MAVLink mission protocol, in pymavlink, for the tests.

The same code talks to the real PX4 and to the plant (tests/e2e/test_px4_parity_mission.py), so
what it records (the exchange, the items read back, the ACK results and opaque ids) can be held
side by side. It is written from the protocol's description (mavlink.io "Mission Protocol"), as a
ground station such as QGroundControl or MAVSDK runs it: upload MISSION_COUNT ->
MISSION_REQUEST_INT* -> MISSION_ITEM_INT* -> MISSION_ACK; download MISSION_REQUEST_LIST ->
MISSION_COUNT -> MISSION_REQUEST_INT* -> MISSION_ITEM_INT* -> MISSION_ACK; clear
MISSION_CLEAR_ALL -> MISSION_ACK.
"""

from __future__ import annotations

import math
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil

from offboard.missions.plan import read_plan
from offboard.missions.wpl import looks_like_wpl, read_wpl

MAV = mavutil.mavlink
GCS_SYSID, GCS_COMPID = 255, 190  # QGroundControl's identity


@dataclass(frozen=True)
class Item:
    """One MISSION_ITEM_INT's content (x, y as sent: degE7 for global frames)."""

    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float
    autocontinue: int = 1

    def key(self) -> tuple:
        """For comparisons: NaN equals NaN, floats at float32 precision."""
        def f(v: float) -> object:
            return "nan" if math.isnan(v) else round(float(v), 4)

        return (self.frame, self.command, tuple(f(p) for p in self.params), self.x, self.y, f(self.z), self.autocontinue)


def items_from_file(path: str | Path) -> list[Item]:
    """A .waypoints or .plan file's items (without the home item 0), as a ground station sends
    them: global frames become their _INT twins with degE7 coordinates."""
    path = Path(path)
    mission = read_wpl(path) if looks_like_wpl(path) else read_plan(path)
    out = []
    for it in mission.items:
        frame = {MAV.MAV_FRAME_GLOBAL: MAV.MAV_FRAME_GLOBAL_INT, MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT: MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}.get(it.frame, it.frame)
        is_global = frame in (MAV.MAV_FRAME_GLOBAL_INT, MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
        x = int(round(it.x * 1e7)) if is_global else int(round(it.x))
        y = int(round(it.y * 1e7)) if is_global else int(round(it.y))
        out.append(Item(frame, it.command, tuple(float(p) for p in it.params), x, y, float(it.z), int(it.autocontinue)))  # type: ignore[arg-type]
    return out


@dataclass
class Exchange:
    """What one transfer saw: (message type, seq or result) in order, and the outcome."""

    def steps(self) -> list[tuple[str, int]]:
        """The exchange without repeats (retries and answers to them), in first-seen order."""
        out: list[tuple[str, int]] = []
        for step in self.log:
            if step not in out:
                out.append(step)
        return out

    log: list[tuple[str, int]] = field(default_factory=list)
    ack: int | None = None
    opaque_id: int | None = None
    items: list[Item] = field(default_factory=list)
    count: int | None = None


class MissionClient:
    """Talks the mission protocol to one vehicle over a pymavlink connection."""

    def __init__(self, conn: mavutil.mavfile, target_system: int, target_component: int = 1, timeout_s: float = 5.0) -> None:
        self.conn = conn
        self.ts, self.tc = target_system, target_component
        self.timeout_s = timeout_s
        self.seen: list = []  # everything mission-related received while waiting (MISSION_CURRENT, REACHED)

    def _recv(self, types: tuple[str, ...], timeout_s: float | None = None):
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind in ("MISSION_CURRENT", "MISSION_ITEM_REACHED", "STATUSTEXT"):
                self.seen.append(msg)
            if kind in types and getattr(msg, "target_system", GCS_SYSID) in (GCS_SYSID, 0):
                return msg
        return None

    def upload(self, items: list[Item], mission_type: int = 0) -> Exchange:
        """Upload ``items``, answering every request (repeats too, as PX4 repeats unanswered ones)."""
        ex = Exchange()
        self.conn.mav.mission_count_send(self.ts, self.tc, len(items), mission_type)
        ex.log.append(("MISSION_COUNT", len(items)))
        while True:
            msg = self._recv(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"))
            if msg is None:
                ex.log.append(("TIMEOUT", -1))
                return ex
            kind = msg.get_type()
            if kind == "MISSION_ACK":
                ex.log.append(("MISSION_ACK", msg.type))
                ex.ack, ex.opaque_id = msg.type, getattr(msg, "opaque_id", None)
                return ex
            ex.log.append((kind, msg.seq))
            it = items[msg.seq]
            self.conn.mav.mission_item_int_send(self.ts, self.tc, msg.seq, it.frame, it.command, 0, it.autocontinue,
                                                *it.params, it.x, it.y, it.z, mission_type)  # fmt: skip
            ex.log.append(("MISSION_ITEM_INT", msg.seq))

    def download(self, mission_type: int = 0) -> Exchange:
        ex = Exchange()
        self.conn.mav.mission_request_list_send(self.ts, self.tc, mission_type)
        ex.log.append(("MISSION_REQUEST_LIST", mission_type))
        msg = self._recv(("MISSION_COUNT",))
        if msg is None:
            ex.log.append(("TIMEOUT", -1))
            return ex
        ex.count, ex.opaque_id = msg.count, getattr(msg, "opaque_id", None)
        ex.log.append(("MISSION_COUNT", msg.count))
        for seq in range(msg.count):
            got = None
            for _ in range(3):  # a lost answer is asked for again, as ground stations do
                self.conn.mav.mission_request_int_send(self.ts, self.tc, seq, mission_type)
                ex.log.append(("MISSION_REQUEST_INT", seq))
                got = self._recv(("MISSION_ITEM_INT",), 1.5)
                if got is not None and got.seq == seq:
                    break
            if got is None:
                ex.log.append(("TIMEOUT", seq))
                return ex
            ex.log.append(("MISSION_ITEM_INT", got.seq))
            ex.items.append(Item(got.frame, got.command, (got.param1, got.param2, got.param3, got.param4), got.x, got.y, got.z, got.autocontinue))
        self.conn.mav.mission_ack_send(self.ts, self.tc, MAV.MAV_MISSION_ACCEPTED, mission_type)
        ex.log.append(("MISSION_ACK", 0))
        return ex

    def clear(self, mission_type: int = 0) -> Exchange:
        ex = Exchange()
        self.conn.mav.mission_clear_all_send(self.ts, self.tc, mission_type)
        ex.log.append(("MISSION_CLEAR_ALL", mission_type))
        msg = self._recv(("MISSION_ACK",))
        if msg is None:
            ex.log.append(("TIMEOUT", -1))
            return ex
        ex.ack, ex.opaque_id = msg.type, getattr(msg, "opaque_id", None)
        ex.log.append(("MISSION_ACK", msg.type))
        return ex


# --- flying a mission: the same client for PX4 and the plant -------------------------------------


@dataclass
class Flight:
    """What a mission flight showed: the items reached (MISSION_ITEM_REACHED, distinct, in order),
    the MISSION_CURRENT seqs seen, the modes (main, sub) and arming seen, and the positions
    (time_boot_ms, north, east, down) of LOCAL_POSITION_NED."""

    reached: list[int] = field(default_factory=list)
    reached_at_ms: dict[int, int] = field(default_factory=dict)
    current: list[int] = field(default_factory=list)
    modes: list[tuple[tuple[int, int], bool]] = field(default_factory=list)
    track: list[tuple[int, float, float, float]] = field(default_factory=list)
    acks: dict[int, int] = field(default_factory=dict)
    disarmed_at_ms: int | None = None
    #: the vehicle's STATUSTEXTs (severity, text): what a failure's message shows (a failsafe names itself)
    texts: list[tuple[int, str]] = field(default_factory=list)

    def note(self, msg) -> None:
        kind = msg.get_type()
        if kind == "STATUSTEXT":
            self.texts.append((msg.severity, msg.text))
        elif kind == "LOCAL_POSITION_NED":
            self.track.append((msg.time_boot_ms, msg.x, msg.y, msg.z))
        elif kind == "MISSION_ITEM_REACHED":
            if not self.reached or self.reached[-1] != msg.seq:
                self.reached.append(msg.seq)
                self.reached_at_ms[msg.seq] = self.track[-1][0] if self.track else 0
        elif kind == "MISSION_CURRENT":
            if not self.current or self.current[-1] != msg.seq:
                self.current.append(msg.seq)
        elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
            mode = ((msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF)
            entry = (mode, bool(msg.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED))
            if not self.modes or self.modes[-1] != entry:
                self.modes.append(entry)
                if not entry[1] and len(self.modes) > 1 and self.track:
                    self.disarmed_at_ms = self.track[-1][0]
        elif kind == "COMMAND_ACK":
            self.acks[msg.command] = msg.result


def command(conn, target_system: int, number: int, *params: float, flight: Flight | None = None, timeout_s: float = 3.0) -> int | None:
    """COMMAND_LONG, repeated (confirmation 0, 1, 2) until its COMMAND_ACK arrives: the result."""
    p = list(params) + [math.nan] * (7 - len(params))
    for confirmation in range(3):
        conn.mav.command_long_send(target_system, 1, number, confirmation, *p)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = conn.recv_match(blocking=True, timeout=0.1)
            if msg is None:
                continue
            if flight is not None:
                flight.note(msg)
            if msg.get_type() == "COMMAND_ACK" and msg.command == number:
                return msg.result
    return None


def fly_mission(conn, target_system: int, timeout_s: float, *, until_landed: bool = True) -> Flight:
    """Arm, switch to Mission mode (DO_SET_MODE 4/4, as MAVSDK's start_mission) and record until
    the vehicle disarms after landing (or ``timeout_s`` of wall time)."""
    flight = Flight()
    assert command(conn, target_system, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1, flight=flight) == 0, "arming refused"
    assert command(conn, target_system, MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4, flight=flight) == 0
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(blocking=True, timeout=0.1)
        if msg is None:
            continue
        flight.note(msg)
        if until_landed and flight.disarmed_at_ms is not None:
            deadline = min(deadline, time.monotonic() + 1.0)  # the last MISSION_ITEM_REACHED's repeats
    return flight


#: Streams a mission client does not read: switched off (SET_MESSAGE_INTERVAL -1) to spare the
#: loopback and the client's parsing on a loaded machine (ATTITUDE, ATTITUDE_QUATERNION,
#: HIGHRES_IMU, ATTITUDE_TARGET, SERVO_OUTPUT_RAW, VFR_HUD, GPS_RAW_INT).
UNREAD_STREAMS = (30, 31, 105, 83, 36, 74, 24)


def quiet_streams(conn, target_system: int) -> None:
    for message_id in UNREAD_STREAMS:
        command(conn, target_system, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, -1, timeout_s=1.0)


def start_plant(*args: str) -> tuple[mavutil.mavfile, "subprocess.Popen"]:
    """``python -m sitl_plant.cli`` on OS-chosen loopback ports talking to a fresh pymavlink
    client (udpin on port 0): the client's connection (its first HEARTBEAT received) and the process."""
    import subprocess
    import sys

    from helpers import REPO

    conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=GCS_SYSID, source_component=GCS_COMPID, dialect="common")
    port = conn.port.getsockname()[1]
    cmd = [sys.executable, "-m", "sitl_plant.cli", "--api-bind", "127.0.0.1:0", "--api-remote", f"127.0.0.1:{port}",
           "--gcs-bind", "none", "--quiet", *args]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if conn.wait_heartbeat(timeout=20) is None:
        proc.kill()
        raise AssertionError(f"the plant sent no heartbeat: {proc.communicate()[1]}")
    return conn, proc
