"""The MAVLink mission protocol, as PX4 v1.16's mission manager runs it: pure, no sockets, no clock.

``MissionManager`` keeps the three stored lists (mission type 0 mission, 1 geofence, 2 rally
points) and the transfer state machine of PX4's ``src/modules/mavlink/mavlink_mission.cpp``
(``MavlinkMissionManager``). It is given the received messages (pymavlink messages, read by
attribute) and the time, and answers with ``Out`` records (the messages to send); the server
packs them. What it does, as PX4 does (measured on PX4 v1.16 SITL, docs/parity/mission.md):

- **Upload** MISSION_COUNT -> MISSION_REQUEST_INT seq 0.. -> MISSION_ITEM_INT -> MISSION_ACK
  ACCEPTED. The first transfer after boot requests with the legacy MISSION_REQUEST (PX4 starts
  in "float mode" and switches to MISSION_REQUEST_INT once a MISSION_ITEM_INT or
  MISSION_REQUEST_INT arrives). A request not answered is repeated every ``RETRY_S`` (0.25 s);
  after ``TIMEOUT_S`` (5 s) without a message the transfer is dropped with the STATUSTEXT
  "Operation timeout". An item with another seq than the one requested is ignored (the request
  is repeated). MISSION_COUNT 0 clears the list (ACK ACCEPTED); more than the list holds ->
  MAV_MISSION_NO_SPACE. An item that does not parse ends the transfer with its reason:
  MAV_MISSION_UNSUPPORTED_FRAME (frame not global, global-relative or MISSION),
  MAV_MISSION_UNSUPPORTED (a command PX4 does not store in that frame),
  MAV_MISSION_INVALID_PARAM1 (a DO_SET_ROI mode PX4 does not know), INVALID_PARAM5_X /
  PARAM6_Y (a legacy MISSION_ITEM whose latitude or longitude is NaN or off the globe: the
  plant's own guard, so that the item can be sent back), MAV_MISSION_ERROR (a
  geofence or rally command in a mission, a polygon of fewer than 3 vertices).
- **Download** MISSION_REQUEST_LIST -> MISSION_COUNT -> (MISSION_REQUEST_INT -> MISSION_ITEM_INT
  | MISSION_REQUEST -> MISSION_ITEM)* -> the client's MISSION_ACK. Items come back as PX4 stores
  them (``_stored``): the parameters PX4 keeps per command, the rest 0; geofence vertices without
  autocontinue.
- **Clear** MISSION_CLEAR_ALL (type 0, 1, 2 or 255 = all) -> MISSION_ACK ACCEPTED.
- MISSION_SET_CURRENT (and ``set_current``, for MAV_CMD_DO_SET_MISSION_CURRENT) moves the current
  item when seq is in the list, else the STATUSTEXT "WPM: WP CURR CMD: Not in list".

pymavlink's common.xml (2.4.50) has no ``opaque_id`` in MISSION_ACK / MISSION_COUNT nor the
ids in MISSION_CURRENT, so neither side of this protocol can carry them: the plant keeps a CRC32
per list only to know whether an upload changed it (PX4: the current item is then reset).
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field
from enum import Enum

from offboard.model.messages import MAVLinkMessage

# MAVLink values (common.xml), spelled out to keep the module free of pymavlink.
MAV_MISSION_TYPE_MISSION, MAV_MISSION_TYPE_FENCE, MAV_MISSION_TYPE_RALLY, MAV_MISSION_TYPE_ALL = 0, 1, 2, 255
MAV_MISSION_ACCEPTED = 0
MAV_MISSION_ERROR = 1
MAV_MISSION_UNSUPPORTED_FRAME = 2
MAV_MISSION_UNSUPPORTED = 3
MAV_MISSION_NO_SPACE = 4
MAV_MISSION_INVALID = 5
MAV_MISSION_INVALID_PARAM1 = 6
MAV_MISSION_INVALID_PARAM5_X = 10
MAV_MISSION_INVALID_PARAM6_Y = 11
MAV_MISSION_OPERATION_CANCELLED = 15

FRAME_GLOBAL, FRAME_MISSION, FRAME_GLOBAL_RELATIVE_ALT = 0, 2, 3
FRAME_GLOBAL_INT, FRAME_GLOBAL_RELATIVE_ALT_INT = 5, 6
MAV_COMP_ID_MISSIONPLANNER = 190

MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_INFO = 6

RETRY_S = 0.25  # MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT (250 ms): repeat an unanswered request
TIMEOUT_S = 5.0  # MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT (5 s): drop a silent transfer
#: Largest list per mission type (PX4's MAX_COUNT, dataman's sizes). Measured on PX4 v1.16 SITL:
#: 65535 mission items and 65 fence points are refused with NO_SPACE, 2001 items and 9 rally
#: points are accepted; the exact mission and rally limits were not probed.
MAX_COUNT = {MAV_MISSION_TYPE_MISSION: 5000, MAV_MISSION_TYPE_FENCE: 64, MAV_MISSION_TYPE_RALLY: 64}

# Commands (MAV_CMD) PX4 stores with global coordinates, and what it keeps of their parameters
# (parse_mavlink_mission_item / format_mavlink_mission_item): the kept params by index.
NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF = 16, 17, 19, 20, 21, 22
NAV_LOITER_TO_ALT, NAV_ROI, NAV_DELAY = 31, 80, 93
NAV_VTOL_TAKEOFF, NAV_VTOL_LAND = 84, 85
DO_JUMP, DO_CHANGE_SPEED, DO_SET_HOME, DO_SET_ROI, DO_LAND_START = 177, 178, 179, 201, 189
FENCE_RETURN_POINT, FENCE_POLY_INCL, FENCE_POLY_EXCL, FENCE_CIRCLE_INCL, FENCE_CIRCLE_EXCL = 5000, 5001, 5002, 5003, 5004
RALLY_POINT = 5100
FENCE_AND_RALLY = (FENCE_POLY_INCL, FENCE_POLY_EXCL, FENCE_CIRCLE_INCL, FENCE_CIRCLE_EXCL, RALLY_POINT)
_GLOBAL_KEEPS: dict[int, tuple[int, ...]] = {
    NAV_WAYPOINT: (0, 1, 3),  # hold time, acceptance radius, yaw
    NAV_LOITER_UNLIM: (2, 3),  # radius, yaw
    NAV_LOITER_TIME: (0, 1, 2, 3),  # time, heading required (0/1), radius, exit xtrack (0/1)
    NAV_LAND: (1, 3),  # precision land, yaw
    NAV_TAKEOFF: (3,),
    NAV_LOITER_TO_ALT: (0, 1, 3),
    NAV_ROI: (0,),
    DO_SET_ROI: (0,),
    195: (),  # DO_SET_ROI_LOCATION
    NAV_VTOL_TAKEOFF: (3,),
    NAV_VTOL_LAND: (3,),
    4501: (),  # CONDITION_GATE
    FENCE_RETURN_POINT: (),
    FENCE_POLY_INCL: (0,),
    FENCE_POLY_EXCL: (0,),
    FENCE_CIRCLE_INCL: (0,),
    FENCE_CIRCLE_EXCL: (0,),
    RALLY_POINT: (),
    400: (0,),  # COMPONENT_ARM_DISARM
    212: (0, 1),  # DO_AUTOTUNE_ENABLE
}
#: Commands PX4 stores in MAV_FRAME_MISSION (no coordinates), all seven params kept.
_MISSION_FRAME_COMMANDS = frozenset({
    DO_JUMP, NAV_ROI, DO_SET_ROI, 42600, 211,  # DO_WINCH, DO_GRIPPER
    DO_CHANGE_SPEED, DO_SET_HOME, DO_LAND_START, 2003, 203, 204, 205, 1000, 531, 1001,  # trigger, digicam, mount, gimbal, focus
    2000, 2001, 2500, 2501, 200, 206, 260, 214, 530, 534, 3000, NAV_DELAY, NAV_RETURN_TO_LAUNCH, 213, 197,
    112, 114, 187, 212, 400,
})  # fmt: skip


class TransferState(Enum):
    IDLE = 0
    SENDLIST = 1  # a download is going on
    GETLIST = 2  # an upload is going on


@dataclass(frozen=True)
class MissionItem:
    """One stored item, as it goes on the wire (x, y: degE7 in global frames of the INT
    messages, else the float fields' values)."""

    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float]
    x: float
    y: float
    z: float
    autocontinue: int = 1
    mission_type: int = MAV_MISSION_TYPE_MISSION

    @property
    def is_global(self) -> bool:
        """Whether the item's position is geodetic (any frame but MAV_FRAME_MISSION)."""
        return self.frame != FRAME_MISSION

    @property
    def relative_alt(self) -> bool:
        """Whether its altitude is above home (the RELATIVE_ALT frames) rather than AMSL."""
        return self.frame in (FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_RELATIVE_ALT_INT)

    def lat_lon_deg(self) -> tuple[float, float]:
        """Latitude and longitude in degrees (stored as degE7)."""
        return self.x * 1e-7, self.y * 1e-7


