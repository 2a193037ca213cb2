"""How fast the vehicle's clock runs against ours, from its telemetry stamps (pure; no sockets).

``offboard fly`` samples on its own clock by default. A vehicle whose ``time_boot_ms`` runs at
another rate (PX4 SITL with ``PX4_SIM_SPEED_FACTOR``, ``sitl-plant --speed 5``) then sees a
sample time To times that rate: against ``sitl-plant --speed 5`` the helix's hold phase was
flown 4.2 m RMS off and reported complete. Before arming, the flight measures the rate over the
telemetry heard so far (at least ``CHECK_SPAN_S`` of our clock) and refuses a vehicle whose rate
is off by more than ``RATE_TOLERANCE`` (``--clock vehicle`` follows the vehicle's clock).

The estimate is robust to queueing: a message handled late only makes our stamp later, never
earlier, while the vehicle's stamps are exact. So of each end of the window (the first and the
last ``GROUP_FRACTION`` of the vehicle's span) the message with the smallest ``wall - boot``
(the least delayed) is taken, and the rate is the vehicle's advance between those two over ours.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Our clock's span the rate is measured over before arming (s).
CHECK_SPAN_S = 1.0
#: The window's ends, each searched for its least delayed message (fraction of the vehicle's span).
GROUP_FRACTION = 0.25
#: The rate must lie within [1 / (1 + tol), 1 + tol]. A real-time vehicle measured over one second
#: is within a few per cent (network and scheduling delays of milliseconds); the simulator speeds
#: people use are 2 and more, or 0.5.
RATE_TOLERANCE = 0.25
#: A rate below this is a vehicle whose clock hardly moves: one that waits for us (lockstep).
STALLED_RATE = 0.05


@dataclass(frozen=True)
class ClockRate:
    """The measured rate: the vehicle's seconds per second of ours, over ``span_s`` of ours."""

    rate: float
    span_s: float
    vehicle_span_s: float

    @property
    def real_time(self) -> bool:
        """Whether the vehicle's clock runs at ours, within ``RATE_TOLERANCE``."""
        return 1.0 / (1.0 + RATE_TOLERANCE) <= self.rate <= 1.0 + RATE_TOLERANCE

    def describe(self) -> str:
        """The measurement in one line (the rate, over which spans of both clocks)."""
        return (f"the vehicle's clock runs at {self.rate:.2f}x ours (its time_boot_ms advanced "
                f"{self.vehicle_span_s:.2f} s in {self.span_s:.2f} s of our clock)")  # fmt: skip


class ClockRateMeter:
    """Collects ``(our clock s, time_boot_ms)`` pairs and estimates the vehicle's clock rate."""

    def __init__(self) -> None:
        self._pairs: list[tuple[float, float]] = []

    def add(self, wall_s: float, time_boot_ms: int) -> None:
        """One pair: our clock (s) when a message stamped ``time_boot_ms`` arrived."""
        self._pairs.append((wall_s, time_boot_ms / 1000.0))

    @property
    def span_s(self) -> float:
        """Our clock's span of the pairs so far (0 without two)."""
        return self._pairs[-1][0] - self._pairs[0][0] if len(self._pairs) > 1 else 0.0

    def measure(self) -> ClockRate | None:
        """The rate over every pair so far; None before ``CHECK_SPAN_S`` of our clock."""
        if self.span_s < CHECK_SPAN_S:
            return None
        b0 = min(p[1] for p in self._pairs)
        b1 = max(p[1] for p in self._pairs)
        width = GROUP_FRACTION * (b1 - b0)
        first = min((p for p in self._pairs if p[1] <= b0 + width), key=lambda p: p[0] - p[1])
        last = min((p for p in self._pairs if p[1] >= b1 - width), key=lambda p: p[0] - p[1])
        span, vehicle_span = last[0] - first[0], last[1] - first[1]
        if span <= 0 or vehicle_span <= 0:  # a clock that does not move (or one group): end to end
            span, vehicle_span = self.span_s, self._pairs[-1][1] - self._pairs[0][1]
        return ClockRate(vehicle_span / span, span, vehicle_span)
