"""The plant's sockets and its telemetry log: the only module of ``sitl-plant`` doing network I/O.

Two links, as PX4 SITL has them, each **one** UDP socket that sends and receives:

- the offboard/API link binds UDP 14580 and sends to 127.0.0.1:14540 (where ``offboard`` or
  MAVSDK listens with ``udpin:0.0.0.0:14540``);
- the ground-station link binds UDP 18570 and sends to 127.0.0.1:14550 (QGroundControl,
  MAVProxy).

Each answers whoever talks to it: the remote address becomes the sender of the last valid
MAVLink packet (with signing, of the last verified signed one: the few messages accepted
unsigned are handled but never move the remote). Outgoing messages of one tick go out batched in one datagram (as PX4 batches
them), which every MAVLink client parses.

Incoming datagrams are parsed by pymavlink with robust parsing, one datagram at a time (MAVLink
over UDP never splits a packet across datagrams, so a truncated or corrupted datagram cannot
spoil the next one): bad bytes are counted, never raised.

``--log FILE.tlog`` records every packet sent and received on both links in the standard tlog
format: for each packet an 8-byte big-endian timestamp in microseconds since the Unix epoch and
the raw MAVLink packet, as pymavlink's ``mavutil.mavlink_connection(path)`` and
``mavlogdump.py`` read it. The timestamp comes from the caller (the server uses a start epoch
plus simulation time, so lockstep logs are reproducible to the byte).
"""

from __future__ import annotations

import errno
import select
import socket
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from offboard.model import mavfast
from offboard.model.busywait import LOCKSTEP_SPIN_S, poll_readable
from offboard.model.errors import LinkError
from offboard.model.tlog import TlogWriter
from offboard.signing import SigningKey, SigningSession, Verdict, persist, save_key
from sitl_plant import codec
from sitl_plant.impairment import DelayLine, Impairment

MAX_DATAGRAM = 1400  # bytes of MAVLink packed into one UDP datagram (below a typical MTU)
KEEPALIVE_IDS = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT})  # whose latest packet a keepalive may resend


def parse_address(text: str, what: str) -> tuple[str, int] | None:
    """``HOST:PORT`` to a tuple; ``none`` (or empty) to None (the link is switched off)."""
    text = text.strip()
    if text.lower() in ("", "none", "off"):
        return None
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{what}: expected HOST:PORT, got {text!r}")
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"{what}: port must be a number, got {port!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"{what}: port must be 0..65535, got {number}")
    return host, number


@dataclass
class LinkCounters:
    """Per-link traffic counters (shown on the status line and in the exit summary)."""

    packets_in: int = 0
    packets_out: int = 0
    bad_packets: int = 0
    unknown_messages: int = 0
    send_errors: int = 0
    encode_errors: int = 0
    by_type_in: dict[str, int] = field(default_factory=dict)
    #: frames refused before any handling: signing verdicts (unsigned, bad_signature, replayed,
    #: stale_stream) and ``sender`` (a system id not on the allow-list)
    refused: dict[str, int] = field(default_factory=dict)
    #: refused frames by sender system id
    refused_senders: dict[int, int] = field(default_factory=dict)


