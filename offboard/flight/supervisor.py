"""What a flight watches while it flies: is the telemetry still coming, and is the vehicle still
in OFFBOARD and armed?

``Supervisor`` keeps the watch and ends the flight (``FlightEnd``) when it must: LINK_LOST when the
telemetry stays stale past the reconnect timeout, or comes back with the vehicle out of OFFBOARD
and it does not return within ``RETURN_BEATS`` heartbeats (its failsafe took over meanwhile);
FAILSAFE or MODE_CHANGED when the vehicle leaves OFFBOARD; MODE_CHANGED when it disarms during the
mission. Telemetry older than the telemetry timeout (wall clock) is an outage: no setpoint goes out
until it is back (``in_outage``, ``stale``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from offboard.codec import VehicleStatus
from offboard.flight.config import FlightConfig, FlightEnd
from offboard.record import FlightStatus

#: Heartbeats after an outage in which the vehicle may still show its offboard-loss failsafe's mode:
#: PX4 v1.16 clears it and is back in OFFBOARD within 1 s of the setpoints' return (measured,
#: docs/parity/commander.md), so the first 1 Hz heartbeat may come before that and the second not.
RETURN_BEATS = 2


class Supervisor:
    """The telemetry's freshness and the vehicle's mode and arming, against what the flight expects.

    Parameters
    ----------
    config : FlightConfig
        ``telemetry_timeout_s`` and ``reconnect_timeout_s``.
    say : callable
        One-line events (telemetry lost, back).

    Attributes
    ----------
    watching : bool
        Whether stale telemetry is an outage (the flight sets it once the vehicle is found).
    expect_offboard, expect_armed : bool
        Whether the vehicle must stay in OFFBOARD, armed (set once each was acknowledged, cleared
        for the landing).
    outage_since : float or None
        When the telemetry of the current outage was last heard (s of the clock); None: no outage.
    outages : list of float
        How long each outage that ended lasted (s).
    """

    def __init__(self, config: FlightConfig, say: Callable[[str], None]) -> None:
        self.config = config
        self._say = say
        self.watching = False
        self.expect_offboard = False
        self.expect_armed = False
        self.last_telemetry_s: float | None = None
        self.outage_since: float | None = None
        self.outages: list[float] = []
        self._verify_beats = 0  # after an outage in OFFBOARD: heartbeats left for the vehicle to show it again
        self._offboard_seen = False
        self._non_offboard_beats = 0
        self._armed_seen = False
        self._disarmed_beats = 0

    # -- the telemetry -------------------------------------------------------------------------------

    @property
    def in_outage(self) -> bool:
        """Whether the telemetry is lost (no setpoints until it is back)."""
        return self.outage_since is not None

    def heard(self, now: float) -> None:
        """Telemetry came at ``now`` (s of the clock); in lockstep also our answer, after which the
        plant sends the next within the timeout."""
        self.last_telemetry_s = now

    def stale(self, now: float) -> bool:
        """Whether the telemetry is older than the telemetry timeout at ``now`` (s), when watching."""
        last = self.last_telemetry_s
        return self.watching and last is not None and now - last > self.config.telemetry_timeout_s

    def service(self, now: float) -> float:
        """Declare an outage when the telemetry has gone stale at ``now`` (s of the clock), and end
        the flight when it has stayed away past the reconnect timeout. Returns how long until the
        next check is due (s; inf: not watching).

        Raises
        ------
        FlightEnd
            LINK_LOST.
        """
        if not self.watching:
            return math.inf
        last = self.last_telemetry_s
        if last is None:
            last = self.last_telemetry_s = now
        stale = now - last
        if self.outage_since is None:
            if stale > self.config.telemetry_timeout_s:
                self.outage_since = last
                self._say(f"telemetry lost ({stale:.2f} s without ATTITUDE/LOCAL_POSITION_NED): setpoints stopped")
        elif now - self.outage_since > self.config.reconnect_timeout_s:
            raise FlightEnd(FlightStatus.LINK_LOST, f"no telemetry for {now - self.outage_since:.1f} s")
        return self.config.telemetry_timeout_s / 4

    def telemetry_back(self, now: float) -> None:
        """The outage ended at ``now`` (s of the clock): counted, and in OFFBOARD the next heartbeat
        must show the vehicle still in it."""
        assert self.outage_since is not None
        gap = now - self.outage_since
        self.outages.append(gap)
        self.outage_since = None
        self._verify_beats = RETURN_BEATS if self.expect_offboard else 0
        self._say(f"telemetry back after {gap:.2f} s: setpoints resumed")

    # -- the vehicle's mode and arming ---------------------------------------------------------------

    def on_heartbeat(self, status: VehicleStatus, statustexts: list[str]) -> None:
        """The vehicle's HEARTBEAT against what is expected of it (``statustexts``: its latest, to
        tell a failsafe from someone else's mode change). Two heartbeats out of OFFBOARD (or
        disarmed) before the first in it count as leaving it: the vehicle may not show it yet.

        Raises
        ------
        FlightEnd
            LINK_LOST (back from an outage out of OFFBOARD), FAILSAFE or MODE_CHANGED; the last
            two with ``stop_setpoints``: the vehicle is no longer ours to command.
        """
        returning = False  # after an outage: its offboard-loss failsafe may clear yet, the setpoints being back
        if self._verify_beats:
            if status.offboard:
                self._verify_beats = 0
            else:
                self._verify_beats -= 1
                if not self._verify_beats:
                    raise FlightEnd(FlightStatus.LINK_LOST, f"telemetry came back with the vehicle in {status.mode_name}: "
                                                            "its failsafe took over during the outage")
                returning = True
        if self.expect_offboard and not returning:
            if status.offboard:
                self._offboard_seen = True
                self._non_offboard_beats = 0
            else:
                self._non_offboard_beats += 1
                if self._offboard_seen or self._non_offboard_beats >= 2:
                    failsafe = status.critical or any("failsafe" in t.lower() for t in statustexts[-3:])
                    kind = FlightStatus.FAILSAFE if failsafe else FlightStatus.MODE_CHANGED
                    why = "failsafe" if failsafe else "mode changed by someone else"
                    last = f" (vehicle: {statustexts[-1]})" if statustexts else ""
                    raise FlightEnd(kind, f"the vehicle left Offboard for {status.mode_name}: {why}{last}", stop_setpoints=True)
        if self.expect_armed:
            if status.armed:
                self._armed_seen = True
                self._disarmed_beats = 0
            else:
                self._disarmed_beats += 1
                if self._armed_seen or self._disarmed_beats >= 2:
                    raise FlightEnd(FlightStatus.MODE_CHANGED, "the vehicle disarmed during the mission", stop_setpoints=True)
