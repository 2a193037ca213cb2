"""A log streamed again: the logged messages re-sent in their original timing."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

from pymavlink import mavutil

from offboard import codec
from offboard.replay.reader import LoggedMessage


def stream_log(
    messages: Iterator[LoggedMessage],
    send: Callable[[bytes], None],
    *,
    speed: float = 1.0,
    systems: set[int] | None = None,
    clock: Callable[[], float] | None = None,
    sleep: Callable[[float], None] | None = None,
) -> int:
    """Re-send logged messages in their original timing (``speed`` times faster).

    Only the messages of ``systems`` (default: all) are sent, each once: a plant logs every
    telemetry message once per link, so a message identical to one already sent at the same
    tlog time by the same source is skipped. Packets are re-packed with one sequence counter
    per source, as a single live link would carry them. Unknown message types are passed on
    unchanged.

    Returns
    -------
    int
        Messages sent.
    """
    import time

    clock = time.monotonic if clock is None else clock
    sleep = time.sleep if sleep is None else sleep
    packers: dict[tuple[int, int], mavutil.mavlink.MAVLink] = {}
    sent_now: set[tuple[int, int, int, bytes]] = set()
    now_stamp = math.nan
    t_first = math.nan
    wall_first = 0.0
    count = 0
    for logged in messages:
        msg = logged.msg
        kind = msg.get_type()
        if kind == "BAD_DATA":
            continue
        src = codec.frame_header(msg)[1:] if kind.startswith("UNKNOWN") else (msg.get_srcSystem(), msg.get_srcComponent())
        if systems is not None and src[0] not in systems:
            continue
        if logged.time_s != now_stamp:
            now_stamp = logged.time_s
            sent_now.clear()
        payload = bytes(msg.get_payload()) if hasattr(msg, "get_payload") and msg.get_payload() is not None else b""
        key = (src[0], src[1], msg.get_msgId(), payload)
        if key in sent_now:
            continue
        sent_now.add(key)
        if math.isnan(t_first):
            t_first, wall_first = logged.time_s, clock()
        due = wall_first + (logged.time_s - t_first) / speed
        wait = due - clock()
        if wait > 0:
            sleep(wait)
        if kind.startswith("UNKNOWN"):
            send(bytes(msg.get_msgbuf()))
        else:
            packer = packers.get(src)
            if packer is None:
                packer = packers[src] = mavutil.mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
            send(bytes(msg.pack(packer)))
            packer.seq = (packer.seq + 1) % 256
        count += 1
    return count
