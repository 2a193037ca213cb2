"""MAVLink FTP (FILE_TRANSFER_PROTOCOL) over one read-only folder, answered as PX4's
``src/modules/mavlink/mavlink_ftp.cpp`` answers (measured on PX4 v1.16 SITL, docs/parity/services.md).

Pure: ``FtpServer.handle(payload) -> list of reply payloads``; no sockets, no clock. The folder
(``root``) is the plant's log folder (``--ftp-root``, by default the folder of ``--log``); a path
is taken relative to it, ``/`` being the folder itself, and a path that leads outside it (``..``,
a symbolic link out) is answered as a missing file. Nothing is ever written: the write opcodes
are answered NAK FileProtected (PX4 SITL would write into its working folder).

Wire format (https://mavlink.io/en/services/ftp.html): the 251-byte payload is a 12-byte header
``<HBBBBBBI`` (seq, session, opcode, size, req_opcode, burst_complete, padding, offset) and up to
239 data bytes. A reply carries seq + 1, the request's session, opcode and offset, ACK (128) or
NAK (129) with the error code as data (FailErrno: the code and errno).
"""

from __future__ import annotations

import errno
import os
import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251
MAX_DATA = PAYLOAD_LEN - HEADER.size  # 239, PX4's kMaxDataLength
#: Chunks answered per BurstReadFile request before ``burst_complete`` asks the client to
#: continue (PX4 streams to the end of the file; bounded here so one request never floods the link).
BURST_CHUNKS = 64


class Op(IntEnum):
    """Opcodes (mavlink_ftp.h ``Opcode``)."""

    NONE = 0
    TERMINATE_SESSION = 1
    RESET_SESSIONS = 2
    LIST_DIRECTORY = 3
    OPEN_FILE_RO = 4
    READ_FILE = 5
    CREATE_FILE = 6
    WRITE_FILE = 7
    REMOVE_FILE = 8
    CREATE_DIRECTORY = 9
    REMOVE_DIRECTORY = 10
    OPEN_FILE_WO = 11
    TRUNCATE_FILE = 12
    RENAME = 13
    CALC_FILE_CRC32 = 14
    BURST_READ_FILE = 15
    ACK = 128
    NAK = 129


class Err(IntEnum):
    """NAK error codes (mavlink_ftp.h ``ErrorCode``)."""

    NONE = 0
    FAIL = 1
    FAIL_ERRNO = 2
    INVALID_DATA_SIZE = 3
    INVALID_SESSION = 4
    NO_SESSIONS_AVAILABLE = 5
    EOF = 6
    UNKNOWN_COMMAND = 7
    FILE_EXISTS = 8
    FILE_PROTECTED = 9
    FILE_NOT_FOUND = 10


WRITE_OPS = (Op.CREATE_FILE, Op.WRITE_FILE, Op.REMOVE_FILE, Op.CREATE_DIRECTORY, Op.REMOVE_DIRECTORY,
             Op.OPEN_FILE_WO, Op.TRUNCATE_FILE, Op.RENAME)  # fmt: skip


class FtpFormatError(ValueError):
    """A FILE_TRANSFER_PROTOCOL payload too short to hold the header."""


@dataclass(frozen=True)
class FtpPayload:
    """One FTP payload (request or reply)."""

    seq: int
    session: int
    opcode: int
    size: int
    req_opcode: int
    burst_complete: int
    offset: int
    data: bytes = b""

    def pack(self) -> bytes:
        """The 251 bytes of FILE_TRANSFER_PROTOCOL.payload (data zero-padded)."""
        head = HEADER.pack(self.seq & 0xFFFF, self.session, self.opcode, self.size, self.req_opcode, self.burst_complete, 0, self.offset)
        return (head + self.data[:MAX_DATA]).ljust(PAYLOAD_LEN, b"\0")

    @classmethod
    def unpack(cls, payload: bytes | bytearray | list[int]) -> FtpPayload:
        """The FTP header and data of a FILE_TRANSFER_PROTOCOL payload; ``FtpFormatError`` when shorter than
        the header.
        """
        raw = bytes(payload)
        if len(raw) < HEADER.size:
            raise FtpFormatError(f"FTP payload of {len(raw)} bytes, shorter than its {HEADER.size}-byte header")
        seq, session, opcode, size, req, burst, _pad, offset = HEADER.unpack_from(raw)
        return cls(seq, session, opcode, size, req, burst, offset, raw[HEADER.size : HEADER.size + min(size, MAX_DATA)])

    @property
    def path(self) -> str:
        """The data as a path (up to the first NUL)."""
        return self.data.split(b"\0", 1)[0].decode("utf-8", "replace")


