"""One client for PX4's services (FTP, log download, shell, calibration, STATUSTEXT, body-frame
velocity), run unchanged against the real PX4 SITL and against sitl-plant.

``ServiceClient`` listens like ``udpin:127.0.0.1:PORT`` (it answers whoever talks to it) but
decodes only the messages a test waits for: a vehicle at speed 4 sends thousands of telemetry
messages a second, more than pymavlink decodes in Python, and a client that decodes them all
falls behind and loses the replies it waits for in the socket's buffer. Each datagram's MAVLink 2
frames are walked by their headers and only the wanted ids are parsed by pymavlink.
"""

from __future__ import annotations

import math
import socket
import struct
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

FTP_HEADER = struct.Struct("<HBBBBBBI")
SHELL_DEVICE = mavlink.SERIAL_CONTROL_DEV_SHELL
SHELL_FLAGS = mavlink.SERIAL_CONTROL_FLAG_RESPOND | mavlink.SERIAL_CONTROL_FLAG_EXCLUSIVE


@dataclass(frozen=True)
class FtpReply:
    seq: int
    session: int
    opcode: int
    req_opcode: int
    burst_complete: int
    offset: int
    data: bytes

    @property
    def nak_code(self) -> int | None:
        return self.data[0] if self.opcode == 129 and self.data else None


class ServiceClient:
    """A ground-station-like client on ``127.0.0.1:port`` (the vehicle sends there)."""

    def __init__(self, port: int, *, sysid: int = 245, compid: int = 190, target: int = 1) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.peer: tuple[str, int] | None = None
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self.target = target
        self._ftp_seq = 0

    def close(self) -> None:
        self.sock.close()

    # -- transport -------------------------------------------------------------------------------

    def send(self, msg: mavlink.MAVLink_message) -> None:
        assert self.peer is not None, "the vehicle has not talked yet"
        self.sock.sendto(msg.pack(self.mav), self.peer)

    def receive(self, ids: set[int], timeout_s: float) -> list[mavlink.MAVLink_message]:
        """Every wanted message that arrives within ``timeout_s`` (from the autopilot component)."""
        out: list[mavlink.MAVLink_message] = []
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            out.extend(self._poll(ids))
        return out

    def wait(self, ids: set[int], timeout_s: float, until=lambda m: True) -> mavlink.MAVLink_message | None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for m in self._poll(ids):
                if until(m):
                    return m
        return None

    def _poll(self, ids: set[int]) -> list[mavlink.MAVLink_message]:
        try:
            data, addr = self.sock.recvfrom(65536)
        except TimeoutError:
            return []
        self.peer = addr
        out = []
        i = 0
        while i + 12 <= len(data):
            if data[i] != 0xFD:
                i += 1
                continue
            length, incompat = data[i + 1], data[i + 2]
            size = 12 + length + (13 if incompat & 1 else 0)
            compid = data[i + 6]
            mid = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
            if mid in ids and compid == 1:
                try:
                    msg = self.mav.parse_char(data[i : i + size])
                except mavlink.MAVError:
                    msg = None
                if msg is not None and msg.get_type() != "BAD_DATA":
                    out.append(msg)
            i += size
        return out

    def connect(self, timeout_s: float = 20.0) -> None:
        hb = self.wait({mavlink.MAVLINK_MSG_ID_HEARTBEAT}, timeout_s)
        assert hb is not None, "no heartbeat from the vehicle"
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    # -- commands --------------------------------------------------------------------------------

    def command(self, command: int, *params: float, timeout_s: float = 5.0) -> int | None:
        """COMMAND_LONG; the ACK's result, or None without one."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(self.target, 1, command, 0, *p))
        ack = self.wait({mavlink.MAVLINK_MSG_ID_COMMAND_ACK}, timeout_s, lambda m: m.command == command)
        return None if ack is None else ack.result

    def command_with_texts(self, command: int, *params: float, listen_s: float) -> tuple[int | None, list[str]]:
        """COMMAND_LONG; the ACK's result and every STATUSTEXT within ``listen_s``."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(self.target, 1, command, 0, *p))
        got = self.receive({mavlink.MAVLINK_MSG_ID_COMMAND_ACK, mavlink.MAVLINK_MSG_ID_STATUSTEXT}, listen_s)
        acks = [m.result for m in got if m.get_type() == "COMMAND_ACK" and m.command == command]
        return (acks[0] if acks else None), [m.text for m in got if m.get_type() == "STATUSTEXT"]

    # -- FTP -------------------------------------------------------------------------------------

    def ftp(self, opcode: int, data: bytes = b"", *, session: int = 0, offset: int = 0, size: int | None = None,
            listen_s: float = 1.0, until_eof: bool = False) -> list[FtpReply]:  # fmt: skip
        """One FTP request; its replies (for a burst: until the EOF NAK or a burst_complete)."""
        self._ftp_seq = (self._ftp_seq + 1) & 0xFFFF
        head = FTP_HEADER.pack(self._ftp_seq, session, opcode, len(data) if size is None else size, 0, 0, 0, offset)
        payload = list((head + data).ljust(251, b"\0"))
        self.send(mavlink.MAVLink_file_transfer_protocol_message(0, self.target, 1, payload))
        replies: list[FtpReply] = []
        end = time.monotonic() + listen_s
        while time.monotonic() < end:
            for m in self._poll({mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL}):
                raw = bytes(m.payload)
                seq, sess, op, n, req, burst, _pad, ofs = FTP_HEADER.unpack_from(raw)
                if req != opcode:
                    continue
                replies.append(FtpReply(seq, sess, op, req, burst, ofs, raw[12 : 12 + n]))
                if not until_eof or op == 129 or burst:
                    return replies
        return replies

    def ftp_list(self, path: str) -> tuple[list[bytes], int | None]:
        """Every entry of ``path`` (ListDirectory from offset 0 until the NAK), and the NAK code."""
        entries: list[bytes] = []
        while True:
            replies = self.ftp(3, path.encode(), offset=len(entries))
            if not replies:
                return entries, None
            r = replies[0]
            if r.opcode == 129:
                return entries, r.nak_code
            entries.extend(e for e in r.data.split(b"\0") if e)

    # -- shell -----------------------------------------------------------------------------------

    def shell(self, line: str, listen_s: float = 1.5) -> str:
        """Send ``line`` to the shell (SERIAL_CONTROL_DEV_SHELL) and collect the answer until
        the prompt comes back (or ``listen_s``)."""
        data = line.encode()
        while data:
            chunk, data = data[:70], data[70:]
            self.send(mavlink.MAVLink_serial_control_message(SHELL_DEVICE, SHELL_FLAGS, 0, 0, len(chunk), list(chunk.ljust(70, b"\0"))))
        out = b""
        end = time.monotonic() + listen_s
        while time.monotonic() < end:
            got = self._poll({mavlink.MAVLINK_MSG_ID_SERIAL_CONTROL})
            for m in got:
                out += bytes(m.data[: m.count])
            if out.endswith(b"> ") and len(out) > 2:
                break
        return out.decode(errors="replace")

    # -- offboard --------------------------------------------------------------------------------

    def position_target(self, frame: int, mask: int, *, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), yaw: float = 0.0) -> None:
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            0, self.target, 1, frame, mask, *pos, *vel, 0, 0, 0, yaw, 0))  # fmt: skip


VELOCITY_YAW_MASK = 0b0000_1001_1100_0111  # positions, accelerations, yaw rate ignored; velocity and yaw used
POSITION_YAW_MASK = 0b0000_1001_1111_1000  # velocities, accelerations, yaw rate ignored
HALF_PI = math.pi / 2
