"""The report on the log itself: sources and their packet loss, message rates and gaps, events,
and the setpoints' latency in the vehicle's clock where the log holds their ATTITUDE_TARGET echo."""

from __future__ import annotations

import math
from dataclasses import dataclass

from offboard.echo import SetpointEcho, echo_words
from offboard.replay.reader import Damage, TlogReader
from offboard.replay.scan import Event, LogScan

#: SET_ATTITUDE_TARGET's type_mask bit: the attitude ignored (body rates flown), nothing to echo
_ATTITUDE_IGNORE = 128


@dataclass(frozen=True)
class SourceStats:
    """Packets of one (system, component) and their loss from sequence numbers."""

    system: int
    component: int
    role: str
    received: int
    lost: int
    duplicates: int
    counters: int  # interleaved sequence counters (a plant logging two links has 2)

    @property
    def loss_percent(self) -> float:
        """Packets lost, % of those sent (received + lost)."""
        total = self.received + self.lost
        return 100.0 * self.lost / total if total else 0.0


@dataclass(frozen=True)
class MessageRate:
    """One message type from one source: count, mean rate and the largest gap (tlog time)."""

    system: int
    component: int
    message: str
    count: int
    rate_hz: float
    max_gap_s: float
    max_gap_at_s: float  # relative to the record's t = 0


@dataclass(frozen=True)
class LogReport:
    """What the log says about the link and the vehicle, beside the tracking figures."""

    path: str
    size_bytes: int
    messages: int
    unknown_messages: int
    start_unix_s: float
    duration_s: float
    damages: list[Damage]
    sources: list[SourceStats]
    rates: list[MessageRate]
    events: list[Event]  # times relative to the record's t = 0
    vehicle_sysid: int | None
    #: the record's seconds per second of the log: 1, or the vehicle's clock rate where the flight
    #: was sampled on it (events, gaps and rates are then on that clock; ``duration_s`` is the log's)
    clock_rate: float = 1.0
    #: the setpoints' latency in the vehicle's clock from its ATTITUDE_TARGET echo
    #: (``setpoint_echo``; None: no echo of a setpoint in the log)
    setpoint_echo: dict | None = None

    def to_dict(self) -> dict:
        """The report for summary.json."""
        return {
            "path": self.path,
            "size_bytes": self.size_bytes,
            "messages": self.messages,
            "unknown_messages": self.unknown_messages,
            "start_unix_s": self.start_unix_s,
            "duration_s": self.duration_s,
            "vehicle_sysid": self.vehicle_sysid,
            "clock_rate": self.clock_rate,
            "damages": [{"offset": d.offset, "resumed_at": d.resumed_at, "reason": d.reason} for d in self.damages],
            "sources": [dict(vars(s), loss_percent=s.loss_percent) for s in self.sources],
            "rates": [vars(r) for r in self.rates],
            "events": [vars(e) for e in self.events],
            "setpoint_echo": self.setpoint_echo,
        }


def log_report(reader: TlogReader, scan: LogScan, t0_log_s: float, clock_rate: float = 1.0) -> LogReport:
    """Statistics and events of a scanned log; times relative to ``t0_log_s`` (tlog time), in
    seconds of the record: ``clock_rate`` of them per second of the log (a flight sampled on the
    vehicle's clock, which ran faster: its events, gaps and stream rates on that clock)."""
    vehicle = scan.vehicle_sysid()
    sources = [
        SourceStats(s, c, scan.role((s, c)), k.received, k.lost, k.duplicates, k.streams)
        for (s, c), k in sorted(scan.seq.items())
    ]
    rates = [
        MessageRate(s, c, m, st.count, st.rate_hz / clock_rate, st.max_gap_s * clock_rate, (st.max_gap_at_s - t0_log_s) * clock_rate)
        for (s, c, m), st in sorted(scan.streams.items())
    ]
    events = [Event((e.time_s - t0_log_s) * clock_rate, e.kind, e.text, e.system) for e in scan.events]
    return LogReport(
        path=str(reader.path),
        size_bytes=reader.size_bytes,
        messages=scan.messages,
        unknown_messages=scan.unknown_messages,
        start_unix_s=scan.first_time_s,
        duration_s=scan.last_time_s - scan.first_time_s if scan.messages else 0.0,
        damages=list(reader.damages),
        sources=sources,
        rates=rates,
        events=events,
        vehicle_sysid=vehicle,
        clock_rate=clock_rate,
        setpoint_echo=setpoint_echo(scan, vehicle),
    )


