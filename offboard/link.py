"""The offboard process's MAVLink link: the only module of ``offboard`` with sockets.

The transport is pymavlink's, so every connection string a pymavlink user knows works as it
is (``udpin:0.0.0.0:14540``, ``udpout:127.0.0.1:14580``, ``tcp:HOST:PORT``, a serial device).
On top of it this module does what a flight needs of a link and pymavlink leaves to its user:

- MAVLink 2 packing with our own identity (``--sysid``/``--compid``) and sequence numbers;
- parsing that never raises on bad bytes (counted), one datagram at a time on UDP;
- **duplicate suppression**: a packet whose source, sequence number and bytes equal one of the
  latest received is dropped (a lockstep plant resends its last telemetry as a keepalive while
  nobody answers; those copies are not news);
- **loss counting** from the sequence numbers of each source (``LinkStats.lost``); frames of
  message ids that common.xml lacks (PX4 sends its development dialect: LINK_NODE_STATUS,
  TIME_ESTIMATE_TO_TARGET, CURRENT_MODE, CURRENT_EVENT_SEQUENCE...) are well-formed packets that
  use a sequence number too: pymavlink hands them over as ``MAVLink_unknown`` with no header
  decoded (source 0/0, sequence 0), so their source and sequence are read from the frame itself;
  they advance the count, are counted in ``LinkStats.unknown`` and logged in their place, but not
  handed to the caller;
- **signing** (``offboard.signing``, optional): what we send is signed, and frames not signed with
  the key are refused and counted (``LinkStats.refused``) after the duplicate filter;
- a **tlog** of every packet sent and received, in the order the flight handled them, stamped
  by an injected clock (wall time, or simulation time in lockstep so that two lockstep runs
  write the same bytes). pymavlink's ``mavutil.mavlink_connection(path)`` and ``mavlogdump.py``
  read it.

A received message is logged when ``recv`` hands it to the caller, not when it arrives, so the
log interleaves what we sent and what we received in the order the flight acted on them.
"""

from __future__ import annotations

import contextlib
import io
import select
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from offboard.codec import frame_header
from offboard.model import mavfast
from offboard.model.busywait import poll_readable
from offboard.model.errors import LinkError
from offboard.model.tlog import TlogWriter, wall_clock_us
from offboard.signing import SigningSession, Verdict

__all__ = ["LinkError", "LinkStats", "MavLink", "frame_header", "wall_clock_us"]

#: Connection-string prefixes accepted (pymavlink's); anything else must be a serial device.
SCHEMES = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:")
#: A packet counts as a duplicate only if its sequence number is this close behind the latest.
DUPLICATE_WINDOW = 64
ONBOARD_SYSID = 245  # MAVSDK's default system id for an API client
ONBOARD_COMPID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191


@dataclass
class LinkStats:
    """Packet counters of one link (what the summary reports as sent/received/lost)."""

    sent: int = 0
    received: int = 0
    lost: int = 0  # sequence-number gaps of the sources we heard
    duplicates: int = 0
    bad: int = 0  # bytes that did not parse as MAVLink (CRC errors, truncation, junk)
    unknown: int = 0  # well-formed frames of message ids common.xml lacks (also in received)
    #: well-formed frames refused by signing (``offboard.signing.Verdict``: unsigned, bad_signature,
    #: replayed, stale_stream), never handed to the flight
    refused: dict[str, int] = field(default_factory=dict)
    sent_by_type: dict[str, int] = field(default_factory=dict)
    received_by_type: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The link's counters for summary.json."""
        return {
            "sent": self.sent,
            "received": self.received,
            "lost": self.lost,
            "duplicates": self.duplicates,
            "bad": self.bad,
            "unknown": self.unknown,
            "refused": dict(sorted(self.refused.items())),
            "sent_by_type": dict(sorted(self.sent_by_type.items())),
            "received_by_type": dict(sorted(self.received_by_type.items())),
        }


@dataclass
class _Source:
    last_seq: int
    recent: dict[int, bytes]
    missing: set[int] = field(default_factory=set)  # sequence numbers skipped, in the last half
    heartbeat: bytes = b""  # its latest HEARTBEAT


#: The UDP receive buffer asked for (the kernel caps it at ``net.core.rmem_max``). The vehicle
#: streams PX4's default set (hundreds of datagrams a second) until we switch the unread ones
#: off; an offboard starved of the processor for a few hundred milliseconds overflows Linux's
#: 208 kB default and the kernel drops what comes next, a parameter's answer as readily as a
#: stream's (a loaded test run lost every answer to one PARAM_REQUEST_READ over 18 tries).
RECEIVE_BUFFER_BYTES = 4 << 20


