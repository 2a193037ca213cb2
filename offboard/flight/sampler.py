"""When a flight samples, and what a sample is made of.

A sample takes the freshest ATTITUDE and LOCAL_POSITION_NED, hands the measured state to the
current setpoint source (before the mission: hold; during it: the controller; while landing:
idle) and sends the setpoint it returns. When one is due:

- in **lockstep**, when an ATTITUDE and a LOCAL_POSITION_NED with the same ``time_boot_ms`` T
  have arrived (the plant then waits for the setpoint echoing T);
- in **real time**, every To of our own (injected) clock, on the freshest telemetry, still
  echoing the ATTITUDE's ``time_boot_ms``;
- on the **vehicle's clock** (``SampleClock.VEHICLE``, for a vehicle that runs faster or slower
  than real time: PX4 SITL ``--speed``, ``sitl-plant --speed``), when the telemetry's
  ``time_boot_ms`` has advanced To since the last one.

``SampleClock.AUTO`` (``offboard fly``'s default) measures the vehicle's clock rate before
OFFBOARD (``offboard.clockrate``, with the ``clock_meter`` fed here) and samples on our clock if
it runs at ours, on the vehicle's if it does not. Every decision is taken while handling a
message or a sample, so a lockstep flight sends the same bytes every time.

``Sampler`` counts the ticks (one a period To, skipped ones included), and over the mission's
window (its first sample to its last) the ``LoopStats``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from offboard import codec
from offboard.clockrate import ClockRateMeter
from offboard.codec import MeasuredState
from offboard.errors import LockstepMismatch
from offboard.flight.config import FlightConfig, Link, SampleClock
from offboard.echo import SetpointEcho
from offboard.flight.supervisor import Supervisor
from offboard.record import RecordBuilder
from pymavlink.dialects.v20 import common as mavlink

#: What a sample sends: the setpoint answering a measured state (None: nothing to send).
SetpointSource = Callable[[MeasuredState], mavlink.MAVLink_message | None]

#: How much earlier than the kept message's stamp a message may be stamped and be one the link
#: reordered (ms); earlier still, the vehicle's clock has started again (a reboot) and it is kept.
OVERTAKEN_MS = 1000


def _overtaken(stamp_ms: int, kept_ms: int) -> bool:
    """Whether a message stamped ``stamp_ms`` is older than the kept one's ``kept_ms`` (reordered)."""
    return 0 < kept_ms - stamp_ms <= OVERTAKEN_MS


@dataclass
class LoopStats:
    """The sample clock's behaviour over the mission.

    The wall-clock periods between recorded samples are spooled like the record's rows
    (``RecordBuilder``: 8 bytes a period, in blocks, to a temporary file), so an hour's flight
    keeps none of them in memory and the summary's percentiles are still exact.
    """

    samples: int = 0
    overruns: int = 0  # real time: samples skipped because we were late by a whole period
    missed: int = 0  # real time: mission periods without a setpoint (telemetry stale)
    overtaken: int = 0  # telemetry not kept: stamped before the message kept (reordered by the link)
    mission_wall_s: float = 0.0
    periods: RecordBuilder = field(default_factory=lambda: RecordBuilder({"period_s": 1}), repr=False, compare=False)

    def add_period(self, period_s: float) -> None:
        """One wall-clock period between two recorded samples (s)."""
        self.periods.append(period_s=period_s)

    @property
    def periods_s(self) -> np.ndarray:
        """Every period added, in order (s)."""
        return self.periods.build()["period_s"]

    def to_dict(self, sample_time_s: float) -> dict:
        """The loop's figures for summary.json (samples, rate, period jitter against ``sample_time_s``,
        overruns, missed samples).
        """
        periods = self.periods_s
        jitter = np.abs(periods - sample_time_s) if len(periods) else np.zeros(1)
        return {
            "samples": self.samples,
            "overruns": self.overruns,
            "missed": self.missed,
            "telemetry_overtaken": self.overtaken,
            "mission_wall_s": self.mission_wall_s,
            "rate_hz": self.samples / self.mission_wall_s if self.mission_wall_s > 0 else math.nan,
            "period_mean_s": float(np.mean(periods)) if len(periods) else math.nan,
            "jitter_p50_ms": float(np.percentile(jitter, 50) * 1e3),
            "jitter_p99_ms": float(np.percentile(jitter, 99) * 1e3),
            "jitter_max_ms": float(np.max(jitter) * 1e3),
        }