def setpoint_echo(scan: LogScan, vehicle: int | None) -> dict | None:
    """The setpoints' latency in the vehicle's clock (``offboard.echo``, as ``offboard fly``
    measures it in flight): the log's SET_ATTITUDE_TARGETs to ``vehicle`` that carry an attitude
    and the vehicle's ATTITUDE_TARGETs, paired in the order logged (either side's tlog: the
    offboard's, or a plant's). None where none pairs (a log of a flight that switched the echo
    off, or of no offboard attitude setpoints)."""
    if vehicle is None:
        return None
    sent = [r for r in scan.set_attitude.get(vehicle, []) if not int(r[1]) & _ATTITUDE_IGNORE]
    echoes = scan.attitude_targets.get(vehicle, [])
    if not sent or not echoes:
        return None
    # in the order logged (the message's place in the log: the order the flight handled them, which
    # two writes within one microsecond of the wall clock, or a clock stepped back, would not keep)
    order = sorted([(r[-1], 0, k) for k, r in enumerate(sent)] + [(r[6], 1, k) for k, r in enumerate(echoes)])
    echo = SetpointEcho()
    for _, kind, k in order:
        if kind == 0:
            r = sent[k]
            echo.sent(r[0], r[2:6], r[9])
        else:
            r = echoes[k]
            echo.echoed(r[0], r[1:5], r[5])
    figures = echo.figures()
    return figures if figures["paired"] else None


def format_log_report(report: LogReport, all_rates: bool = False) -> str:
    """Plain-text tables: sources and loss, message rates and gaps, events."""
    lines = [f"log {report.path}: {report.size_bytes} bytes, {report.messages} messages"
             + (f" ({report.unknown_messages} of unknown type)" if report.unknown_messages else "")
             + f", {report.duration_s:.2f} s, vehicle system {report.vehicle_sysid}"
             + (f"; times, gaps and rates below on the vehicle's clock, which ran at {report.clock_rate:.2f}x the log's"
                if report.clock_rate != 1.0 else "")]
    for d in report.damages:
        resumed = "nothing readable after it" if d.resumed_at is None else f"resumed at byte {d.resumed_at}"
        lines.append(f"  damaged at byte {d.offset}: {d.reason}; {resumed}")
    lines.append("")
    lines.append(f"{'source':<10} {'role':<20} {'received':>9} {'lost':>7} {'loss %':>7} {'dup':>5} {'counters':>8}")
    for s in report.sources:
        lines.append(f"{s.system:>3}/{s.component:<6} {s.role:<20} {s.received:>9} {s.lost:>7} {s.loss_percent:>7.2f} "
                     f"{s.duplicates:>5} {s.counters:>8}")
    lines.append("")
    lines.append(f"{'source':<10} {'message':<30} {'count':>7} {'rate Hz':>8} {'max gap s':>10} {'at t s':>8}")
    shown = report.rates if all_rates else [r for r in report.rates if r.count > 1]
    for r in shown:
        # a burst (all at one instant, as the parameter requests) has no rate and no gap: "-"
        rate = f"{r.rate_hz:>8.2f}" if math.isfinite(r.rate_hz) else f"{'-':>8}"
        at = f"{r.max_gap_at_s:>8.2f}" if math.isfinite(r.max_gap_at_s) else f"{'-':>8}"
        lines.append(f"{r.system:>3}/{r.component:<6} {r.message:<30} {r.count:>7} {rate} {r.max_gap_s:>10.3f} {at}")
    if report.setpoint_echo is not None:
        lines.append("")
        lines.append(echo_words(report.setpoint_echo))
    if report.events:
        lines.append("")
        lines.append("events (t s, system):")
        for e in report.events:
            lines.append(f"  {e.time_s:9.2f}  {e.system:>3}  {e.kind:<9} {e.text}")
    return "\n".join(lines)
