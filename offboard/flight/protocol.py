"""The MAVLink protocol a flight speaks with its vehicle, besides the setpoints: finding the
vehicle (its HEARTBEAT) and sending ours, commands (COMMAND_LONG, retried until a COMMAND_ACK),
parameters (PARAM_REQUEST_READ / PARAM_VALUE), time (TIMESYNC), the vehicle's home
(HOME_POSITION), its landed state (EXTENDED_SYS_STATE) and what it says (STATUSTEXT).

``VehicleClient`` keeps what these exchanges learn of the vehicle. It never reads the link
itself: each wait goes through the ``wait(until, timeout_s)`` it is given (``Flight``'s pump),
which hands every message of the vehicle to ``handle`` and keeps the samples going meanwhile, so
that the setpoints never stop for a command's round trip.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from offboard import codec
from offboard.codec import VehicleStatus
from offboard.errors import CommandRejected
from offboard.flight.config import FlightConfig, Link
from pymavlink.dialects.v20 import common as mavlink

STATUSTEXT_GRACE_S = 0.3  # wait this long after a refusal for the STATUSTEXT saying why
MODE_ACK_GRACE_S = 0.5  # after a DO_SET_MODE's first ACK, wait this long for PX4's second
TIMESYNC_ATTEMPTS = 3
TIMESYNC_TIMEOUT_S = 1.0  # per attempt
HOME_TIMEOUT_S = 1.0  # how long to wait for HOME_POSITION once asked for
HEARTBEAT_PERIOD_S = 1.0  # ours (in lockstep: of the vehicle's time)

#: ``wait(until, timeout_s)``: handle messages and samples until ``until()`` holds (True) or the
#: timeout runs out (False; None: no timeout).
Wait = Callable[[Callable[[], bool], float | None], bool]
#: The vehicle's home: (latitude deg, longitude deg, altitude m AMSL) and its local NED position (m).
VehicleHome = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass
class _Pending:
    """A command waiting for its COMMAND_ACK."""

    command: int
    params: tuple[float, ...]
    name: str
    attempts: int = 0
    result: int | None = None
    acks: int = 0  # COMMAND_ACKs received for it (PX4 sends two for DO_SET_MODE: a refusal in either counts)
    first_ack_s: float | None = None
    results: list[int] = field(default_factory=list)  # every ACK's result, in order (a burst counts them)
    #: what a heartbeat shows once the command is done, and whether one since the first try did
    took_effect: Callable[[VehicleStatus], bool] | None = None
    seen_done: bool = False


class VehicleClient:
    """Our side of the vehicle's MAVLink protocol, and what it has learnt of the vehicle.

    Parameters
    ----------
    link : Link
        Where the requests go (the answers come back through ``wait``).
    config : FlightConfig
        Timeouts and attempts, ``lockstep`` and ``target_system``.
    clock : callable
        Monotonic seconds (wall clock: every timeout, our heartbeat in real time, TIMESYNC).
    wait : Wait
        The flight's pump.
    say : callable
        One-line events (notes, the vehicle's warnings).
    boot_ms : callable
        The vehicle's latest ``time_boot_ms`` (ms): in lockstep our heartbeat and our TIMESYNC
        time follow it, so that a lockstep flight sends the same bytes every time.

    Attributes
    ----------
    target : (system, component) or None
        The vehicle, once its HEARTBEAT was heard.
    status : VehicleStatus or None
        Its latest HEARTBEAT.
    vehicle_params : dict
        The parameters read (name -> value).
    landed_state : int or None
        Its latest EXTENDED_SYS_STATE ``landed_state`` (MAV_LANDED_STATE).
    home : VehicleHome or None
        Its latest HOME_POSITION.
    timesync : dict or None
        ``offset_ms`` and ``rtt_ms`` of the last TIMESYNC exchange that was answered.
    statustexts : list of str
        The vehicle's last 20 STATUSTEXTs.
    """

    def __init__(self, link: Link, config: FlightConfig, clock: Callable[[], float], wait: Wait,
                 say: Callable[[str], None], boot_ms: Callable[[], int]) -> None:  # fmt: skip
        self.link = link
        self.config = config
        self.clock = clock
        self._wait = wait
        self._say = say
        self._boot_ms = boot_ms
        self.target: tuple[int, int] | None = None
        #: the vehicle's autopilot as its HEARTBEAT says (MAV_AUTOPILOT; None: not found yet)
        self.autopilot: int | None = None
        self.status: VehicleStatus | None = None
        self.vehicle_params: dict[str, float] = {}
        self.landed_state: int | None = None
        self.home: VehicleHome | None = None
        self.timesync: dict[str, float] | None = None
        self.statustexts: list[str] = []
        self._statustext_count = 0
        self._early: dict[tuple[tuple[int, int], str], mavlink.MAVLink_message] = {}
        self._pending: _Pending | None = None
        self._params_wanted: frozenset[str] = frozenset()
        self._timesync_ts1: int | None = None
        self._timesync_reply: tuple[int, int] | None = None
        self._next_heartbeat: float = 0.0
        self._next_heartbeat_ms = 0

    # -- the vehicle's messages ----------------------------------------------------------------------

    def discover(self, msg: mavlink.MAVLink_message) -> list[mavlink.MAVLink_message]:
        """Before the vehicle is known: take the first autopilot's HEARTBEAT (``target_system``'s if
        given) as the vehicle's. Returns the telemetry it sent before it, to be handled now (a
        lockstep plant may send it only once)."""
        kind = msg.get_type()
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind in ("ATTITUDE", "LOCAL_POSITION_NED"):
            self._early[(source, kind)] = msg
        elif kind == "HEARTBEAT" and codec.is_autopilot_heartbeat(msg):
            if self.config.target_system is None or source[0] == self.config.target_system:
                self.target = source
                self.autopilot = int(msg.autopilot)
                if hasattr(self.link, "trusted"):
                    self.link.trusted = source  # only the vehicle's datagrams may move our link's peer
                self.status = codec.vehicle_status(msg)
                early = [self._early[(source, k)] for k in ("ATTITUDE", "LOCAL_POSITION_NED") if (source, k) in self._early]
                self._early.clear()
                return early
        return []

    def from_vehicle(self, msg: mavlink.MAVLink_message) -> bool:
        """Whether ``msg`` comes from the vehicle we fly."""
        return (msg.get_srcSystem(), msg.get_srcComponent()) == self.target

    def on_heartbeat(self, msg: mavlink.MAVLink_message) -> VehicleStatus:
        """The vehicle's HEARTBEAT: its status, which may show a pending command done."""
        status = codec.vehicle_status(msg)
        self.status = status
        pending = self._pending
        if pending is not None and pending.took_effect is not None and pending.took_effect(status):
            pending.seen_done = True
        return status

    def handle(self, msg: mavlink.MAVLink_message) -> None:
        """One of the vehicle's messages other than its telemetry and HEARTBEAT."""
        kind = msg.get_type()
        if kind == "COMMAND_ACK":
            p = self._pending
            if p is not None and int(msg.command) == p.command and int(getattr(msg, "target_system", 0)) in (0, self._own_sysid()):
                p.result = int(msg.result)
                p.results.append(p.result)
                p.acks += 1
                if p.first_ack_s is None:
                    p.first_ack_s = self.clock()
        elif kind == "PARAM_VALUE":
            name, value = codec.param_value(msg)
            if name in self._params_wanted:
                self.vehicle_params[name] = value
        elif kind == "TIMESYNC":
            # our request, answered; tc1 = 0 is the vehicle's own request (PX4 sends them at 10 Hz),
            # whose ts1 equals ours in lockstep, where both are the simulation time
            if self._timesync_ts1 is not None and int(msg.tc1) != 0 and int(msg.ts1) == self._timesync_ts1:
                self._timesync_reply = (int(msg.tc1), self.now_ns())
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = int(msg.landed_state)
        elif kind == "HOME_POSITION":
            self.home = ((msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0),
                         (float(msg.x), float(msg.y), float(msg.z)))  # fmt: skip
        elif kind == "STATUSTEXT":
            text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            text = text.rstrip("\x00").strip()
            if text:
                self.statustexts = (self.statustexts + [text])[-20:]
                self._statustext_count += 1
                if int(msg.severity) <= mavlink.MAV_SEVERITY_WARNING:
                    self._say(f"vehicle: {text}")

    def _own_sysid(self) -> int:
        return int(getattr(self.link, "sysid", 0))

    # -- our heartbeat -------------------------------------------------------------------------------

    def send_heartbeat(self) -> None:
        """Our HEARTBEAT now; the next is due a second later (of the vehicle's time in lockstep)."""
        self.link.send(codec.heartbeat())
        if self.config.lockstep:
            self._next_heartbeat_ms = self._boot_ms() + int(HEARTBEAT_PERIOD_S * 1000)
        else:
            self._next_heartbeat = self.clock() + HEARTBEAT_PERIOD_S

    def heartbeat_if_due_ms(self, t_ms: int) -> None:
        """In lockstep: our HEARTBEAT if it is due at the vehicle's ``time_boot_ms`` t_ms."""
        if self._next_heartbeat_ms <= t_ms:
            self.send_heartbeat()

    def service(self, now: float) -> float:
        """In real time, once the vehicle is known: our HEARTBEAT if it is due at ``now`` (s of our
        clock). Returns how long until the next one is (s; inf: not ours to time)."""
        if self.config.lockstep or self.target is None:
            return math.inf
        if now >= self._next_heartbeat:
            self.send_heartbeat()
        return self._next_heartbeat - now

    # -- commands ------------------------------------------------------------------------------------

    def command(self, command: int, params: tuple[float, ...], *, took_effect: Callable[[VehicleStatus], bool] | None = None) -> None:
        """Send a COMMAND_LONG and wait for its ACK, retrying (confirmation + 1) when none comes.

        ``took_effect``: what a heartbeat shows once the command is done (armed, a mode). With no
        ACK after the attempts, a heartbeat received since the first try that shows it counts as
        the ACK (the ACKs were lost, not the command: MAVSDK does the same).

        Raises
        ------
        CommandRejected
            Not ACCEPTED, or no ACK after the attempts (result name ``NO_ACK``).
        """
        assert self.target is not None
        name = codec.mav_cmd_name(command)
        pending = _Pending(command, params, name, took_effect=took_effect)
        texts_before = self._statustext_count
        self._pending = pending
        try:
            while pending.attempts < self.config.command_attempts:
                self.link.send(codec.command_long(self.target[0], self.target[1], command, params, pending.attempts))
                pending.attempts += 1
                self._wait(lambda: pending.result is not None and pending.result != mavlink.MAV_RESULT_IN_PROGRESS,
                           self.config.command_timeout_s)
                if pending.result is not None and pending.result != mavlink.MAV_RESULT_IN_PROGRESS:
                    break
            if command == mavlink.MAV_CMD_DO_SET_MODE and pending.result is not None:
                # PX4 answers a mode change twice: ACCEPTED from its MAVLink receiver and the
                # commander's own result, mostly 5-12 ms after it, but a loaded PX4 has sent the
                # commander's first: a refusal in either is the answer
                self._wait(lambda: pending.acks >= 2, MODE_ACK_GRACE_S)
                refusals = [r for r in pending.results if r not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS)]
                pending.result = refusals[0] if refusals else pending.result
        finally:
            self._pending = None
        if pending.result is None:
            if pending.seen_done:
                self._say(f"note: no ACK for {name} after {pending.attempts} attempts, but the vehicle's heartbeat shows it done")
                return
            raise CommandRejected(name, -1, f"NO_ACK after {pending.attempts} attempts")
        if pending.result != mavlink.MAV_RESULT_ACCEPTED:
            # PX4 says why in a STATUSTEXT that follows the ACK: give it a moment
            self._wait(lambda: self._statustext_count > texts_before, STATUSTEXT_GRACE_S)
            reason = self.statustexts[-1] if self._statustext_count > texts_before else ""
            exc = CommandRejected(name, pending.result, codec.mav_result_name(pending.result))
            if reason:
                exc.args = (f"{exc.args[0]}; the vehicle says: {reason}",)
            raise exc

    def command_burst(self, commands: list[tuple[int, tuple[float, ...]]]) -> list[int]:
        """Send COMMAND_LONGs of one command id at once; the results of the ACKs that came within the
        command timeout, in arrival order (an ACK names the command, not which of them it answers)."""
        assert self.target is not None
        command = commands[0][0]
        assert all(c == command for c, _ in commands)
        pending = _Pending(command, (), codec.mav_cmd_name(command))
        self._pending = pending
        try:
            for _, params in commands:
                self.link.send(codec.command_long(self.target[0], self.target[1], command, params, 0))
            self._wait(lambda: len(pending.results) >= len(commands), self.config.command_timeout_s)
        finally:
            self._pending = None
        return list(pending.results)

    # -- parameters, time, home ----------------------------------------------------------------------

    def param_family(self) -> str:
        """Probe which simulator's physical parameters the vehicle publishes: ``SIM`` (sitl-plant),
        ``SIH`` (PX4's SIH) or ``none`` (a real airframe); the probe's value is kept. Both probes
        are asked at once, and the first answer ends the probe."""
        probes = {"SIM_THR_MAX": "SIM", "SIH_MASS": "SIH"}
        values = self.read_params(list(probes), enough=bool)
        for probe, family in probes.items():
            if probe in values:
                self.vehicle_params[probe] = values[probe]
                return family
        return "none"

    def link_lossy(self) -> bool:
        """Whether the link has lost packets of the vehicle (its sequence numbers)."""
        return int(getattr(getattr(self.link, "stats", None), "lost", 0)) > 0

    def read_param(self, name: str, attempts: int | None = None) -> float | None:
        """PARAM_REQUEST_READ ``name`` until its PARAM_VALUE comes (``read_params``); its value, or None."""
        return self.read_params([name], attempts).get(name)

    def read_params(self, names: list[str], attempts: int | None = None,
                    enough: Callable[[dict[str, float]], bool] | None = None) -> dict[str, float]:  # fmt: skip
        """PARAM_REQUEST_READ each of ``names`` at once, then again for those not answered within
        ``param_timeout_s``, ``attempts`` (or ``param_attempts``) rounds in all; the values that
        came, by name (not kept). A PARAM_VALUE names its parameter, so the requests need not wait
        for each other: over a lossy link each round costs one timeout, not one per parameter (as
        QGroundControl and MAVSDK keep several in flight). ``enough(values)``: stop as soon as it
        holds."""
        assert self.target is not None
        values: dict[str, float] = {}
        wanted = list(dict.fromkeys(names))
        self._params_wanted = frozenset(wanted)
        try:
            for _ in range(attempts or self.config.param_attempts):
                missing = [n for n in wanted if n not in values]
                for name in missing:
                    self.link.send(codec.param_request_read(self.target[0], self.target[1], name))

                def answered() -> bool:
                    for n in missing:
                        if n in self.vehicle_params:
                            values[n] = self.vehicle_params.pop(n)
                    return len(values) == len(wanted) or (enough is not None and enough(values))

                if self._wait(answered, self.config.param_timeout_s) or answered():
                    break
        finally:
            self._params_wanted = frozenset()
        return values

    def sync_time(self) -> None:
        """TIMESYNC with the vehicle (up to three requests): ``timesync`` gets the offset and the
        round trip; without an answer it stays as it was (a note says so)."""
        for _ in range(TIMESYNC_ATTEMPTS):
            ts1 = self.now_ns()
            self._timesync_ts1 = ts1
            self._timesync_reply = None
            self.link.send(codec.timesync_request(ts1))
            answered = self._wait(lambda: self._timesync_reply is not None, TIMESYNC_TIMEOUT_S)
            if answered and self._timesync_reply is not None:
                tc1, now_ns = self._timesync_reply
                offset, rtt = codec.timesync_offset_ns(ts1, tc1, now_ns)
                self.timesync = {"offset_ms": offset / 1e6, "rtt_ms": rtt / 1e6}
                self._timesync_ts1 = None
                return
        self._timesync_ts1 = None
        self._say("note: no TIMESYNC reply; continuing without")

    def now_ns(self) -> int:
        """Our TIMESYNC time (ns): the latest telemetry stamp in lockstep (reproducible), else the clock."""
        if self.config.lockstep:
            return self._boot_ms() * 1_000_000  # simulation time: reproducible
        return int(self.clock() * 1e9)

    def vehicle_home(self) -> VehicleHome | None:
        """The vehicle's HOME_POSITION, asked for (MAV_CMD_REQUEST_MESSAGE) when it has not come by
        itself; None when it does not come within a second (a refusal is a note)."""
        if self.home is None:
            try:
                self.command(mavlink.MAV_CMD_REQUEST_MESSAGE, (float(mavlink.MAVLINK_MSG_ID_HOME_POSITION),))
            except CommandRejected as exc:
                self._say(f"note: {exc}")
            self._wait(lambda: self.home is not None, HOME_TIMEOUT_S)
        return self.home
