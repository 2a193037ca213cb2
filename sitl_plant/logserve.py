"""Log download (LOG_REQUEST_LIST / LOG_ENTRY, LOG_REQUEST_DATA / LOG_DATA, LOG_REQUEST_END,
LOG_ERASE) serving the plant's own tlog, as PX4's ``src/modules/mavlink/mavlink_log_handler.cpp``
serves its .ulg files (measured on PX4 v1.16 SITL: docs/parity/services.md).

Pure: ``LogServer`` answers requests with message lists and hands out the LOG_DATA of a running
download in bounded batches (``pump``) that the plant's loop sends as it goes, as PX4 streams a
download at the link's rate. No sockets, no clock; it reads the file.

The plant has one log, the tlog it writes (``--log``), id 0. Its size is taken at each
LOG_REQUEST_LIST (what is on disk then; the plant flushes its tlog every second) and a download
serves that many bytes, so a listed size and the bytes downloaded agree while the file grows.
``time_utc`` is the Unix time (s) of the tlog's first record, i.e. when the log began. LOG_ERASE
is acknowledged by nothing, as PX4, but the plant keeps the file: it is the user's run record.
"""

from __future__ import annotations

import struct
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

DATA_LEN = 90  # LOG_DATA.data
#: LOG_DATA messages per ``pump`` (per tick of the plant's loop: 4 ms in real time)
PUMP_BATCH = 32


class LogServer:
    """The logs of one vehicle: the file at ``path`` (None: the plant writes no log)."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = None if path is None else Path(path)
        self._listed_size: int | None = None
        self._download: tuple[int, int, int] | None = None  # (id, next offset, end offset)

    def _size_now(self) -> int | None:
        if self.path is None:
            return None
        try:
            return self.path.stat().st_size
        except OSError:
            return None

    def _time_utc(self) -> int:
        """The first tlog record's stamp (µs since the Unix epoch, big-endian), in seconds."""
        try:
            with self.path.open("rb") as fh:  # type: ignore[union-attr]
                head = fh.read(8)
        except OSError:
            return 0
        return struct.unpack(">Q", head)[0] // 1_000_000 if len(head) == 8 else 0

    def request_list(self, start: int, end: int) -> list[mavlink.MAVLink_message]:
        """LOG_ENTRY for each id in [start, end] that exists; with no log, one LOG_ENTRY of
        zeros (``num_logs`` 0), as PX4 answers an empty log folder."""
        size = self._size_now()
        if size is None:
            return [mavlink.MAVLink_log_entry_message(0, 0, 0, 0, 0)]
        self._listed_size = size
        if start > 0 or end < 0:
            return []
        return [mavlink.MAVLink_log_entry_message(0, 1, 1, self._time_utc(), size)]  # last_log_num = num_logs, as PX4 v1.16

    def request_data(self, log_id: int, offset: int, count: int) -> list[mavlink.MAVLink_message]:
        """Start (or restart) the download of ``count`` bytes from ``offset``; the first batch.

        As PX4 v1.16 answers (measured): whole 90-byte messages until ``count`` is covered, at
        least one (count 50 gives 90 bytes, count 0 gives one message), the last one shorter at
        the end of the file; an unknown id, or an offset at or beyond the end, gets no answer.
        """
        size = self._listed_size if self._listed_size is not None else self._size_now()
        self._download = None
        if log_id != 0 or size is None or offset >= size:
            return []
        messages = max(1, -(-count // DATA_LEN))
        self._download = (log_id, offset, min(size, offset + messages * DATA_LEN))
        return self.pump()

    def pump(self, batch: int = PUMP_BATCH) -> list[mavlink.MAVLink_message]:
        """The next LOG_DATA of the running download (at most ``batch``); [] when none runs."""
        if self._download is None or self.path is None:
            return []
        log_id, offset, end = self._download
        want = min(end - offset, batch * DATA_LEN)
        try:
            with self.path.open("rb") as fh:
                fh.seek(offset)
                block = fh.read(want)
        except OSError:
            block = b""
        out = []
        for start in range(0, len(block), DATA_LEN):
            piece = block[start : start + DATA_LEN]
            out.append(mavlink.MAVLink_log_data_message(log_id, offset + start, len(piece), list(piece.ljust(DATA_LEN, b"\0"))))
        offset += len(block)
        self._download = None if (offset >= end or not block) else (log_id, offset, end)
        return out

    def request_end(self) -> None:
        """LOG_REQUEST_END: stop the download."""
        self._download = None

    def erase(self) -> None:
        """LOG_ERASE: nothing is deleted (module docstring); a running download stops."""
        self._download = None

    @property
    def downloading(self) -> bool:
        """Whether a LOG_REQUEST_DATA transfer is running."""
        return self._download is not None
