"""The tlog writer leaves whole records on disk whenever its buffer reaches the file (issue 14)."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from offboard.model.tlog import TlogWriter


def _packets() -> list[bytes]:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return [
        mavlink.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3).pack(mav),
        mavlink.MAVLink_attitude_message(10, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0).pack(mav),
        mavlink.MAVLink_statustext_message(6, b"a status text of some length").pack(mav),
    ]


def test_the_file_on_disk_always_ends_on_a_whole_record(tmp_path):
    """Read the file as a killed process would leave it, after every record: its size is always a
    record boundary. Writing the stamp and the packet separately left the stamp alone on disk
    whenever the packet was the write that flushed the buffer."""
    path = tmp_path / "flight.tlog"
    writer = TlogWriter(path)
    packets = _packets()
    boundaries = {0}
    end = 0
    sizes_seen = set()
    for i in range(3000):
        packet = packets[i % len(packets)]
        writer.write(1_700_000_000_000_000 + i, packet)
        end += 8 + len(packet)
        boundaries.add(end)
        size = path.stat().st_size
        sizes_seen.add(size)
        assert size in boundaries, f"record {i}: {size} bytes on disk is inside a record"
    assert len(sizes_seen) > 5  # the buffer did reach the disk several times on the way
    writer.close()
    assert path.stat().st_size == end and writer.records == 3000
