"""The tlog writer both processes record with (the reader is ``offboard.replay.reader.TlogReader``).

A tlog is what MAVProxy, QGroundControl and ``mavlogdump.py`` read: per packet, an 8-byte
big-endian timestamp (µs since the Unix epoch) and the raw MAVLink packet.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path
from typing import BinaryIO

from offboard.model.errors import LinkError
from offboard.model.paths import output_file_problem

_TLOG_STAMP = struct.Struct(">Q")

#: 2020-01-01T00:00:00Z: the origin of the tlog stamps (and SYSTEM_TIME) of a lockstep flight, on
#: both sides, so that two lockstep runs write the same bytes.
LOCKSTEP_EPOCH_S = 1_577_836_800


def wall_clock_us() -> int:
    """Microseconds since the Unix epoch (the tlog's usual timestamp)."""
    return time.time_ns() // 1000


class TlogWriter:
    """Appends ``(timestamp, packet)`` records to a tlog file; ``close()`` flushes.

    Each record goes to the file buffer in one write, so whenever the buffer reaches the disk (full,
    ``flush()``) it ends on a whole record: a process killed with SIGKILL leaves a log that ends on
    its last flushed record, never on a timestamp without its packet (issue 14: two writes left a
    dangling 8-byte stamp in 18 of 20 kills).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        problem = output_file_problem(self.path)  # the rule of every output file (offboard/model/paths.py)
        if problem is not None:
            raise LinkError(f"--log {self.path}: cannot write the log: {problem}")
        try:
            self._fh: BinaryIO | None = self.path.open("wb")
        except OSError as exc:
            raise LinkError(f"{self.path}: cannot write the log: {exc.strerror}") from None
        self.records = 0

    def write(self, time_us: int, packet: bytes | bytearray) -> None:
        """One record: the 8-byte big-endian stamp (microseconds since the Unix epoch), then the packet."""
        if self._fh is not None:
            self._fh.write(_TLOG_STAMP.pack(time_us) + packet)
            self.records += 1

    def flush(self) -> None:
        """Hand what is written so far to the operating system."""
        if self._fh is not None:
            self._fh.flush()

    def close(self) -> None:
        """Flush and close the file (further writes are dropped)."""
        if self._fh is not None:
            self._fh.flush()
            self._fh.close()
            self._fh = None