class Sampler:
    """The freshest telemetry, the sample clock and the setpoint source (module docstring).

    Parameters
    ----------
    link : Link
        Where the setpoints go.
    config : FlightConfig
        ``lockstep`` and ``clock``.
    sample_time_s : float
        To (s): the controller's sample time; the flight sets ``to`` again once it is resolved.
    clock : callable
        Monotonic seconds (wall clock).
    supervisor : Supervisor
        Whether the telemetry is fresh enough to send on.

    Attributes
    ----------
    source : SetpointSource or None
        What a sample sends (None: no setpoints).
    samples_sent : int
        Setpoints sent so far.
    tick : int
        Periods To since the first sample, skipped ones included.
    on_vehicle_clock : bool
        Real time paced by the vehicle's ``time_boot_ms`` rather than by our clock.
    clock_meter : ClockRateMeter or None
        On our own clock in real time, until the flight has measured the vehicle's clock rate.
    mission_tick0 : int or None
        The tick of the mission's first sample; ``mission_samples``: the number of its last (the
        flight sets it); ``mission_done``: its last has been taken.
    loop : LoopStats
        The mission's samples, overruns and missed periods.
    """

    def __init__(self, link: Link, config: FlightConfig, sample_time_s: float, clock: Callable[[], float],
                 supervisor: Supervisor) -> None:  # fmt: skip
        self.link = link
        self.config = config
        self.to = sample_time_s
        #: the setpoints' echo (``offboard.echo``; None: not asked for; the flight decides once
        #: it knows the vehicle, ``FlightConfig.echoes_setpoints``)
        self.echo: SetpointEcho | None = None
        self.clock = clock
        self._supervisor = supervisor
        # the freshest telemetry
        self.att: mavlink.MAVLink_message | None = None
        self.lpn: mavlink.MAVLink_message | None = None
        self._recent_att: dict[int, mavlink.MAVLink_message] = {}  # by stamp: pairs for the position
        self._stamps_since_sample = 0  # distinct ATTITUDE stamps since the last lockstep sample
        # what a sample sends
        self.source: SetpointSource | None = None
        self.samples_sent = 0
        # the ticks
        self.tick = 0
        self._answered_ms: int | None = None
        self._prev_sample_ms: int | None = None
        self._next_tick_s: float | None = None
        self._next_tick_ms: float | None = None  # on the vehicle's clock
        self._sample_late_s = 0.0  # on the vehicle's clock: how long after its tick the sampled position came
        # on our own clock in real time the vehicle's clock must run at our rate (offboard.clockrate);
        # AUTO measures it and then follows the vehicle's clock if it does not
        self.on_vehicle_clock = not config.lockstep and config.clock == SampleClock.VEHICLE
        self.clock_meter: ClockRateMeter | None = None
        if not (config.lockstep or self.on_vehicle_clock):
            self.clock_meter = ClockRateMeter()
        # the mission's window
        self.mission_tick0: int | None = None
        self.mission_samples = 0  # the mission's last sample number (its samples are 0 ... this)
        self.mission_done = False
        self._mission_wall0: float | None = None
        self._last_sample_wall: float | None = None
        self._last_sample_t: float | None = None  # on the vehicle's clock: the last sample's mission time
        self.loop = LoopStats()

    # -- the telemetry -------------------------------------------------------------------------------

    def take(self, msg: mavlink.MAVLink_message) -> None:
        """Keep the vehicle's ATTITUDE or LOCAL_POSITION_NED as the freshest: one stamped earlier
        than the one kept, by at most ``OVERTAKEN_MS``, was overtaken on the way (a link that
        reorders: a radio, a network) and is not kept; one stamped far earlier is a vehicle
        whose clock started again, and is.

        Raises
        ------
        codec.BadTelemetry
            Not a usable one (not kept).
        """
        if msg.get_type() == "ATTITUDE":
            codec.check_attitude(msg)
            if self.att is not None and _overtaken(int(msg.time_boot_ms), int(self.att.time_boot_ms)):
                self.loop.overtaken += 1
                return
            if self.att is None or int(msg.time_boot_ms) != int(self.att.time_boot_ms):
                self._stamps_since_sample += 1  # a lockstep vehicle: one a period
            self.att = msg
            self._recent_att[int(msg.time_boot_ms)] = msg
            if len(self._recent_att) > codec.RECENT_ATTITUDES:
                del self._recent_att[next(iter(self._recent_att))]
        else:
            codec.check_local_position(msg)
            if self.lpn is not None and _overtaken(int(msg.time_boot_ms), int(self.lpn.time_boot_ms)):
                self.loop.overtaken += 1
                return
            self.lpn = msg

    def meter(self, msg: mavlink.MAVLink_message, now: float) -> None:
        """While the vehicle's clock rate is measured: an ATTITUDE's stamp against ``now`` (s)."""
        if self.clock_meter is not None and msg.get_type() == "ATTITUDE":
            self.clock_meter.add(now, int(msg.time_boot_ms))

    @property
    def has_telemetry(self) -> bool:
        """Whether an ATTITUDE and a LOCAL_POSITION_NED have come."""
        return self.att is not None and self.lpn is not None

    def boot_ms(self) -> int:
        """The latest ATTITUDE's ``time_boot_ms`` (ms; 0 before the first)."""
        return int(self.att.time_boot_ms) if self.att is not None else 0

    # -- when a sample is due ------------------------------------------------------------------------

    def lockstep_due(self) -> int | None:
        """In lockstep: the ``time_boot_ms`` (ms) whose sample is due, or None.

        Raises
        ------
        LockstepMismatch
            The vehicle advanced without waiting for us, or by another period than To.
        """
        if not self.config.lockstep or self.source is None or self.att is None or self.lpn is None:
            return None
        t_ms = int(self.att.time_boot_ms)
        if t_ms != int(self.lpn.time_boot_ms) or t_ms == self._answered_ms:
            return None
        if self._prev_sample_ms is not None:
            step = t_ms - self._prev_sample_ms
            if step != int(round(self.to * 1000)) and self.samples_sent > 1:
                if self._stamps_since_sample > 1:
                    # a lockstep vehicle sends one stamp a period and waits; this one did not wait
                    raise LockstepMismatch(f"the vehicle is not in lockstep: its ATTITUDE advanced {self._stamps_since_sample} "
                                           f"stamps ({step} ms) without waiting for our setpoint; start sitl-plant with "
                                           "--lockstep, or fly without --lockstep")  # fmt: skip
                raise LockstepMismatch(f"the lockstep plant advances {step} ms a period but the controller's To is "
                                       f"{self.to * 1000:g} ms: start sitl-plant with --lockstep-period {self.to:g}")
        return t_ms

    def sample_lockstep(self, t_ms: int) -> None:
        """In lockstep: the sample answering ``time_boot_ms`` t_ms (``lockstep_due``)."""
        if self.sample(self.clock()):  # unanswered (nothing to send yet): the plant still waits for it
            self._stamps_since_sample = 0
            self._prev_sample_ms = t_ms
            self._answered_ms = t_ms
            self.tick += 1

    def vehicle_clock_sample_if_due(self) -> None:
        """On the vehicle's clock: a sample when the position's ``time_boot_ms`` reaches the next
        tick (late by whole periods: those are skipped and counted, as in real time)."""
        if not self.on_vehicle_clock or self.source is None or self.att is None or self.lpn is None:
            return
        t_ms = float(self.lpn.time_boot_ms)
        period_ms = self.to * 1000.0
        if self._next_tick_ms is None:
            self._next_tick_ms = t_ms
        if t_ms < self._next_tick_ms:
            return
        late = t_ms - self._next_tick_ms
        if late >= period_ms:
            skipped = int(late // period_ms)
            self.loop.overruns += self._mission_ticks(self.tick, skipped)
            self.tick += skipped
            self._next_tick_ms += skipped * period_ms
        # the position came this long after the tick: the references are taken at its instant, so
        # that state and reference are of one time (the streams' stamps need not fall on the ticks:
        # sitl-plant's 100 Hz on its 4 ms steps are 8 and 12 ms apart, and the samples then fell
        # 40 and 60 ms apart, reading 2 m/s of helix as a 2 cm ripple of the error)
        self._sample_late_s = (t_ms - self._next_tick_ms) / 1000.0
        if not self.sample(self.clock()):
            self.loop.missed += self._mission_ticks(self.tick, 1)
        self.tick += 1
        self._next_tick_ms += period_ms

    def _mission_ticks(self, first: int, count: int) -> int:
        """How many of the ``count`` ticks from ``first`` are the mission's, from its first sample
        to its last (a late loop's skip, or a period without a setpoint, before the mission or
        past its end is not the mission's overrun or miss)."""
        if self.mission_tick0 is None or self.mission_done:
            return 0
        last = self.mission_tick0 + self.mission_samples
        return max(0, min(first + count - 1, last) - max(first, self.mission_tick0) + 1)

    def service(self, now: float) -> float:
        """On our own clock in real time: the sample due at ``now`` (s of the clock; late by whole
        periods: those are skipped and counted). Returns how long until the next is due (s; inf:
        not ours to time)."""
        if self.config.lockstep or self.on_vehicle_clock or self.source is None:
            return math.inf
        if self._next_tick_s is None:
            self._next_tick_s = now
        if now >= self._next_tick_s:
            late = now - self._next_tick_s
            if late >= self.to:  # a whole period late: skip the missed samples
                skipped = int(late // self.to)
                self.loop.overruns += self._mission_ticks(self.tick, skipped)
                self.tick += skipped
                self._next_tick_s += skipped * self.to
            if not self.sample(now):
                self.loop.missed += self._mission_ticks(self.tick, 1)  # no setpoint this period (telemetry stale)
            self.tick += 1
            self._next_tick_s += self.to
        return self._next_tick_s - self.clock()

    # -- a sample ------------------------------------------------------------------------------------

    def sample(self, now: float) -> bool:
        """Run the current setpoint source on the freshest telemetry; whether a setpoint went out."""
        source = self.source
        if source is None or self.att is None or self.lpn is None or self._supervisor.in_outage:
            return False
        if self.config.lockstep:
            # the plant waits for this answer: new telemetry is due within the timeout from now
            self._supervisor.heard(now)
        elif self._supervisor.stale(now):
            return False  # stale: the supervisor declares the outage
        try:
            # the attitude of the position's own instant when we have it: one coherent sample
            att = self._recent_att.get(int(self.lpn.time_boot_ms), self.att)
            measured = codec.measured_state(att, self.lpn)
        except codec.BadTelemetry:
            return False
        msg = source(measured)
        if msg is None:
            return False
        self.link.send(msg)
        self.samples_sent += 1
        if self.echo is not None and msg.get_type() == "SET_ATTITUDE_TARGET":
            self.echo.sent(msg.time_boot_ms, msg.q, msg.thrust)
        return True

    # -- the mission's window ------------------------------------------------------------------------

    @property
    def mission_started(self) -> bool:
        """Whether the mission's first sample has been taken."""
        return self.mission_tick0 is not None

    def mission_sample(self, now: float) -> tuple[int, float]:
        """(n, t): this sample's number in the mission and its mission time (s), the instant of its
        references (on the vehicle's clock, of its position). The first call starts the mission
        (``now``: s of the clock)."""
        if self.mission_tick0 is None:
            self.mission_tick0 = self.tick
            self._mission_wall0 = now
        n = self.tick - self.mission_tick0
        return n, n * self.to + (self._sample_late_s if self.on_vehicle_clock else 0.0)

    def recorded(self, now: float, mission_t_s: float | None = None) -> float:
        """A mission sample was recorded at ``now`` (s of the clock), at mission time
        ``mission_t_s``; its time since the mission's first (s). The loop's period is our clock's,
        or on the vehicle's clock the vehicle's between the samples' mission times (its To, and how
        late each came after its tick: our clock's would measure the vehicle's speed-up)."""
        if self.on_vehicle_clock and mission_t_s is not None:
            if self._last_sample_t is not None:
                self.loop.add_period(mission_t_s - self._last_sample_t)
            self._last_sample_t = mission_t_s
        elif self._last_sample_wall is not None:
            self.loop.add_period(now - self._last_sample_wall)
        self._last_sample_wall = now
        self.loop.samples += 1
        return now - (self._mission_wall0 or now)

    def finish(self) -> LoopStats:
        """The loop's figures at the flight's end: ``mission_wall_s`` runs from the mission's first
        sample to its last recorded one (or to now)."""
        if self._mission_wall0 is not None:
            end = self._last_sample_wall if self._last_sample_wall is not None else self.clock()
            self.loop.mission_wall_s = end - self._mission_wall0
        return self.loop
