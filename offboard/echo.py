"""When the vehicle took each setpoint, in its own clock: the ATTITUDE_TARGET echo.

PX4 streams ATTITUDE_TARGET with the attitude setpoint it flies (the quaternion copied float for
float; the thrust the norm of the thrust vector, which is the thrust sent) and the time it took
it: ``time_boot_ms`` is the ``vehicle_attitude_setpoint``'s timestamp, which in offboard its
MAVLink receiver sets on each SET_ATTITUDE_TARGET (PX4
``src/modules/mavlink/streams/ATTITUDE_TARGET.hpp``). Our SET_ATTITUDE_TARGET carries the stamp
of the ATTITUDE it answers. A setpoint's echo, found by its quaternion and thrust together (a
still hover sends the same attitude many samples running, rarely the same thrust), therefore
gives the loop's latency in the vehicle's clock: from the instant the telemetry measured to the
instant the vehicle took the answer, both stamps the vehicle's. It is the latency the law's
prediction carries the state over, measured where it happens: at any ``--speed`` (where the
offboard's own clock is not the vehicle's) and over any link, asymmetric ones included, where the
offboard's round trip says only the sum of both ways.

PX4's stream sends the latest setpoint taken, so at 10 Hz (its default on the API link) every
other setpoint of a 20 Hz law is echoed. A setpoint equal to the one sent before it (attitude and
thrust) cannot be told from it and is not paired; an echo of no setpoint of ours (another
module's, a position mode's) pairs nothing. ``bench/px4_log.py`` pairs the same setpoints against
PX4's own log (ULog), and ``tests/e2e/test_px4_flight.py`` checks that the two agree.
"""

from __future__ import annotations

import math
import struct
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

#: The ATTITUDE_TARGET rate asked for (Hz): PX4's default on its API link; each echo pairs the
#: latest setpoint the vehicle took.
ECHO_RATE_HZ = 10.0
#: Setpoints kept waiting for their echo: 3 s of a 20 Hz law, far beyond any latency paired.
PENDING = 64
#: The longest latency paired, ms: an echo later than this is of a setpoint long superseded.
MAX_LATENCY_MS = 2000.0

_KEY = struct.Struct("<5f")  # the quaternion and the thrust as the message carries them


class SetpointEcho:
    """Pairs the SET_ATTITUDE_TARGETs sent (``sent``) with the vehicle's ATTITUDE_TARGET echoes
    (``echoed``); ``latencies_ms`` holds each pair's latency (module docstring), ``figures()``
    their summary. Pure: no I/O, no clock."""

    def __init__(self) -> None:
        self._pending: OrderedDict[bytes, int] = OrderedDict()
        self._last: bytes | None = None
        self.latencies_ms: list[float] = []
        #: echoes of one of our setpoints stamped before the telemetry it answered: the two clocks
        #: are not one (a vehicle that stamps ATTITUDE_TARGET otherwise than PX4); not paired
        self.inconsistent = 0

    def sent(self, stamp_ms: int, q_wxyz: Sequence[float], thrust: float) -> None:
        """A SET_ATTITUDE_TARGET went out answering the telemetry of ``stamp_ms`` with attitude
        ``q_wxyz`` and normalised ``thrust``."""
        key = _KEY.pack(*q_wxyz, thrust)
        if key == self._last:
            self._pending.pop(key, None)  # the same setpoint again: whose echo it is cannot be told
            return
        self._last = key
        pending = self._pending
        pending[key] = int(stamp_ms)
        pending.move_to_end(key)
        if len(pending) > PENDING:
            pending.popitem(last=False)

    def echoed(self, stamp_ms: int, q_wxyz: Sequence[float], thrust: float) -> float | None:
        """The vehicle's ATTITUDE_TARGET of ``stamp_ms``: the latency of the setpoint it echoes, ms
        (None: not one of ours waiting, or inconsistent)."""
        sent_ms = self._pending.pop(_KEY.pack(*q_wxyz, thrust), None)
        if sent_ms is None:
            return None
        latency = float(int(stamp_ms) - sent_ms)
        if not 0.0 <= latency <= MAX_LATENCY_MS:
            self.inconsistent += 1
            return None
        self.latencies_ms.append(latency)
        return latency

    def figures(self) -> dict:
        """``latency_figures`` of the latencies paired."""
        return latency_figures(self.latencies_ms)


def latency_figures(latencies_ms: Sequence[float]) -> dict:
    """``{"paired", "p50_ms", "p90_ms", "max_ms"}``: how many latencies (the finite ones), their
    median, 90th percentile and largest, ms (None for none)."""
    values = np.asarray([v for v in latencies_ms if math.isfinite(v)], dtype=float)
    if values.size == 0:
        return {"paired": 0, "p50_ms": None, "p90_ms": None, "max_ms": None}
    p50, p90 = np.percentile(values, [50, 90])
    return {"paired": int(values.size), "p50_ms": round(float(p50), 2), "p90_ms": round(float(p90), 2),
            "max_ms": round(float(values.max()), 2)}  # fmt: skip


def echo_words(figures: dict, designed_s: float | None = None) -> str:
    """One line of the flight's summary: the echo's figures against the latency designed for."""
    if not figures["paired"]:
        return "setpoint echo: none paired (no ATTITUDE_TARGET from the vehicle echoed one of our setpoints)"
    designed = "" if designed_s is None else f"; the law was designed for {designed_s * 1000.0:.0f} ms"
    return (f"setpoint echo: the vehicle took the setpoints {figures['p50_ms']:g} ms (median), {figures['p90_ms']:g} ms "
            f"(90 %), at most {figures['max_ms']:g} ms after the telemetry they answer, in its clock "
            f"({figures['paired']} ATTITUDE_TARGET echoes){designed}")