def crc32(data: bytes, crc: int = 0) -> int:
    """PX4's ``crc32part`` (src/lib/crc): the reflected CRC-32 table of zlib, but started at
    ``crc`` (0) with no final inversion; zlib's ``crc32`` inverts on entry and exit, so undo both.
    (PX4 v1.16 answers 0x44D62841 for its etc/init.d-posix/rcS, zlib 0x1792ED84.)"""
    return (zlib.crc32(data, crc ^ 0xFFFFFFFF) ^ 0xFFFFFFFF) & 0xFFFFFFFF


class FtpServer:
    """The FTP service of one vehicle over the folder ``root`` (None: no folder, every path missing).

    Parameters
    ----------
    root : path or None
        The folder exposed as ``/``, read-only.
    burst_chunks : int
        Chunks per BurstReadFile request (``BURST_CHUNKS``).
    """

    def __init__(self, root: str | Path | None, *, burst_chunks: int = BURST_CHUNKS) -> None:
        self.root = None if root is None else Path(root).resolve()
        self.burst_chunks = burst_chunks
        self._session: tuple[int, Path, int] | None = None  # (id, file, size at open)
        self._last: tuple[int, int, list[bytes]] | None = None  # (seq, opcode, replies): PX4 resends a repeated request's reply

    # -- the protocol ----------------------------------------------------------------------------

    def handle(self, payload: bytes | bytearray | list[int]) -> list[bytes]:
        """Answer one request payload: the reply payloads to send, in order (several for a burst).

        Raises
        ------
        FtpFormatError
            ``payload`` shorter than the header.
        """
        req = FtpPayload.unpack(payload)
        if req.opcode in (Op.ACK, Op.NAK):
            return []  # a reply (another vehicle's, echoed): not for us
        if self._last is not None and self._last[:2] == (req.seq, req.opcode) and req.opcode != Op.BURST_READ_FILE:
            return list(self._last[2])  # the reply was lost: the same again (mavlink_ftp.cpp's last-reply resend)
        replies = [r.pack() for r in self._dispatch(req)]
        self._last = (req.seq, req.opcode, replies)
        return replies

    def _dispatch(self, req: FtpPayload) -> list[FtpPayload]:
        op = req.opcode
        if op == Op.LIST_DIRECTORY:
            return [self._list(req)]
        if op == Op.OPEN_FILE_RO:
            return [self._open(req)]
        if op == Op.READ_FILE:
            return [self._read(req)]
        if op == Op.BURST_READ_FILE:
            return self._burst(req)
        if op == Op.TERMINATE_SESSION:
            if self._session is None or self._session[0] != req.session:
                return [_nak(req, Err.INVALID_SESSION)]
            self._session = None
            return [_ack(req)]
        if op == Op.RESET_SESSIONS:
            self._session = None
            return [_ack(req)]
        if op == Op.CALC_FILE_CRC32:
            return [self._crc(req)]
        if op in WRITE_OPS:
            return [_nak(req, Err.FILE_PROTECTED)]
        return [_nak(req, Err.UNKNOWN_COMMAND)]

    def _resolve(self, text: str) -> Path | None:
        """The file or folder ``text`` names inside the root, or None (missing, or outside)."""
        if self.root is None or "\0" in text:
            return None
        try:
            path = (self.root / text.lstrip("/")).resolve()
        except (OSError, RuntimeError):
            return None
        if path != self.root and self.root not in path.parents:
            return None
        return path if path.exists() else None

    def _list(self, req: FtpPayload) -> FtpPayload:
        folder = self._resolve(req.path)
        if folder is None:
            return _nak(req, Err.FILE_NOT_FOUND)
        if not folder.is_dir():
            return _nak(req, Err.FAIL_ERRNO, errno.ENOTDIR)
        entries = [b"S", b"S"] + [_entry(folder, name) for name in sorted(os.listdir(folder))]  # readdir's "." and ".." first
        if req.offset >= len(entries):
            return _nak(req, Err.EOF)
        data = b""
        for entry in entries[req.offset :]:
            if len(data) + len(entry) + 1 > MAX_DATA:  # PX4: offset + nameLen + 2 > kMaxDataLength
                break
            data += entry + b"\0"
        return _ack(req, data)

    def _open(self, req: FtpPayload) -> FtpPayload:
        if self._session is not None:
            return _nak(req, Err.NO_SESSIONS_AVAILABLE)  # PX4 has one session
        path = self._resolve(req.path)
        if path is None:
            return _nak(req, Err.FILE_NOT_FOUND)
        if not path.is_file():
            return _nak(req, Err.FAIL_ERRNO, errno.EISDIR)
        size = path.stat().st_size
        self._session = (0, path, size)
        return FtpPayload(req.seq + 1, 0, Op.ACK, 4, req.opcode, 0, req.offset, struct.pack("<I", size))

    def _chunk(self, offset: int, size: int) -> bytes:
        assert self._session is not None
        with self._session[1].open("rb") as fh:
            fh.seek(offset)
            return fh.read(size)

    def _read(self, req: FtpPayload) -> FtpPayload:
        if self._session is None or self._session[0] != req.session:
            return _nak(req, Err.INVALID_SESSION)
        size = req.size if 0 < req.size <= MAX_DATA else MAX_DATA
        data = self._chunk(req.offset, size)
        if not data:
            return _nak(req, Err.EOF)
        return _ack(req, data)

    def _burst(self, req: FtpPayload) -> list[FtpPayload]:
        if self._session is None or self._session[0] != req.session:
            return [_nak(req, Err.INVALID_SESSION)]
        out: list[FtpPayload] = []
        offset, seq = req.offset, req.seq + 1
        block = self._chunk(offset, MAX_DATA * self.burst_chunks)
        for start in range(0, len(block), MAX_DATA):
            data = block[start : start + MAX_DATA]
            out.append(FtpPayload(seq, req.session, Op.ACK, len(data), req.opcode, 0, offset + start, data))
            seq += 1
        end = offset + len(block)
        if len(block) < MAX_DATA * self.burst_chunks or not self._chunk(end, 1):
            out.append(FtpPayload(seq, req.session, Op.NAK, 1, req.opcode, 0, end, bytes([Err.EOF])))  # as PX4: EOF ends the stream
        else:
            last = out[-1]
            out[-1] = FtpPayload(last.seq, last.session, last.opcode, last.size, last.req_opcode, 1, last.offset, last.data)
        return out

    def _crc(self, req: FtpPayload) -> FtpPayload:
        path = self._resolve(req.path)
        if path is None:
            return _nak(req, Err.FILE_NOT_FOUND)  # PX4: FileNotFound when open() says ENOENT
        if not path.is_file():
            return _nak(req, Err.FAIL_ERRNO, errno.EISDIR)
        crc = 0
        with path.open("rb") as fh:
            while block := fh.read(1 << 16):
                crc = crc32(block, crc)
        return _ack(req, struct.pack("<I", crc))


def _entry(folder: Path, name: str) -> bytes:
    """One ListDirectory entry: ``F<name>\\t<size>``, ``D<name>``, or ``S`` (skipped: links and
    other kinds, as PX4 skips what is neither a regular file nor a folder)."""
    path = folder / name
    if path.is_symlink():
        return b"S"
    if path.is_file():
        return b"F" + name.encode("utf-8", "replace") + b"\t" + str(path.stat().st_size).encode()
    if path.is_dir():
        return b"D" + name.encode("utf-8", "replace")
    return b"S"


def _ack(req: FtpPayload, data: bytes = b"") -> FtpPayload:
    return FtpPayload(req.seq + 1, req.session, Op.ACK, len(data), req.opcode, 0, req.offset, data)


def _nak(req: FtpPayload, err: Err, errno_value: int | None = None) -> FtpPayload:
    data = bytes([err]) if errno_value is None else bytes([err, errno_value & 0xFF])
    return FtpPayload(req.seq + 1, req.session, Op.NAK, len(data), req.opcode, 0, req.offset, data)