def _widen_receive_buffer(sock: socket.socket) -> None:
    try:
        if sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) < RECEIVE_BUFFER_BYTES:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
    except OSError:  # a platform that refuses: its default it is
        pass


class MavLink:
    """One MAVLink connection with a tlog, duplicate suppression and loss counting.

    Parameters
    ----------
    connect : str
        A pymavlink connection string.
    sysid, compid : int
        Our identity (MAVSDK's 245 and MAV_COMP_ID_ONBOARD_COMPUTER by default).
    tlog_path : path or None
        Where to record every packet sent and received.
    log_time_us : callable
        The tlog timestamp of a packet logged now, microseconds since the Unix epoch.

    Raises
    ------
    LinkError
        The connection cannot be opened (bad string, address in use, no such device).
    """

    def __init__(
        self,
        connect: str,
        *,
        sysid: int = ONBOARD_SYSID,
        compid: int = ONBOARD_COMPID,
        tlog_path: str | Path | None = None,
        log_time_us: Callable[[], int] = wall_clock_us,
        signing: SigningSession | None = None,
        spin_s: float = 0.0,
    ) -> None:
        self.connect = connect
        self.spin_s = spin_s  # lockstep: poll this long before sleeping in a wait (offboard.model.busywait)
        if not connect.startswith(SCHEMES) and not (connect.startswith("/") or connect.upper().startswith("COM")):
            raise LinkError(f"--connect {connect!r}: expected a pymavlink connection string such as "
                            "udpin:0.0.0.0:14540, udpout:127.0.0.1:14580, tcp:127.0.0.1:5760 or a serial device")
        try:
            # pymavlink prints "[Errno 111] Connection refused sleeping" on stdout between its tcp
            # retries: the one line below says it once
            with contextlib.redirect_stdout(io.StringIO()):
                self.conn = mavutil.mavlink_connection(connect, source_system=sysid, source_component=compid, dialect="common")
        except (OSError, ValueError) as exc:
            reason = getattr(exc, "strerror", None) or str(exc)
            raise LinkError(f"--connect {connect}: cannot open the link: {reason}") from None
        except Exception as exc:  # noqa: BLE001 - serial and other transports raise their own kinds
            raise LinkError(f"--connect {connect}: cannot open the link: {exc}") from None
        self._datagrams = isinstance(self.conn, mavutil.mavudp)
        if self._datagrams:
            _widen_receive_buffer(self.conn.port)
        self._packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._queue: deque[mavlink.MAVLink_message] = deque()
        self._sources: dict[tuple[int, int], _Source] = {}
        self.stats = LinkStats()
        self.log_time_us = log_time_us
        self.signing = signing
        #: the (system, component) we fly, once known: only a datagram carrying one of its frames
        #: (verified signed, with signing) may change where we send (pymavlink's udpin answers
        #: everyone it heard, so any datagram from anyone else would get our setpoints too, and
        #: take them away from the vehicle with older pymavlink versions)
        self.trusted: tuple[int, int] | None = None
        self._tlog: TlogWriter | None = None
        if tlog_path is not None:
            try:
                self._tlog = TlogWriter(tlog_path)
            except OSError:  # LinkError, OutputPathError: the socket is ours to close
                self.conn.close()
                raise
        port = getattr(self.conn, "port", None)
        self._fileno = port.fileno() if port is not None and hasattr(port, "fileno") else getattr(self.conn, "fd", None)

    # -- identity ----------------------------------------------------------------------------------

    @property
    def sysid(self) -> int:
        """Our MAVLink system id."""
        return int(self._packer.srcSystem)

    @property
    def compid(self) -> int:
        """Our MAVLink component id."""
        return int(self._packer.srcComponent)

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The (host, port) our UDP socket is bound to (None: not a UDP link)."""
        port = getattr(self.conn, "port", None)
        try:
            return port.getsockname() if port is not None else None
        except OSError:
            return None

    # -- sending -----------------------------------------------------------------------------------

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Pack with our identity and next sequence number (signed, with signing), log, send."""
        if self.signing is not None:
            self.signing.stamp(self._packer)
        packet = mavfast.pack(msg, self._packer)  # pymavlink's bytes, pre-built for the hot messages
        self._packer.seq = (self._packer.seq + 1) & 0xFF
        if self._tlog is not None:
            self._tlog.write(self.log_time_us(), packet)
        self.conn.write(packet)
        self.stats.sent += 1
        kind = msg.get_type()
        self.stats.sent_by_type[kind] = self.stats.sent_by_type.get(kind, 0) + 1

    # -- receiving ---------------------------------------------------------------------------------

    def recv(self, timeout_s: float) -> mavlink.MAVLink_message | None:
        """The next new message (logged now), or None when none came within ``timeout_s``.

        Frames of other dialects are logged in their place and never returned."""
        deadline = time.monotonic() + max(timeout_s, 0.0)
        while True:
            self._pass_unknown()
            if self._queue:
                msg = self._queue.popleft()
                if self._tlog is not None:
                    self._tlog.write(self.log_time_us(), msg.get_msgbuf())
                return msg
            read = self._fill(max(deadline - time.monotonic(), 0.0))
            if not read and time.monotonic() >= deadline:
                self._pass_unknown()
                return None

    def pending(self) -> bool:
        """Whether a message is already waiting (without blocking)."""
        while True:
            self._pass_unknown()
            if self._queue:
                return True
            if not self._fill(0.0):
                return False

    def _pass_unknown(self) -> None:
        """Log the other dialects' frames at the head of the queue, in order, and drop them."""
        queue = self._queue
        while queue and isinstance(queue[0], mavlink.MAVLink_unknown):
            msg = queue.popleft()
            if self._tlog is not None:
                self._tlog.write(self.log_time_us(), msg.get_msgbuf())

    def _fill(self, timeout_s: float) -> bool:
        """Read until something is queued or ``timeout_s`` passed; whether any datagram came."""
        deadline = time.monotonic() + max(timeout_s, 0.0)
        read = False
        while not self._queue:
            data, sender = self._read()
            if data:
                read = True
                if self._parse(data) and sender is not None:
                    self._answer(sender)  # a stranger's datagram leaves it: we keep answering the vehicle
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return read
            self._wait(remaining)
        return read

    def _read(self) -> tuple[bytes, tuple[str, int] | None]:
        """The next datagram (or chunk of a stream) and, on UDP, who sent it; b"" when none waits.

        On UDP we read the socket ourselves: pymavlink's ``recv`` makes every sender one we
        answer (``udpin`` sends to every address it heard since version 2.4.4x, to the last
        before), and ``_answer`` decides that instead."""
        if self._datagrams:
            try:
                data, sender = self.conn.port.recvfrom(65535)
            except OSError:  # nothing waiting (EAGAIN), or an earlier send found nobody (ECONNREFUSED)
                return b"", None
            return data, sender
        try:
            data = self.conn.recv()
        except OSError:
            return b"", None
        if not data:
            return b"", None
        return (bytes(data) if not isinstance(data, bytes) else data), None

    def _answer(self, sender: tuple[str, int]) -> None:
        """Send to ``sender`` alone from now on (UDP): the vehicle's address, or while no vehicle
        is known, whoever sent an accepted frame last. pymavlink's ``udpin`` sends to its
        ``clients``, its ``udpbcast`` (and older ``udpin``) to ``last_address``; ``udpout`` keeps
        its destination."""
        conn = self.conn
        if getattr(conn, "udp_server", False):
            conn.clients = {sender}
            conn.clients_last_alive = {sender: time.time()}
            conn.last_address = sender
        elif getattr(conn, "broadcast", False):
            conn.last_address = sender

    def _wait(self, timeout_s: float) -> None:
        if self._fileno is None:
            time.sleep(min(timeout_s, 0.001))
            return
        try:
            if self.spin_s > 0.0 and poll_readable([self._fileno], min(self.spin_s, timeout_s)):
                return
            select.select([self._fileno], [], [], timeout_s)
        except (InterruptedError, ValueError, OSError):
            time.sleep(min(timeout_s, 0.001))

    def _parse(self, data: bytes) -> bool:
        """Queue the new messages of ``data``; whether one came from the trusted source (from
        anyone accepted, while none is trusted)."""
        parser = self._parser
        trusted = False
        try:
            # a UDP datagram holds whole frames: the hot ones decoded with pre-built structs
            messages = mavfast.parse_datagram(parser, data) if self._datagrams else (parser.parse_buffer(data) or [])
        except Exception:  # noqa: BLE001 - bad bytes must never stop a flight
            messages = []
            self.stats.bad += 1
        if self._datagrams:  # MAVLink over UDP never splits a packet: start afresh
            parser.buf = bytearray()
            parser.buf_index = 0
            parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                self.stats.bad += 1
                continue
            unknown = isinstance(msg, mavlink.MAVLink_unknown)
            header = frame_header(msg) if unknown else None  # (seq, system, component): pymavlink decodes none
            if self._is_duplicate(msg, header):  # first: a lockstep keepalive's copy is a duplicate, not a replay
                self.stats.duplicates += 1
                continue
            verified = True
            if self.signing is not None:
                sysid, compid = (header[1], header[2]) if header is not None else (msg.get_srcSystem(), msg.get_srcComponent())
                verdict = self.signing.check.check(msg.get_msgbuf(), msg.get_msgId(), sysid, compid)
                if not verdict.accepted:
                    self.stats.refused[verdict.value] = self.stats.refused.get(verdict.value, 0) + 1
                    continue
                verified = verdict is Verdict.SIGNED  # (a RADIO_STATUS taken unsigned proves nothing)
            self._track(msg, header)
            self.stats.received += 1
            kind = msg.get_type()
            self.stats.received_by_type[kind] = self.stats.received_by_type.get(kind, 0) + 1
            if unknown:  # another dialect's message: counted, and logged in its place (recv), never handed over
                self.stats.unknown += 1
            self._queue.append(msg)
            if verified and (self.trusted is None or (msg.get_srcSystem(), msg.get_srcComponent()) == self.trusted):
                trusted = True
        return trusted

    def _is_duplicate(self, msg: mavlink.MAVLink_message, header: tuple[int, int, int] | None = None) -> bool:
        """Whether ``msg`` repeats, byte for byte, one of the latest packets of its source (a
        lockstep keepalive, a duplicating link). Read only: ``_track`` counts what is accepted.

        ``header`` (sequence, system, component) read from the frame, for messages whose header
        pymavlink did not decode (``MAVLink_unknown``)."""
        seq, sysid, compid = header if header is not None else (msg.get_seq(), msg.get_srcSystem(), msg.get_srcComponent())
        src = self._sources.get((sysid, compid))
        if src is None:
            return False
        packet = bytes(msg.get_msgbuf())
        # its latest HEARTBEAT again, however far behind its number: a waiting lockstep plant's
        # keepalive (sitl_plant's KEEPALIVE_IDS); a new one always has a new sequence number. Any
        # other old frame again is a replay (signing counts it), or a duplicate within the window
        if packet == src.heartbeat:
            return True
        return ((src.last_seq - seq) & 0xFF) < DUPLICATE_WINDOW and src.recent.get(seq) == packet

    def _track(self, msg: mavlink.MAVLink_message, header: tuple[int, int, int] | None = None) -> None:
        """Follow the sequence numbers of an accepted packet's source: a forward jump counts the
        packets skipped as lost; one of them arriving late (a reordering link) is taken back off
        the count, so that ``lost`` counts only what never came (issue 14: 2 034 "lost" of none)."""
        seq, sysid, compid = header if header is not None else (msg.get_seq(), msg.get_srcSystem(), msg.get_srcComponent())
        key = (sysid, compid)
        packet = bytes(msg.get_msgbuf())
        src = self._sources.get(key)
        if src is None:
            src = self._sources[key] = _Source(seq, {seq: packet})
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                src.heartbeat = packet
            return
        src.recent[seq] = packet
        if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            src.heartbeat = packet
        behind = (src.last_seq - seq) & 0xFF
        if 0 < behind < 128:  # late (reordered), or from a second sequence: the baseline stays
            if seq in src.missing:
                src.missing.discard(seq)
                self.stats.lost -= 1
            return
        gap = (seq - src.last_seq - 1) & 0xFF  # a forward jump: packets lost on the way (so far)
        if gap:
            src.missing.update((src.last_seq + k) & 0xFF for k in range(1, gap + 1))
            self.stats.lost += gap
        src.last_seq = seq
        if src.missing:  # a packet more than half the sequence behind is not coming any more
            src.missing = {m for m in src.missing if ((seq - m) & 0xFF) < 128}

    # -- the end -----------------------------------------------------------------------------------

    def flush(self) -> None:
        """Hand the tlog's records so far to the operating system."""
        if self._tlog is not None:
            self._tlog.flush()

    def close(self) -> None:
        """Close the connection and the tlog (which is then complete); persist the signing timestamp."""
        try:
            self.conn.close()
        finally:
            if self._tlog is not None:
                self._tlog.close()
            if self.signing is not None:
                self.signing.close()

    def __enter__(self) -> MavLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