# --- what goes out ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Out:
    """A message to send: ``kind`` is the MAVLink message name, ``fields`` its fields in the
    order of pymavlink's constructor (after target system and component where it has them)."""

    kind: str
    target: tuple[int, int] | None
    fields: tuple


def _ack(target: tuple[int, int], result: int, mission_type: int) -> Out:
    return Out("MISSION_ACK", target, (result, mission_type))


def _text(text: str, severity: int = MAV_SEVERITY_CRITICAL) -> Out:
    return Out("STATUSTEXT", None, (severity, text))


# --- the manager -----------------------------------------------------------------------------


@dataclass
class _Transfer:
    partner: tuple[int, int] = (0, 0)
    mission_type: int = MAV_MISSION_TYPE_MISSION
    seq: int = 0
    count: int = 0
    items: list[MissionItem] = field(default_factory=list)
    current_seq: int = -1
    crc: int = 0
    last_sent_s: float | None = None
    last_recv_s: float | None = None


class MissionManager:
    """PX4's mission manager for one vehicle (one instance serves every link, as PX4's static
    lists do; ``handle`` takes the link's index so answers go back where the request came from).

    Attributes
    ----------
    lists : dict of mission type -> list of MissionItem
    current_seq : int
        The mission's current item (MISSION_CURRENT.seq).
    changed : bool
        Set when an upload or a clear changed the mission list (the navigator re-reads it);
        the reader resets it.
    """

    def __init__(self) -> None:
        self.lists: dict[int, list[MissionItem]] = {t: [] for t in MAX_COUNT}
        self.crc: dict[int, int] = {t: 0 for t in MAX_COUNT}
        self.current_seq = 0
        self.changed = False
        self.state = TransferState.IDLE
        self.int_mode = False  # PX4 boots in float mode (its _int_mode is false until an INT message)
        self._t = _Transfer()
        self._link: int = 0

    # -- reading ---------------------------------------------------------------------------------

    @property
    def mission(self) -> list[MissionItem]:
        """The mission list's items (MAV_MISSION_TYPE_MISSION)."""
        return self.lists[MAV_MISSION_TYPE_MISSION]

    def mission_current(self) -> tuple[int, int, int, int]:
        """MISSION_CURRENT's (seq, total, mission_state, mission_mode) as PX4 v1.16 sends them:
        total is the item count, or 65535 (UINT16_MAX) without a mission; v1.16 leaves
        mission_state and mission_mode 0 (unknown)."""
        n = len(self.mission)
        return self.current_seq, n if n > 0 else 65535, 0, 0

    @property
    def busy_link(self) -> int | None:
        """The link of the transfer going on, or None."""
        return None if self.state is TransferState.IDLE else self._link

    # -- incoming --------------------------------------------------------------------------------

    @staticmethod
    def addressed_to_us(msg: MAVLinkMessage, sysid: int, compid: int) -> bool:
        """PX4's CHECK_SYSID_COMPID_MISSION: our system and our component, the mission planner's
        (190) or all (0)."""
        ts, tc = getattr(msg, "target_system", 0), getattr(msg, "target_component", 0)
        return ts == sysid and tc in (compid, MAV_COMP_ID_MISSIONPLANNER, 0)

    def handle(self, msg: MAVLinkMessage, now_s: float, link: int = 0) -> list[Out]:
        """Answer one MISSION_* message (a pymavlink message; others give [])."""
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        handler = {
            "MISSION_COUNT": self._on_count,
            "MISSION_ITEM_INT": self._on_item,
            "MISSION_ITEM": self._on_item,
            "MISSION_REQUEST_LIST": self._on_request_list,
            "MISSION_REQUEST_INT": self._on_request,
            "MISSION_REQUEST": self._on_request,
            "MISSION_ACK": self._on_ack,
            "MISSION_CLEAR_ALL": self._on_clear_all,
            "MISSION_SET_CURRENT": self._on_set_current,
        }.get(kind)
        if handler is None:
            return []
        if kind in ("MISSION_ITEM_INT", "MISSION_REQUEST_INT"):
            self.int_mode = True
        elif kind in ("MISSION_ITEM", "MISSION_REQUEST"):
            self.int_mode = False
        return handler(msg, src, now_s, link)

    def update(self, now_s: float) -> list[Out]:
        """Time-driven: repeat an unanswered request, drop a silent transfer (PX4's send())."""
        t = self._t
        if self.state is TransferState.GETLIST and t.last_sent_s is not None and now_s - t.last_sent_s > RETRY_S:
            return self._request(now_s)
        if self.state is not TransferState.IDLE and t.last_recv_s is not None and now_s - t.last_recv_s > TIMEOUT_S:
            self.state = TransferState.IDLE
            return [_text("Operation timeout")]
        return []

    def set_current(self, seq: int) -> bool:
        """Make ``seq`` the current mission item (MISSION_SET_CURRENT, DO_SET_MISSION_CURRENT)."""
        if 0 <= seq < len(self.mission):
            self.current_seq = seq
            return True
        return False

    # -- upload ----------------------------------------------------------------------------------

    def _on_count(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        t = self._t
        mtype = int(msg.mission_type)
        count = int(msg.count)
        if self.state is TransferState.GETLIST:
            t.last_recv_s = now_s
            if src != t.partner:
                return [_ack(src, MAV_MISSION_ERROR, mtype)]
            if t.seq == 0:  # our first request was lost: ask again
                return self._request(now_s)
            return [_text("WPM: REJ. CMD: Busy"), _ack(t.partner, MAV_MISSION_ERROR, t.mission_type)]
        if self.state is TransferState.SENDLIST:
            return [_text("WPM: IGN MISSION_COUNT: Busy"), _ack(src, MAV_MISSION_ERROR, mtype)]
        if mtype not in MAX_COUNT:
            return [_ack(src, MAV_MISSION_INVALID, mtype)]
        if count > MAX_COUNT[mtype]:
            return [_ack(src, MAV_MISSION_NO_SPACE, mtype)]
        if count == 0:
            self._store(mtype, [], 0, -1)
            return [_ack(src, MAV_MISSION_ACCEPTED, mtype)]
        self._t = _Transfer(partner=src, mission_type=mtype, count=count, last_recv_s=now_s)
        self._link = link
        self.state = TransferState.GETLIST
        return self._request(now_s)

    def _request(self, now_s: float) -> list[Out]:
        t = self._t
        t.last_sent_s = now_s
        kind = "MISSION_REQUEST_INT" if self.int_mode else "MISSION_REQUEST"
        return [Out(kind, t.partner, (t.seq, t.mission_type))]

    def _on_item(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        t = self._t
        seq, mtype = int(msg.seq), int(msg.mission_type)
        if src != t.partner and self.state is not TransferState.IDLE:
            return [_text("REJ. MIS ITEM: partner id mismatch")]
        if self.state is TransferState.IDLE:
            if src == t.partner and t.count and t.seq == seq + 1:
                return [_ack(t.partner, MAV_MISSION_ACCEPTED, t.mission_type)]  # a repeat of the last item: ACK again
            return [_text("IGN MISSION_ITEM: No transfer"), _ack(src, MAV_MISSION_ERROR, mtype)]
        if mtype != t.mission_type:
            return [_ack(t.partner, MAV_MISSION_ERROR, t.mission_type)]
        if self.state is TransferState.SENDLIST:
            return [_text("IGN MISSION_ITEM: Busy"), _ack(t.partner, MAV_MISSION_ERROR, t.mission_type)]
        t.last_recv_s = now_s
        if seq != t.seq:
            return []  # not the one asked for: ignored (the request is repeated)
        item, result = parse_item(msg, self.int_mode, mtype)
        if item is None:
            self.state = TransferState.IDLE
            return [_text("IGN MISSION_ITEM: Invalid item"), _ack(t.partner, result, t.mission_type)]
        if int(getattr(msg, "current", 0)):
            t.current_seq = seq
        t.items.append(item)
        t.crc = _crc(item, t.crc)
        t.seq = seq + 1
        if t.seq < t.count:
            return self._request(now_s)
        self.state = TransferState.IDLE
        if t.crc != self.crc[mtype] or len(t.items) != len(self.lists[mtype]):
            self._store(mtype, t.items, t.crc, t.current_seq)
        return [_ack(t.partner, MAV_MISSION_ACCEPTED, t.mission_type)]

    def _store(self, mtype: int, items: list[MissionItem], crc: int, current_seq: int) -> None:
        self.lists[mtype] = list(items)
        self.crc[mtype] = crc
        if mtype == MAV_MISSION_TYPE_MISSION:
            self.current_seq = max(current_seq, 0)
            self.changed = True

    # -- download --------------------------------------------------------------------------------

    def _on_request_list(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        t = self._t
        mtype = int(msg.mission_type)
        if self.state is TransferState.SENDLIST and t.seq == t.count:
            self.state = TransferState.IDLE  # all sent, the ACK was lost: start again
        if self.state is TransferState.IDLE or (self.state is TransferState.SENDLIST and t.mission_type == mtype and src == t.partner):
            items = self.lists.get(mtype, [])
            self._t = _Transfer(partner=src, mission_type=mtype, count=len(items), last_recv_s=now_s)
            self._link = link
            self.state = TransferState.SENDLIST
            return [Out("MISSION_COUNT", src, (len(items), mtype))]
        return [_text("Mission download request ignored, already active", MAV_SEVERITY_INFO)]

    def _on_request(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        t = self._t
        seq, mtype = int(msg.seq), int(msg.mission_type)
        if self.state is TransferState.IDLE:
            return []  # PX4 ignores requests outside a transfer silently (buggy OSDs)
        if src != t.partner:
            return [_text("WPM: REJ. CMD: partner id mismatch")]
        if self.state is TransferState.GETLIST:
            return [_text("WPM: REJ. CMD: Busy")]
        if mtype != t.mission_type:
            return []
        t.last_recv_s = now_s
        if seq == t.seq and t.seq < t.count:
            t.seq += 1
        elif seq != t.seq - 1:
            self.state = TransferState.IDLE
            return [_ack(t.partner, MAV_MISSION_ERROR, t.mission_type), _text("WPM: REJ. CMD: Req. WP was unexpected")]
        stored = self.lists[mtype]
        if seq >= len(stored):
            self.state = TransferState.IDLE
            return [_ack(t.partner, MAV_MISSION_ERROR, t.mission_type), _text("WPM: REJ. CMD: Req. WP was unexpected")]
        return [item_out(stored[seq], t.partner, self.int_mode, current=seq == self.current_seq)]

    def _on_ack(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        t = self._t
        if src != t.partner:
            return [_text("REJ. WP CMD: partner id mismatch")] if self.state is not TransferState.IDLE else []
        if self.state is TransferState.SENDLIST and int(msg.mission_type) == t.mission_type:
            self.state = TransferState.IDLE
        elif self.state is TransferState.GETLIST:
            result = int(msg.type)
            if result == MAV_MISSION_UNSUPPORTED:  # the partner does not speak this mode: switch
                self.int_mode = not self.int_mode
                return self._request(now_s)
            if result == MAV_MISSION_OPERATION_CANCELLED:
                self.state = TransferState.IDLE
        return []

    # -- clear, current --------------------------------------------------------------------------

    def _on_clear_all(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        mtype = int(msg.mission_type)
        if self.state is not TransferState.IDLE:
            return [_text("WPM: IGN CLEAR CMD: Busy")]
        for t in (MAX_COUNT if mtype == MAV_MISSION_TYPE_ALL else (mtype,) if mtype in MAX_COUNT else ()):
            self._store(t, [], 0, 0)
        return [_ack(src, MAV_MISSION_ACCEPTED, mtype)]

    def _on_set_current(self, msg: MAVLinkMessage, src: tuple[int, int], now_s: float, link: int) -> list[Out]:
        if self.state is not TransferState.IDLE:
            return [_text("WPM: IGN WP CURR CMD: Busy")]
        if not self.set_current(int(msg.seq)):
            return [_text("WPM: WP CURR CMD: Not in list")]
        return []


# --- what the vehicle reports ----------------------------------------------------------------


@dataclass
class Reporter:
    """When MISSION_CURRENT and MISSION_ITEM_REACHED go out besides the streams (PX4's
    MavlinkMissionManager::send): MISSION_CURRENT on every change (its 1 Hz is the plant's stream,
    server.STREAMS); MISSION_ITEM_REACHED on every change of the item reached last, then again at
    1 Hz ten more times."""

    REPEATS = 10
    _sent_current: tuple = ()
    _sent_reached: int = 0
    _next_s: float = 0.0
    _repeats: int = 0

    def due(self, now_s: float, current: tuple[int, int, int, int], reached_seq: int, reached_count: int, has_mission: bool) -> list[Out]:
        """The messages to send now; ``current`` is ``MissionManager.mission_current()``,
        ``reached_count`` grows with every item reached (``Navigator.reached_count``)."""
        tick = now_s >= self._next_s - 1e-9
        out = []
        if self._sent_current and current != self._sent_current:  # (the first: the stream's)
            out.append(Out("MISSION_CURRENT", None, current))
        if reached_count != self._sent_reached and reached_seq >= 0:
            out.append(Out("MISSION_ITEM_REACHED", None, (reached_seq,)))
            self._repeats = 0
        elif tick and reached_seq >= 0 and has_mission and self._repeats < self.REPEATS:
            out.append(Out("MISSION_ITEM_REACHED", None, (reached_seq,)))
            self._repeats += 1
        if tick:
            self._next_s = now_s + 1.0
        self._sent_current, self._sent_reached = current, reached_count
        return out


# --- items -----------------------------------------------------------------------------------


def parse_item(msg: MAVLinkMessage, int_mode: bool, mission_type: int) -> tuple[MissionItem | None, int]:
    """A received MISSION_ITEM(_INT) as PX4 stores it, or (None, the MAV_MISSION_RESULT why not)
    (``parse_mavlink_mission_item`` and the checks of ``handle_mission_item_both``)."""
    m = msg
    frame, command = int(m.frame), int(m.command)
    raw = (float(m.param1), float(m.param2), float(m.param3), float(m.param4))
    x, y, z = m.x, m.y, float(m.z)
    int_frames = (FRAME_GLOBAL_INT, FRAME_GLOBAL_RELATIVE_ALT_INT)
    if frame in (FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT) or (int_mode and frame in int_frames):
        keeps = _GLOBAL_KEEPS.get(command)
        if keeps is None:
            return None, MAV_MISSION_UNSUPPORTED
        if command in (NAV_ROI, DO_SET_ROI) and int(raw[0]) not in (0, 3):  # MAV_ROI_NONE, MAV_ROI_LOCATION
            return None, MAV_MISSION_INVALID_PARAM1
        params = _kept(command, raw, keeps)
        if int_mode:
            lat_e7, lon_e7 = int(x), int(y)
        else:  # float mode: degrees in the float fields
            if not (math.isfinite(x) and abs(x) <= 90.0):
                return None, MAV_MISSION_INVALID_PARAM5_X
            if not (math.isfinite(y) and abs(y) <= 180.0):
                return None, MAV_MISSION_INVALID_PARAM6_Y
            lat_e7, lon_e7 = int(round(float(x) * 1e7)), int(round(float(y) * 1e7))
        relative = frame in (FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_RELATIVE_ALT_INT)
        stored_frame = FRAME_GLOBAL_RELATIVE_ALT_INT if relative else FRAME_GLOBAL_INT
        autocontinue = int(m.autocontinue)
        item = MissionItem(int(m.seq), stored_frame, command, params, lat_e7, lon_e7, _f32(z), autocontinue, mission_type)
    elif frame == FRAME_MISSION:
        if command not in _MISSION_FRAME_COMMANDS:
            return None, MAV_MISSION_UNSUPPORTED
        if command in (NAV_ROI, DO_SET_ROI) and int(raw[0]) not in (0, 1, 2):  # NONE, WPNEXT, WPINDEX
            return None, MAV_MISSION_INVALID_PARAM1
        item = MissionItem(int(m.seq), FRAME_MISSION, command, tuple(_f32(p) for p in raw), float(x), float(y), _f32(z), int(m.autocontinue), mission_type)  # type: ignore[arg-type]
    else:
        return None, MAV_MISSION_UNSUPPORTED_FRAME
    if mission_type == MAV_MISSION_TYPE_MISSION and command in FENCE_AND_RALLY:
        return None, MAV_MISSION_ERROR
    if mission_type == MAV_MISSION_TYPE_FENCE:
        if command in (FENCE_POLY_INCL, FENCE_POLY_EXCL) and int(raw[0] + 0.5) < 3:
            return None, MAV_MISSION_ERROR  # "Fence: too few vertices"
        item = MissionItem(item.seq, item.frame, item.command, item.params, item.x, item.y, item.z, 0, mission_type)
    return item, MAV_MISSION_ACCEPTED


def _kept(command: int, raw: tuple[float, float, float, float], keeps: tuple[int, ...]) -> tuple[float, float, float, float]:
    out = [0.0, 0.0, 0.0, 0.0]
    for i in keeps:
        out[i] = _f32(raw[i])
    if command in (NAV_WAYPOINT, NAV_LOITER_UNLIM, NAV_LAND, NAV_TAKEOFF, NAV_VTOL_TAKEOFF, NAV_VTOL_LAND) and math.isfinite(out[3]):
        out[3] = _f32(math.degrees(math.radians(out[3]) % (2 * math.pi)))  # yaw: wrap_2pi
    if command == NAV_LOITER_TIME:
        out[1] = 1.0 if raw[1] > 0 else 0.0  # force heading
        out[3] = 1.0 if raw[3] > 0 else 0.0  # exit cross-track
    if command == NAV_LOITER_TO_ALT:
        out[0] = 1.0 if raw[0] > 0 else 0.0
        out[3] = 1.0 if raw[3] > 0 else 0.0
    if command in (FENCE_POLY_INCL, FENCE_POLY_EXCL):
        out[0] = float(int(raw[0] + 0.5))
    return out[0], out[1], out[2], out[3]


def item_out(item: MissionItem, target: tuple[int, int], int_mode: bool, *, current: bool = False) -> Out:
    """The MISSION_ITEM_INT (or, in float mode, MISSION_ITEM) that sends ``item`` back."""
    frame, x, y = item.frame, item.x, item.y
    if item.is_global and not int_mode:
        frame = FRAME_GLOBAL_RELATIVE_ALT if item.relative_alt else FRAME_GLOBAL
        x, y = float(_f32(item.x * 1e-7)), float(_f32(item.y * 1e-7))
    elif not item.is_global and int_mode:
        x, y = int(round(item.x)), int(round(item.y))
    kind = "MISSION_ITEM_INT" if int_mode else "MISSION_ITEM"
    return Out(kind, target, (item.seq, frame, item.command, int(current), item.autocontinue, *item.params, x, y, item.z, item.mission_type))


def _f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _crc(item: MissionItem, crc: int) -> int:
    raw = struct.pack("<BHB", item.frame, item.command, item.autocontinue) + struct.pack("<4fddf", *item.params, float(item.x), float(item.y), item.z)
    return zlib.crc32(raw, crc)


__all__ = ["MissionManager", "MissionItem", "Out", "Reporter", "parse_item", "item_out", "TransferState", "RETRY_S", "TIMEOUT_S", "MAX_COUNT"]