class Endpoint:
    """One UDP socket: MAVLink in and out, with the remote learnt from who talks to it.

    Parameters
    ----------
    name : str
        ``"api"`` or ``"gcs"`` (for messages and counters).
    bind : (host, port)
        Local address (port 0 lets the OS choose).
    remote : (host, port) or None
        Where to send before anyone talked to us; None: only answer who talks.
    sysid, compid : int
        Our MAVLink identity on this link.
    signing : SigningSession or None
        Sign what we send, and refuse incoming frames that are not signed with its key
        (``offboard.signing``).
    allowed_senders : set of int or None
        System ids whose frames are handled (None: anyone's, as PX4); the others are refused
        and counted, and never become the remote we answer.
    """

    def __init__(self, name: str, bind: tuple[str, int], remote: tuple[str, int] | None, sysid: int, compid: int,
                 *, signing: SigningSession | None = None, allowed_senders: frozenset[int] | None = None,
                 impair_in: Impairment | None = None, impair_out: Impairment | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.name = name
        self.remote = remote
        self.signing = signing
        self.allowed_senders = allowed_senders
        #: what a bad link does to the datagrams received and sent (sitl_plant/impairment.py)
        self.impair_in = impair_in
        self.impair_out = impair_out
        self._clock = clock
        self._held_in = DelayLine()
        self._held_out = DelayLine()
        self.counters = LinkCounters()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
            self.sock.bind(bind)
        except OSError as exc:
            self.sock.close()
            raise LinkError(f"{name} link: cannot bind UDP {bind[0]}:{bind[1]}: {exc.strerror}") from None
        except (OverflowError, socket.gaierror) as exc:
            self.sock.close()
            raise LinkError(f"{name} link: bad bind address {bind[0]}:{bind[1]}: {exc}") from None
        self.sock.setblocking(False)
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        #: the latest packet sent of each message id in KEEPALIVE_IDS (resent by lockstep keepalives)
        self.latest: dict[int, bytes] = {}
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.remembered: dict[str, list[bytes]] = {}

    @property
    def local_address(self) -> tuple[str, int]:
        """The (host, port) the endpoint's socket is bound to."""
        return self.sock.getsockname()

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()

    def pack(self, messages: list[mavlink.MAVLink_message]) -> list[bytes]:
        """Serialise messages with this link's sequence numbers."""
        out = []
        packer = self.packer
        signing = self.signing
        for msg in messages:
            if signing is not None:
                signing.stamp(packer)
            try:
                packet = mavfast.pack(msg, packer)  # pymavlink's bytes, pre-built for the hot messages
            except (struct.error, OverflowError, ValueError, TypeError):
                self.counters.encode_errors += 1  # a value out of its field's range: not sent
                continue
            out.append(packet)
            mid = msg.get_msgId()  # not msg.id: some messages (HIGHRES_IMU) have a field named id
            if mid in KEEPALIVE_IDS:
                self.latest[mid] = packet
            packer.seq = (packer.seq + 1) & 0xFF
        return out

    def send_packets(self, packets: list[bytes]) -> list[bytes]:
        """Send packed packets batched into datagrams; returns the datagrams (built even while
        nobody is known to send to, so a lockstep keepalive has them once someone talks)."""
        if not packets:
            return []
        datagrams: list[bytes] = []
        chunk = bytearray()
        for p in packets:
            if chunk and len(chunk) + len(p) > MAX_DATAGRAM:
                datagrams.append(bytes(chunk))
                chunk = bytearray()
            chunk += p
        if chunk:
            datagrams.append(bytes(chunk))
        if self.remote is not None:
            for d in datagrams:
                self.send_datagram(d)
            self.counters.packets_out += len(packets)
        return datagrams

    def send_datagram(self, data: bytes) -> None:
        """Send one datagram to the remote (none known: dropped), through the outgoing impairment if any."""
        if self.remote is None:
            return
        if self.impair_out is not None:
            now = self._clock()
            for release_s, copy in self.impair_out.schedule(data, now):
                self._held_out.push(release_s, copy, self.remote)
            self.release(now)
            return
        self._sendto(data, self.remote)

    def release(self, now_s: float) -> None:
        """Send the held datagrams whose delay is over (to where they were addressed)."""
        for data, remote in self._held_out.due(now_s):
            self._sendto(data, remote)  # type: ignore[arg-type]

    def next_release_s(self) -> float | None:
        """When the next held datagram (either way) is due; None: none is held."""
        times = [t for t in (self._held_in.next_release_s(), self._held_out.next_release_s()) if t is not None]
        return min(times) if times else None

    def _sendto(self, data: bytes, remote: tuple[str, int]) -> None:
        try:
            self.sock.sendto(data, remote)
        except OSError as exc:
            # nobody listening (ICMP port unreachable), buffer full: UDP is best effort
            if exc.errno not in (errno.ECONNREFUSED, errno.EAGAIN, errno.EWOULDBLOCK, errno.ENOBUFS, errno.EHOSTUNREACH, errno.ENETUNREACH):
                raise
            self.counters.send_errors += 1

    def receive(self) -> list[mavlink.MAVLink_message]:
        """Every valid message waiting on the socket (bad bytes counted, unknown ids kept)."""
        out: list[mavlink.MAVLink_message] = []
        impair = self.impair_in
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                if exc.errno == errno.ECONNREFUSED:  # an earlier send found nobody listening
                    continue
                raise
            if impair is not None:
                for release_s, copy in impair.schedule(data, self._clock()):
                    self._held_in.push(release_s, copy, addr)
                continue
            if self._parse_datagram(data, out):
                self.remote = addr
        if impair is not None or len(self._held_out):
            now = self._clock()
            for data, addr in self._held_in.due(now):
                if self._parse_datagram(data, out):
                    self.remote = addr  # type: ignore[assignment]
            self.release(now)
        return out

    def _verdict(self, msg: mavlink.MAVLink_message) -> tuple[str | None, bool]:
        """Why a well-formed frame is refused before handling (None: it is not), and whether it
        may make its sender the remote we answer: with signing, only a verified signed frame
        may (a RADIO_STATUS, ADSB_VEHICLE or COLLISION is handled unsigned, as PX4 does, but
        proves nothing about who sent it); without signing, any accepted frame."""
        sender = msg.get_srcSystem()
        if self.allowed_senders is not None and sender not in self.allowed_senders:
            return "sender", False
        if self.signing is not None:
            verdict = self.signing.check.check(msg.get_msgbuf(), msg.get_msgId(), sender, msg.get_srcComponent())
            if not verdict.accepted:
                return verdict.value, False
            return None, verdict is Verdict.SIGNED
        return None, True

    def _parse_datagram(self, data: bytes, out: list[mavlink.MAVLink_message]) -> bool:
        """Queue the accepted messages of one datagram; whether one of them may make its sender
        the remote (``_verdict``)."""
        parser = self.parser
        counters = self.counters
        found = False
        try:
            messages = mavfast.parse_datagram(parser, data)  # the hot frames with pre-built structs, as pymavlink
        except Exception:  # noqa: BLE001 - a malformed packet must never stop the plant
            messages = []
            counters.bad_packets += 1
        for msg in messages:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                counters.bad_packets += 1
                continue
            refusal, proves = self._verdict(msg)
            if refusal is not None:
                counters.refused[refusal] = counters.refused.get(refusal, 0) + 1
                sender = msg.get_srcSystem()
                counters.refused_senders[sender] = counters.refused_senders.get(sender, 0) + 1
                continue
            found = found or proves
            counters.packets_in += 1
            if kind == "UNKNOWN" or kind.startswith("UNKNOWN_"):
                counters.unknown_messages += 1
            counters.by_type_in[kind] = counters.by_type_in.get(kind, 0) + 1
            out.append(msg)
        # drop whatever partial packet is left: the next datagram starts afresh
        parser.buf = bytearray()
        parser.buf_index = 0
        parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        return found


class Link:
    """The plant's endpoints (API first, then GCS) and the optional tlog.

    Parameters
    ----------
    endpoints : list of Endpoint
    tlog : TlogWriter or None
    log_time_us : callable
        The tlog timestamp for packets logged now (microseconds since the Unix epoch).
    """

    def __init__(self, endpoints: list[Endpoint], tlog: TlogWriter | None, log_time_us: Callable[[], int],
                 *, lockstep: bool = False) -> None:  # fmt: skip
        self.endpoints = endpoints
        self.lockstep = lockstep  # (a session SETUP_SIGNING starts signs on the simulation's clock alone)
        self.tlog = tlog
        self.log_time_us = log_time_us
        self._socks = [e.sock for e in endpoints]
        self._note_id = 65535  # the next note's STATUSTEXT id (note)

    def wait(self, timeout_s: float) -> bool:
        """Block until a socket is readable or the timeout passes; whether one is readable."""
        if timeout_s < 0:
            timeout_s = 0.0
        held = [t for t in (e.next_release_s() for e in self.endpoints) if t is not None]
        if held:  # a held datagram falls due: wake for it (receive() hands it over)
            now = time.monotonic()
            first = min(held)
            if first <= now:
                return True
            timeout_s = min(timeout_s, first - now)
        try:
            # lockstep: the offboard answers within a few hundred microseconds, caught awake
            if self.lockstep and poll_readable(self._socks, min(LOCKSTEP_SPIN_S, timeout_s)):
                return True
            readable, _, _ = select.select(self._socks, [], [], timeout_s)
        except InterruptedError:
            return False
        if not readable and held and min(held) <= time.monotonic():
            return True
        return bool(readable)

    def impairment_status(self) -> str:
        """`` link: N dropped, M duplicated, ...`` of the impaired directions (the status line's
        tail; '' on a clean link)."""
        dropped = duplicated = corrupted = 0
        for e in self.endpoints:
            for impair in (e.impair_in, e.impair_out):
                if impair is not None:
                    c = impair.counts
                    dropped, duplicated, corrupted = dropped + c.dropped, duplicated + c.duplicated, corrupted + c.corrupted
        if not any(e.impair_in or e.impair_out for e in self.endpoints):
            return ""
        return f" link: {dropped} dropped, {duplicated} duplicated, {corrupted} corrupted"

    def note(self, text: str) -> None:
        """Record ``text`` in the tlog as STATUSTEXT of ours that is not sent (what the log was
        recorded under, such as the link's impairment); no sequence number is spent. A text
        longer than one STATUSTEXT's 50 bytes goes whole, in chunks sharing an ``id`` (MAVLink 2,
        as PX4 sends long texts and QGroundControl joins them); notes count their ids down from
        65535, away from the plant's own, which count up from 1."""
        if self.tlog is not None and self.endpoints:
            e = self.endpoints[0]
            packer = mavlink.MAVLink(None, srcSystem=e.packer.srcSystem, srcComponent=e.packer.srcComponent)
            self._note_id -= 1
            t = self.log_time_us()
            for msg in codec.statustext(mavlink.MAV_SEVERITY_NOTICE, text, self._note_id + 1):
                self.tlog.write(t, msg.pack(packer))

    def receive(self) -> list[tuple[int, mavlink.MAVLink_message]]:
        """Messages waiting on every endpoint, as (endpoint index, message); not yet logged."""
        out: list[tuple[int, mavlink.MAVLink_message]] = []
        for i, endpoint in enumerate(self.endpoints):
            for msg in endpoint.receive():
                out.append((i, msg))
        return out

    def log_received(self, msg: mavlink.MAVLink_message) -> None:
        """Record a received message in the tlog, stamped now (call it as the message is handled,
        so its timestamp is the plant time at which it acted)."""
        if self.tlog is not None:
            self.tlog.write(self.log_time_us(), msg.get_msgbuf())

    def send(self, index: int, messages: list[mavlink.MAVLink_message], *, remember: str | None = None) -> None:
        """Pack, log and send messages on one endpoint; ``remember`` keeps the datagrams by key."""
        if not messages:
            return
        endpoint = self.endpoints[index]
        packets = endpoint.pack(messages)
        if self.tlog is not None:
            t = self.log_time_us()
            for p in packets:
                self.tlog.write(t, p)
        datagrams = endpoint.send_packets(packets)
        if remember is not None:
            endpoint.remembered[remember] = datagrams

    def resend_remembered(self) -> None:
        """Send the remembered datagrams again (lockstep keepalive); not logged."""
        for endpoint in self.endpoints:
            for datagrams in endpoint.remembered.values():
                for d in datagrams:
                    endpoint.send_datagram(d)

    def send_keepalive(self, index: int, message_ids: list[int]) -> None:
        """Resend, byte for byte and not logged, the latest packet sent of each of ``message_ids``
        (in ``KEEPALIVE_IDS``) that the remembered datagrams do not already carry: no sequence
        number is spent, so the logged stream is the same however many keepalives the wall clock
        fired, and a client's duplicate filter drops the copies."""
        endpoint = self.endpoints[index]
        remembered = [d for datagrams in endpoint.remembered.values() for d in datagrams]
        for mid in message_ids:
            packet = endpoint.latest.get(mid)
            if packet is not None and not any(packet in d for d in remembered):
                endpoint.send_datagram(packet)

    def flush(self) -> None:
        """Hand the tlog's records so far to the operating system."""
        if self.tlog is not None:
            self.tlog.flush()

    def rekey(self, key: SigningKey) -> None:
        """SETUP_SIGNING: sign with ``key`` on every link from now on (a new session where there
        was none, on the plant's log clock), persisting it where the first session does."""
        path = next((e.signing.key_path for e in self.endpoints if e.signing is not None), None)
        for i, e in enumerate(self.endpoints):
            if e.signing is None:
                e.signing = SigningSession(key, self.log_time_us, link_id=i, key_path=path, lockstep=self.lockstep)
            else:
                e.signing.rekey(key)
        if path is not None:
            save_key(path, key)

    def unsign(self) -> None:
        """SETUP_SIGNING with an all-zero key: signing off on every link."""
        persist(e.signing for e in self.endpoints if e.signing is not None)
        for e in self.endpoints:
            e.signing = None
            e.packer.signing.sign_outgoing = False

    def close(self) -> None:
        """Close the sockets and the tlog; persist the newest signing timestamp of all links once."""
        for e in self.endpoints:
            e.close()
        persist(e.signing for e in self.endpoints if e.signing is not None)
        if self.tlog is not None:
            self.tlog.close()
