"""A mission flown over MAVLink: the flight sequence and the control loop, with no sockets.

``Flight`` is given a link (``send(msg)``, ``recv(timeout_s) -> msg | None``), a clock
(``time.monotonic`` by default) and a stop flag, so tests can drive it with a fake link and a
fake clock. The sequence (docs/offboard.md):

1. wait for the vehicle's HEARTBEAT (``LinkTimeout`` naming the address otherwise);
2. read the parameters it needs (PARAM_REQUEST_READ by name, with retries), synchronise time
   (TIMESYNC), switch off the streams it never reads and ask for the ones it samples at its
   telemetry rate (MAV_CMD_SET_MESSAGE_INTERVAL);
3. stream setpoints (the vehicle's own attitude, thrust 0) **before** asking for OFFBOARD
   (MAV_CMD_DO_SET_MODE, PX4 main mode 6), then arm (MAV_CMD_COMPONENT_ARM_DISARM);
4. fly the mission: mission time 0 is the first sample after the arm is acknowledged; each
   sample runs the controller on the freshest ATTITUDE and LOCAL_POSITION_NED exactly as
   ``offboard.inprocess.run_scenario`` does on its simulated vehicle, and sends one setpoint;
5. land with MAV_CMD_NAV_LAND (the vehicle's own landing), wait for the ground, disarm.

The parts it owns: a ``VehicleClient`` (``protocol``: the vehicle's messages other than the
setpoints), a ``Supervisor`` (``supervisor``: telemetry outages, the vehicle's mode and arming) and
a ``Sampler`` (``sampler``: when a sample is due, lockstep, real time or the vehicle's clock, and
what it is made of). Every wait of any of them goes through ``Flight._pump``, which reads the
link, routes each message and runs the time-driven work, so that the setpoints never stop while
the flight waits for an answer.

How it can end (``FlightStatus``): COMPLETE; LINK_LOST (telemetry stale for longer than the
telemetry timeout and not back within the reconnect timeout, or back after the vehicle left
OFFBOARD; setpoints stop while it is stale and resume if it comes back in OFFBOARD); FAILSAFE or
MODE_CHANGED (the vehicle left OFFBOARD: we stop commanding at once); REJECTED (a command
refused or never acknowledged: ``CommandRejected``); NAN_COMMAND and DIVERGED (the output is
never sent; the vehicle is told to land); LOST_TRACK and ESTIMATE_LOST in flight (``guards``:
off the reference and not closing, or the vehicle's estimator no longer vouching for what the
law reads; the vehicle is told to land); INTERRUPTED (Ctrl-C: land, disarm).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from offboard import codec
from offboard.clockrate import STALLED_RATE
from offboard.codec import MeasuredState, Scaling, SetpointOutput
from offboard.controller import ControllerParams
from offboard.controller.command import Controller
from offboard.controller.design import inner_loop_from_params
from offboard.controller.prediction import LatencyPredictor
from offboard.controller.tuning import vehicle_values
from offboard.controllers import make_controller
from offboard.errors import ClockMismatch, CommandRejected, LinkTimeout, MissionFormatError
from offboard.flight.choice import VEHICLE_PARAMS, ControllerChoice, params_to_read, resolve_controller
from offboard.flight.config import FlightConfig, FlightEnd, HeadingHoldMode, Link, SampleClock
from offboard.echo import ECHO_RATE_HZ, SetpointEcho
from offboard.flight.guards import EstimatorGuard, HeadingResetWatch, TrackGuard, sensor_health_changes
from offboard.flight.heading_hold import EKF2_ALIGN_HEIGHT_M, TakeoffHeadingHold, alignment_delay_s, aligns_in_flight, highest_down_m
from offboard.flight.protocol import VehicleClient
from offboard.flight.sampler import LoopStats, Sampler
from offboard.flight.supervisor import Supervisor
from offboard.missions.geo import mission_offset_ned
from offboard.metrics import lost_reason
from offboard.record import COLUMNS, FlightRecord, FlightStatus, RecordBuilder, control_row
from offboard.model.tlog import LOCKSTEP_EPOCH_S
from offboard.trajectory.base import ReferencePairs, Trajectory
from offboard.trajectory.shifted import shift_trajectory
from pymavlink.dialects.v20 import common as mavlink

#: Extra record columns of a MAVLink flight: the ATTITUDE stamp answered, and when (wall clock).
#: the record's columns, the telemetry stamp answered, the sample's wall time, and the telemetry's
#: age the latency prediction was handed (NaN where it was handed none: no prediction, lockstep,
#: the vehicle's clock), which ``offboard replay --rerun`` reads back to re-run it exactly
FLIGHT_COLUMNS = {**COLUMNS, "time_boot_ms": 1, "sample_wall_s": 1, "telemetry_age_s": 1}
MAX_HOME_OFFSET_M = 1000.0  # a mission's home farther than this from the vehicle's is refused
#: Ends of a guard (``flight.guards``): the vehicle is handed to its own landing.
GUARD_ENDS = (FlightStatus.LOST_TRACK, FlightStatus.ESTIMATE_LOST)

# --- results -------------------------------------------------------------------------------------


@dataclass
class FlightResult:
    """What a flight leaves: the record, how it ended, and what the link and the loop did."""

    record: FlightRecord
    status: FlightStatus
    detail: str
    controller: ControllerParams | None
    scaling: Scaling | None
    vehicle_params: dict[str, float]
    loop: LoopStats
    outages: list[float]
    timesync: dict[str, float] | None
    landed: bool
    disarmed: bool
    notes: list[str]
    vehicle: tuple[int, int] | None
    home_offset_ned_m: tuple[float, float, float] | None = None
    #: the take-off heading hold: ``{"mode", "held", "heading_deg", "released_s"}`` (``heading_hold``)
    heading_hold: dict[str, object] | None = None
    #: the estimator's heading resets seen in ATTITUDE: ``{"t_s", "time_boot_ms", "deg"}`` each
    #: (``t_s``: mission time, None before the mission; ``guards.HeadingResetWatch``)
    heading_resets: list[dict[str, object]] = field(default_factory=list)
    #: the latency the law's state was predicted over (s; None: the measured state)
    predicted_latency_s: float | None = None
    #: whether that prediction observed the rate loop's integral and torque (None: not predicted)
    observed_rate_loop: bool | None = None
    #: the observer's memory (s; None: not observed)
    observer_memory_s: float | None = None
    #: the setpoints' latency in the vehicle's clock from its ATTITUDE_TARGET echo
    #: (``echo.latency_figures``; None: not asked for)
    setpoint_echo: dict | None = None


@dataclass(frozen=True)
class Progress:
    """One live-progress sample: what the one-line display shows.

    During the mission: its phase, mission time and the 3D error (m). During the landing: phase
    ``"landing"``, the vehicle's seconds since the landing began, and ``error_m`` NaN (the vehicle
    lands by itself: there is no reference).
    """

    phase: str
    t_s: float
    pos_ned_m: tuple[float, float, float]
    error_m: float


# --- the flight ----------------------------------------------------------------------------------


class LogClock:
    """The tlog's timestamps (µs): wall time, or in lockstep the epoch plus the latest stamp seen
    (the same bytes every run); ``wall``: wall time in lockstep too (when each packet is sent or
    handled, to measure the loop's hand-overs; ``offboard fly --log-clock wall``). ``sim_us`` is
    the first kind whatever ``wall`` says: what signs in lockstep (``offboard.signing``)."""

    def __init__(self, lockstep: bool, wall_us: Callable[[], int] | None = None, *, wall: bool = False) -> None:
        self.lockstep = lockstep
        self.wall = wall
        self._wall_us = wall_us or (lambda: int(time.time() * 1e6))
        self.boot_ms = 0

    def __call__(self) -> int:
        return self._wall_us() if self.wall else self.sim_us()

    def sim_us(self) -> int:
        """In lockstep the epoch plus the latest ``time_boot_ms`` seen, else the wall clock (µs)."""
        if self.lockstep:
            return LOCKSTEP_EPOCH_S * 1_000_000 + self.boot_ms * 1000
        return self._wall_us()


class Flight:
    """One mission flown over a MAVLink link (module docstring).

    Parameters
    ----------
    link : Link
    trajectory : Trajectory
        The mission's references, NED, mission time 0 at the first armed sample.
    choice : ControllerChoice
    config : FlightConfig
    thrust_max_n : float or None
        The vehicle's thrust at normalised 1 when it does not publish SIM_THR_MAX (real PX4).
    clock : callable
        Monotonic seconds (wall clock; real-time sampling and every timeout).
    stop_requested : callable
        True once the user asked to stop (Ctrl-C): land, disarm, INTERRUPTED.
    log_clock : LogClock or None
        Told the latest ``time_boot_ms`` seen, so lockstep logs are stamped by simulation time.
    progress, event : callables or None
        Live progress (each sample) and one-line events (connected, armed, landing ...).
    mission_home : (lat deg, lon deg, alt m) or None
        The geographic origin of the trajectory's NED frame (waypoint files): the flight asks
        for the vehicle's HOME_POSITION and flies the mission where it is on the map.
    meta : dict, optional
        Kept in the record's metadata (the flight adds the measured clock rate and the clock
        sampled on).
    """

    def __init__(
        self,
        link: Link,
        trajectory: Trajectory,
        choice: ControllerChoice,
        config: FlightConfig | None = None,
        *,
        thrust_max_n: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        stop_requested: Callable[[], bool] = lambda: False,
        log_clock: LogClock | None = None,
        progress: Callable[[Progress], None] | None = None,
        event: Callable[[str], None] | None = None,
        meta: dict[str, object] | None = None,
        mission_home: tuple[float, float, float] | None = None,
    ) -> None:
        self.link = link
        self.mission_home = mission_home
        self.home_offset_ned_m: tuple[float, float, float] | None = None
        self.trajectory = trajectory
        self.choice = choice
        self.config = config or FlightConfig()
        self.clock = clock
        self.stop_requested = stop_requested
        self.log_clock = log_clock
        self._progress = progress
        self._event = event
        self._thrust_max_override = thrust_max_n
        self.meta = dict(meta or {})
        self.phases = trajectory.phases()
        self._interrupt_enabled = True
        # the parts: the telemetry's freshness and the vehicle's mode and arming; the samples; the
        # vehicle's protocol and what it has told us
        self.supervisor = Supervisor(self.config, self._say)
        # the vehicle's flying: on its reference, and its estimator still vouching for the estimate
        self.track_guard = TrackGuard(self.config.lost_track_m) if math.isfinite(self.config.lost_track_m) else None
        self.estimator_guard = EstimatorGuard() if self.config.watch_estimator else None
        self._sensor_health: dict[str, bool] | None = None
        self._mission_t_s = 0.0  # mission time of the latest sample
        to = choice.sample_time_s if choice.sample_time_s is not None else choice.base.sample_time_s
        self.sampler = Sampler(link, self.config, to, clock, self.supervisor)
        self.client = VehicleClient(link, self.config, clock, self._pump, self._say, self.sampler.boot_ms)
        # the mission
        self.controller: Controller | None = None
        self.params: ControllerParams | None = None
        self.scaling: Scaling | None = None
        self.rows = RecordBuilder(FLIGHT_COLUMNS)
        self.sampler.mission_samples = int(round(trajectory.duration_s / self.to))
        self.references = ReferencePairs(trajectory, self.to)
        #: with a latency prediction the law sees the state L ahead, and the references L ahead with it
        self.lookahead_s = 0.0
        self.predicted_latency_s: float | None = None  # the latency the state was predicted over (None: not predicted)
        self.observed_rate_loop: bool | None = None  # whether that prediction observed the rate loop (None: not predicted)
        self.observer_memory_s: float | None = None  # the observer's memory (None: not observed)
        self._attitude_heard_s: float | None = None  # when the latest ATTITUDE came (our clock)
        self.references_ahead = ReferencePairs(trajectory, self.to)
        self._landing_ms: int | None = None  # the vehicle's time when the landing's progress began
        #: the take-off heading hold (``heading_hold``): wanted for this vehicle (decided once its
        #: parameters are read), and the hold itself from the mission's start while it applies
        self._hold_heading = self.config.takeoff_heading_hold == HeadingHoldMode.ON
        self.heading_hold: TakeoffHeadingHold | None = None
        self._highest_down_m = math.nan  # the mission reference's highest point (NED down), where the hold is wanted
        self.heading_resets = HeadingResetWatch()
        self._mission_boot0_ms: int | None = None  # the vehicle's time of the mission's first sample's telemetry
        self.notes: list[str] = []
        self.armed_by_us = False
        self.landed = False
        self.disarmed = False

    @property
    def to(self) -> float:
        """The sample time To (s): the choice's, and once resolved the controller's."""
        return self.sampler.to

    # -- public ----------------------------------------------------------------------------------

    def run(self) -> FlightResult:
        """Fly; returns how it ended. Raises ``LinkTimeout`` when no vehicle is heard at all."""
        status, detail = FlightStatus.COMPLETE, ""
        try:
            try:
                self._connect()
                self._prepare()
                self._stream_and_arm()
                self._fly_mission()
            except CommandRejected as exc:
                status, detail = FlightStatus.REJECTED, str(exc)
            except FlightEnd as end:
                status, detail = end.status, end.detail
            self.sampler.mission_done = True  # whatever happens next is not part of the mission's record
            if status in (FlightStatus.NAN_COMMAND, FlightStatus.DIVERGED):
                self.sampler.source = None  # never send that output again
            elif status in GUARD_ENDS:
                self.sampler.source = self._level_source  # the law no longer flies it: level, hover thrust
            if status in (FlightStatus.COMPLETE, FlightStatus.INTERRUPTED, FlightStatus.NAN_COMMAND, FlightStatus.DIVERGED,
                          *GUARD_ENDS) or (status is FlightStatus.REJECTED and self.armed_by_us):  # fmt: skip
                land_status, land_detail = self._land_and_disarm()
                if land_status is not None:
                    if status is FlightStatus.COMPLETE:
                        status, detail = land_status, land_detail
                    else:
                        detail = f"{detail}; then the landing failed: {land_detail}"
        except KeyboardInterrupt:  # a second Ctrl-C: stop waiting at once
            status = FlightStatus.INTERRUPTED
            detail = (detail + "; " if detail else "") + "second interrupt: stopped waiting for the landing"
        if status is FlightStatus.INTERRUPTED and not detail:
            detail = "interrupted by the user"
        if self.estimator_guard is not None and not self.estimator_guard.heard and self.sampler.mission_started:
            self._note("the vehicle sent no ESTIMATOR_STATUS during the mission: its estimator was not watched")
        loop = self.sampler.finish()
        identified = getattr(getattr(self.controller, "velocity", None), "noise", None)
        if identified is not None:
            self._note(f"velocity filter: T {identified.time_constant_s():.3f} s, chosen from the estimates' noise "
                       f"(their velocity bias walks {identified.bias_walk_m_s_sqrt_s:.3f} m/s/sqrt(s), "
                       f"{identified.white_m_s:.3f} m/s of white noise in the position's derivative)")
        record = self.rows.build(phases=self.phases, status=status, status_detail=detail, meta=self.meta)
        for builder in (self.rows, loop.periods):
            if builder.spool_error is not None:
                self._note(builder.spool_error)
        return FlightResult(
            record=record, status=status, detail=detail, controller=self.params, scaling=self.scaling,
            vehicle_params=dict(self.client.vehicle_params), loop=loop, outages=list(self.supervisor.outages),
            timesync=self.client.timesync,
            landed=self.landed, disarmed=self.disarmed, notes=list(self.notes), vehicle=self.client.target,
            home_offset_ned_m=self.home_offset_ned_m, heading_hold=self._heading_hold_summary(),
            heading_resets=[{"t_s": self._mission_time_of(boot_ms), "time_boot_ms": boot_ms, "deg": deg}
                            for boot_ms, deg in self.heading_resets.resets],
            predicted_latency_s=self.predicted_latency_s,
            observed_rate_loop=self.observed_rate_loop,
            observer_memory_s=self.observer_memory_s,
            setpoint_echo=None if self.sampler.echo is None else self.sampler.echo.figures(),
        )  # fmt: skip

    # -- the sequence ----------------------------------------------------------------------------

    def _connect(self) -> None:
        cfg = self.config
        client = self.client
        if not self._pump(lambda: client.target is not None, cfg.heartbeat_timeout_s):
            where = f" on {cfg.connect}" if cfg.connect else ""
            which = f" (system {cfg.target_system})" if cfg.target_system is not None else ""
            raise LinkTimeout(f"no vehicle heartbeat{which} heard{where} within {cfg.heartbeat_timeout_s:g} s")
        self._say(f"vehicle {client.target[0]}/{client.target[1]} found ({client.status.mode_name if client.status else '?'}, "  # type: ignore[index]
                  f"{'armed' if client.status and client.status.armed else 'disarmed'})")
        client.send_heartbeat()
        # stream from now on: a lockstep plant then never waits on us (no keepalives, same bytes
        # every run), and PX4 sees setpoints well before OFFBOARD is asked for
        self.supervisor.watching = True
        # the setpoints' echo pairs every setpoint from the first (decided now the vehicle is known;
        # the stream is asked for with the others, _configure_streams)
        self.sampler.echo = SetpointEcho() if cfg.echoes_setpoints(client.autopilot) else None
        self.sampler.source = self._hold_source

    def _prepare(self) -> None:
        cfg, choice, client = self.config, self.choice, self.client
        family = client.param_family()
        required, optional = params_to_read(choice, cfg, self._thrust_max_override is not None, family)
        names = [name for name in required + optional if name not in client.vehicle_params]
        values = client.read_params(names)
        unanswered = [name for name in names if name not in values]
        if unanswered and client.link_lossy():  # a lossy link, not absent parameters: ask longer
            values.update(client.read_params(unanswered, 2 * cfg.param_attempts))
        for name in required:
            if name in names and name not in values:
                hint = " (pass --thrust-max-n for a vehicle without it)" if name == "SIM_THR_MAX" else ""
                raise LinkTimeout(f"the vehicle did not answer PARAM_REQUEST_READ {name} ({VEHICLE_PARAMS[name]}) "
                                  f"after {cfg.param_attempts} tries{hint}")
        client.vehicle_params.update({name: values[name] for name in names if name in values})  # in asking order
        if cfg.takeoff_heading_hold == HeadingHoldMode.AUTO:
            self._hold_heading = aligns_in_flight(client.vehicle_params)
        p = vehicle_values(client.vehicle_params)
        try:
            self.scaling = Scaling(
                thrust_max_n=self._thrust_max_override if self._thrust_max_override is not None else p["SIM_THR_MAX"],
                torque_roll_pitch_max_nm=p.get("SIM_TQ_RP_MAX"),
                torque_yaw_max_nm=p.get("SIM_TQ_Y_MAX"),
            )
        except ValueError as exc:
            raise LinkTimeout(f"the vehicle's scaling is unusable: {exc}") from None
        # the latency the design allows for: measured (TIMESYNC) before designing, unless given
        measure_latency = choice.tuned and choice.latency_s is None and not cfg.lockstep
        if measure_latency:
            client.sync_time()
            rtt_s = client.timesync["rtt_ms"] / 1000.0 if client.timesync else 0.0
            rate_hz = cfg.telemetry_rate_for(self.to)
            period_s = 1.0 / rate_hz if rate_hz else 0.0
            latency_s = rtt_s + period_s
            choice = replace(choice, latency_s=latency_s)
            self._say(f"latency {latency_s * 1000:.0f} ms for the design: TIMESYNC round trip "
                      f"{rtt_s * 1000:.1f} ms + one telemetry period {period_s * 1000:.0f} ms")
        try:
            if choice.tuned and not cfg.lockstep:
                # the design takes most of a second: keep streaming meanwhile (PX4 leaves OFFBOARD
                # after COM_OF_LOSS_T without setpoints). In lockstep the vehicle waits for us, and
                # a thread's timing would make the log differ from run to run.
                with ThreadPoolExecutor(max_workers=1) as pool:
                    future = pool.submit(resolve_controller, choice, cfg.model, dict(client.vehicle_params), self.scaling)
                    self._pump(future.done)
                    self.params, notes = future.result()
            else:
                self.params, notes = resolve_controller(choice, cfg.model, client.vehicle_params, self.scaling)
                if cfg.lockstep:  # the vehicle waited for us: our pause was no telemetry loss
                    self.supervisor.heard(self.clock())
        except ValueError as exc:
            raise LinkTimeout(str(exc)) from None
        for note in notes:
            self._say(note)
        if abs(self.params.sample_time_s - self.to) > 1e-12:
            self.sampler.to = self.params.sample_time_s
        if "PAP_TO" in p and abs(p["PAP_TO"] - self.to) > 1e-6:
            self._say(f"note: the vehicle's PAP_TO is {p['PAP_TO']:g} s, the controller's To {self.to:g} s "
                      "(its paper inner loop then differs from the in-process run)")
        if "COM_OF_LOSS_T" in p and cfg.telemetry_timeout_s >= p["COM_OF_LOSS_T"]:
            self._say(f"note: the telemetry timeout {cfg.telemetry_timeout_s:g} s is not below the vehicle's "
                      f"COM_OF_LOSS_T {p['COM_OF_LOSS_T']:g} s: its failsafe may act first")
        predictor = None
        if choice.predicts and cfg.output == SetpointOutput.ATTITUDE:
            model = replace(inner_loop_from_params(vehicle_values(client.vehicle_params), choice.latency_s or 0.0),
                            observe=choice.observes)  # fmt: skip
            predictor = LatencyPredictor(model, self.params.sample_time_s, self.params.mass_kg, self.params.gravity_m_s2)
            self.lookahead_s = predictor.latency_s
            self.predicted_latency_s = choice.latency_s or 0.0
            self.observed_rate_loop = choice.observes
            self.observer_memory_s = predictor.observer_memory_s if choice.observes else None
        self.controller = make_controller(choice.kind, self.params, vehicle_model=cfg.model, predictor=predictor)
        self.sampler.mission_samples = int(round(self.trajectory.duration_s / self.to))
        if not measure_latency:
            client.sync_time()
        if self.mission_home is not None:
            self._align_mission()
        if self._hold_heading:  # the mission's highest point, for the take-off heading hold (a scan of its samples)
            trajectory, to = self.references.trajectory, self.to
            if cfg.lockstep:
                self._highest_down_m = highest_down_m(trajectory, to)
            else:  # a long mission takes a while: keep the setpoints streaming meanwhile, as for the design
                with ThreadPoolExecutor(max_workers=1) as pool:
                    scan = pool.submit(highest_down_m, trajectory, to)
                    self._pump(scan.done)
                    self._highest_down_m = scan.result()
        self._configure_streams()

    def _configure_streams(self) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: the streams we never read off (-1), then ATTITUDE and
        LOCAL_POSITION_NED at the telemetry rate, and ESTIMATOR_STATUS at
        ``codec.ESTIMATOR_STATUS_RATE_HZ`` when it is watched (not with the vehicle's rates kept).

        All go out at once (one round trip, as MAVSDK keeps several in flight: a COMMAND_ACK names
        the command, not its stream); when an ACK is missing or not ACCEPTED, each is sent again
        alone and retried as every command (they are idempotent), so that a refusal names its
        stream. A refusal (a vehicle without that stream, or a link that lost every try) is one
        note: the flight goes on."""
        cfg = self.config
        rate_hz = cfg.telemetry_rate_for(self.to)
        echo = self.sampler.echo is not None  # decided once the vehicle was found (_connect)
        if cfg.echoes_setpoints(mavlink.MAV_AUTOPILOT_PX4) and not echo:
            self._note("setpoint echo: not asked for (the vehicle's HEARTBEAT says it is not PX4, whose ATTITUDE_TARGET "
                       "carries when it took the setpoint)")
        wanted: list[tuple[int, float | None]] = [
            (mid, None) for mid in codec.UNREAD_STREAMS if not (echo and mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET)
        ] if cfg.unread_streams_off else []  # fmt: skip
        if echo:  # the setpoints' echo, at PX4's own rate on its API link (offboard.echo)
            wanted.append((mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET, ECHO_RATE_HZ))
        if rate_hz is not None:
            wanted += [(mid, rate_hz) for mid in codec.SAMPLED_STREAMS]
            if cfg.watch_estimator:
                wanted.append((mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS, codec.ESTIMATOR_STATUS_RATE_HZ))
        if not wanted:
            return
        burst = [codec.message_interval_params(mid, rate) for mid, rate in wanted]
        for _ in range(cfg.command_attempts):
            results = self.client.command_burst(burst)
            if len(results) == len(burst) and all(r == mavlink.MAV_RESULT_ACCEPTED for r in results):
                return
            if any(r != mavlink.MAV_RESULT_ACCEPTED for r in results) or not self.client.link_lossy():
                break  # a refusal, or ACKs missing on a clean link: one by one, to name the stream
        else:
            # a lossy link: the burst went out command_attempts times, and never came back whole
            # (an ACK does not say which command it answers). Each command then reached the
            # vehicle with the odds of as many retries; sending them one by one to know which
            # took 0.5 s a stream (15 s at 20 % loss), for streams we only switch off
            self._say(f"note: over this lossy link no burst of the {len(burst)} SET_MESSAGE_INTERVAL commands "
                      f"was acknowledged whole; each was sent {cfg.command_attempts} times")
            return
        refused = []
        for mid, rate in wanted:
            command, params = codec.message_interval_params(mid, rate)
            try:
                self.client.command(command, params)
            except CommandRejected as exc:
                name = mavlink.mavlink_map[mid].msgname if mid in mavlink.mavlink_map else str(mid)
                refused.append(f"{name} {'off' if rate is None else f'at {rate:g} Hz'}: {exc.result_name}")
        if refused:
            self._say(f"note: SET_MESSAGE_INTERVAL refused for {len(refused)} stream(s), keeping the vehicle's rate: "
                      + "; ".join(refused))

    def _stream_and_arm(self) -> None:
        sampler = self.sampler
        target = sampler.samples_sent + self.config.prestream_samples
        self._pump(lambda: sampler.samples_sent >= target)
        self._check_clock_rate()
        command, params = codec.set_mode_offboard_params()
        self.client.command(command, params, took_effect=lambda st: st.offboard)
        self.supervisor.expect_offboard = True
        self._say("offboard mode accepted")
        command, params = codec.arm_params(True)
        self.client.command(command, params, took_effect=lambda st: st.armed)
        self.armed_by_us = True
        self.supervisor.expect_armed = True
        self._say("armed: flying the mission")

    def _fly_mission(self) -> None:
        assert self.controller is not None
        self.controller.reset()
        sampler = self.sampler
        sampler.source = self._mission_source
        self._pump(lambda: sampler.mission_done)

    def _land_and_disarm(self) -> tuple[FlightStatus | None, str]:
        """NAV_LAND, wait for the ground, disarm. Returns a status only if this itself failed."""
        self._interrupt_enabled = False
        self.supervisor.expect_offboard = self.supervisor.expect_armed = False
        if not self.armed_by_us:
            return None, ""
        client = self.client
        try:
            if self.supervisor.in_outage:
                return FlightStatus.LINK_LOST, "telemetry lost before the landing"
            self._say("landing (MAV_CMD_NAV_LAND)")
            command, params = codec.land_params()
            client.command(command, params, took_effect=lambda st: st.landing)
            self.sampler.source = self._idle_source
            deadline = self.clock() + self.config.land_timeout_s
            on_ground = lambda: client.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND or (  # noqa: E731
                client.status is not None and not client.status.armed
            )
            if not self._pump(on_ground, deadline - self.clock()):
                return None, self._note(f"the vehicle did not report being on the ground within {self.config.land_timeout_s:g} s")
            self.landed = True
            if client.status is not None and not client.status.armed:
                self.disarmed = True
                self._say("landed; the vehicle disarmed itself")
                return None, ""
            command, params = codec.arm_params(False)
            try:
                client.command(command, params, took_effect=lambda st: not st.armed)
            except CommandRejected as exc:
                # on the ground but not yet landed by the vehicle's own detector (its Land mode
                # still running): it disarms itself once it is (PX4's COM_DISARM_LAND)
                self._say(f"note: {exc}; waiting for the vehicle to disarm itself")
                if not self._pump(lambda: client.status is not None and not client.status.armed, max(deadline - self.clock(), 0.0)):
                    raise
                self.disarmed = True
                self._say("landed; the vehicle disarmed itself")
                return None, ""
            self.disarmed = True
            self._say("landed and disarmed")
            return None, ""
        except CommandRejected as exc:
            return FlightStatus.REJECTED, str(exc)
        except FlightEnd as end:
            return end.status, end.detail

    def _align_mission(self) -> None:
        """Move a geo-referenced mission into the vehicle's local frame (HOME_POSITION)."""
        assert self.mission_home is not None
        home = self.client.vehicle_home()
        if home is None:
            self._say("note: no HOME_POSITION from the vehicle: the mission's home is taken as the vehicle's origin")
            return
        offset = mission_offset_ned(self.mission_home, *home)
        horizontal = math.hypot(offset[0], offset[1])
        if horizontal > MAX_HOME_OFFSET_M:
            raise MissionFormatError(f"the mission's home ({self.mission_home[0]:.6f}, {self.mission_home[1]:.6f}) is "
                                     f"{horizontal / 1000:.1f} km from the vehicle's: not a mission for this vehicle")
        self.home_offset_ned_m = offset
        shifted = shift_trajectory(self.trajectory, offset)
        if shifted is not self.trajectory:
            self.trajectory = shifted
            self.references = ReferencePairs(shifted, self.to)
            self.references_ahead = ReferencePairs(shifted, self.to)
            self._say(f"mission home at NED ({offset[0]:.2f}, {offset[1]:.2f}, {offset[2]:.2f}) m of the vehicle's frame")

    def _check_clock_rate(self) -> None:
        """Before OFFBOARD, on our own clock: refuse a vehicle whose clock runs at another rate
        (``offboard.clockrate``); we keep streaming while the measurement completes."""
        meter = self.sampler.clock_meter
        if meter is None:
            return
        self._pump(lambda: meter.measure() is not None, 10.0)
        measured = meter.measure()
        self.sampler.clock_meter = None  # measured once; no more pairs kept
        if measured is None:
            return  # no telemetry to measure with: the telemetry watch reports that
        self.meta["clock_rate"] = measured.rate
        if measured.real_time:
            if self.config.clock == SampleClock.AUTO:
                self.meta["clock"] = SampleClock.WALL.value
            return
        if measured.rate < STALLED_RATE:
            raise ClockMismatch(f"{measured.describe()}: a lockstep vehicle waits for our setpoints; fly it with --lockstep")
        if self.config.clock == SampleClock.AUTO:
            self.sampler.on_vehicle_clock = True
            self.meta["clock"] = SampleClock.VEHICLE.value
            self._say(f"{measured.describe()}: sampling every {self.to * 1000:g} ms of the vehicle's clock")
            return
        raise ClockMismatch(f"{measured.describe()}, so a sample time of {self.to * 1000:g} ms of ours would be "
                            f"{self.to * measured.rate * 1000:.0f} ms of the vehicle's: fly it with --clock vehicle")

    # -- the pump: every wait goes through here ----------------------------------------------------

    def _pump(self, until: Callable[[], bool], timeout_s: float | None = None) -> bool:
        """Handle messages and samples until ``until()`` holds (True) or the timeout (False)."""
        deadline = None if timeout_s is None else self.clock() + timeout_s
        while True:
            if self._interrupt_enabled and self.stop_requested():
                raise FlightEnd(FlightStatus.INTERRUPTED, "interrupted by the user")
            self._lockstep_sample_if_due()
            if until():
                return True
            now = self.clock()
            if deadline is not None and now >= deadline:
                return False
            wait = self._service(now)
            if until():
                return True
            if deadline is not None:
                wait = min(wait, max(deadline - self.clock(), 0.0))
            msg = self.link.recv(max(wait, 0.0))
            if msg is not None:
                self._handle(msg)

    def _service(self, now: float) -> float:
        """Time-driven work (heartbeat, staleness, real-time samples); returns how long to wait (s).
        Telemetry that looks stale is first looked for in the socket: what arrived while this
        process was not running (a loaded host, a long pause) is not a link outage."""
        if self.supervisor.stale(now) and not self.supervisor.in_outage:
            while self.link.pending():  # until the telemetry is heard (the rest waits for the pump)
                msg = self.link.recv(0.0)
                if msg is not None:
                    self._handle(msg)
                if not self.supervisor.stale(self.clock()):
                    break
            now = self.clock()
        wait = min(0.05, self.client.service(now))
        wait = min(wait, self.supervisor.service(now))
        wait = min(wait, self.sampler.service(now))
        return max(wait, 0.0)

    # -- handling one message ----------------------------------------------------------------------

    def _handle(self, msg: mavlink.MAVLink_message) -> None:
        client = self.client
        if client.target is None:
            for early in client.discover(msg):
                self._on_telemetry(early)
            return
        if not client.from_vehicle(msg):
            return
        kind = msg.get_type()
        if kind in ("ATTITUDE", "LOCAL_POSITION_NED"):
            self._on_telemetry(msg)
        elif kind == "ATTITUDE_TARGET" and self.sampler.echo is not None:
            self.sampler.echo.echoed(msg.time_boot_ms, msg.q, msg.thrust)
        elif kind == "HEARTBEAT":
            self._on_heartbeat(msg)
        elif kind == "ESTIMATOR_STATUS":
            self._on_estimator_status(int(msg.flags))
        elif kind == "SYS_STATUS":
            self._on_sys_status(msg)
        else:
            client.handle(msg)

    def _on_telemetry(self, msg: mavlink.MAVLink_message) -> None:
        sampler = self.sampler
        try:
            sampler.take(msg)
        except codec.BadTelemetry as exc:
            self._note(f"ignored: {exc}")
            return
        if self.log_clock is not None:
            self.log_clock.boot_ms = max(self.log_clock.boot_ms, int(msg.time_boot_ms))
        now = self.clock()
        if msg.get_type() == "ATTITUDE":
            self._attitude_heard_s = now
            self._watch_heading(msg)
        self.supervisor.heard(now)
        sampler.meter(msg, now)
        if self.supervisor.in_outage and sampler.has_telemetry:
            self.supervisor.telemetry_back(now)
            if self.controller is not None and sampler.mission_started:
                self.controller.reset()  # its memory is a gap old: restart it from the measured state
                if self.track_guard is not None:
                    self.track_guard.reset()
        self._lockstep_sample_if_due()
        sampler.vehicle_clock_sample_if_due()

    def _on_estimator_status(self, flags: int) -> None:
        """ESTIMATE_LOST when, during the mission, the estimator stops vouching for what the law reads."""
        guard = self.estimator_guard
        if guard is None:
            return
        why = guard.update(flags)
        sampler = self.sampler
        if why and sampler.mission_started and not sampler.mission_done and self.supervisor.expect_armed:
            raise FlightEnd(FlightStatus.ESTIMATE_LOST, f"at t = {self._mission_t_s:.2f} s {why}: handed to the vehicle's landing")

    def _on_sys_status(self, msg: mavlink.MAVLink_message) -> None:
        """The sensors' health as it changes: said and noted (the estimator decides what it costs)."""
        self._sensor_health, changes = sensor_health_changes(self._sensor_health, int(msg.onboard_control_sensors_present),
                                                             int(msg.onboard_control_sensors_enabled),
                                                             int(msg.onboard_control_sensors_health))  # fmt: skip
        for line in changes:
            self._note(f"vehicle: {line}")

    def _on_heartbeat(self, msg: mavlink.MAVLink_message) -> None:
        status = self.client.on_heartbeat(msg)
        try:
            self.supervisor.on_heartbeat(status, self.client.statustexts)
        except FlightEnd as end:
            if end.stop_setpoints:
                self.sampler.source = None  # we stop commanding at once
            raise

    # -- sampling ----------------------------------------------------------------------------------

    def _lockstep_sample_if_due(self) -> None:
        """In lockstep: the sample answering the latest telemetry, once both have come (our
        heartbeat first when a second of the vehicle's time has passed)."""
        t_ms = self.sampler.lockstep_due()
        if t_ms is not None:
            self.client.heartbeat_if_due_ms(t_ms)
            self.sampler.sample_lockstep(t_ms)

    def _setpoint_message(self, sp: codec.AttitudeSetpoint | codec.ActuatorSetpoint, t_ms: int) -> mavlink.MAVLink_message:
        target = self.client.target
        assert target is not None
        if isinstance(sp, codec.ActuatorSetpoint):
            return codec.set_actuator_control_target(t_ms, sp, target[0], target[1])
        return codec.set_attitude_target(t_ms, sp, target[0], target[1])

    def _hold_source(self, measured: MeasuredState) -> mavlink.MAVLink_message:
        """Before the mission: the vehicle's own attitude, thrust 0 (proof of offboard life)."""
        return self._setpoint_message(codec.hold_setpoint(measured.euler_rad, 0.0), measured.time_boot_ms)

    def _idle_source(self, measured: MeasuredState) -> mavlink.MAVLink_message:
        """While the vehicle lands by itself: not flown; hover thrust in the air, 0 on the ground."""
        thrust = 0.0
        on_ground = self.client.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.params is not None and self.scaling is not None and not on_ground:
            thrust = self.params.mass_kg * self.params.gravity_m_s2 / self.scaling.thrust_max_n
        if self._progress is not None:  # the landing's progress: seconds since it began, where the vehicle is
            if self._landing_ms is None:
                self._landing_ms = measured.time_boot_ms
            self._progress(Progress("landing", (measured.time_boot_ms - self._landing_ms) / 1000.0,
                                    tuple(float(v) for v in measured.pos_ned_m), math.nan))  # type: ignore[arg-type]
        return self._setpoint_message(codec.hold_setpoint(measured.euler_rad, thrust), measured.time_boot_ms)

    def _level_source(self, measured: MeasuredState) -> mavlink.MAVLink_message:
        """After a guard ended the mission, until the vehicle's landing takes over: level at the
        heading flown, hover thrust (what the law's estimate or reference can no longer give)."""
        assert self.params is not None and self.scaling is not None
        thrust = self.params.mass_kg * self.params.gravity_m_s2 / self.scaling.thrust_max_n
        level = np.array([0.0, 0.0, float(measured.euler_rad[2])])
        return self._setpoint_message(codec.hold_setpoint(level, thrust), measured.time_boot_ms)

    def _mission_source(self, measured: MeasuredState) -> mavlink.MAVLink_message | None:
        """One sample of the mission: the same computation as ``run_scenario``'s, from telemetry."""
        assert self.controller is not None and self.params is not None and self.scaling is not None
        sampler = self.sampler
        now = self.clock()
        if not sampler.mission_started:
            self._mission_boot0_ms = int(measured.time_boot_ms)
            self._say_start(measured)
            self._start_heading_hold(measured)
        n, t = sampler.mission_sample(now)
        self._mission_t_s = t
        recording = not sampler.mission_done and n <= sampler.mission_samples
        ref_n, ref_n1 = self.references.pair(t)
        hold = self.heading_hold
        if hold is not None and hold.holding:
            if not hold.update(t, float(measured.pos_ned_m[2])):
                self._note(f"heading released at t = {t:.2f} s, {hold.delay_s + hold.settle_s:g} s after the vehicle rose "
                           f"{hold.align_height_m:g} m above its take-off point (EKF2's in-flight heading alignment)")
            ref_n, ref_n1 = hold.apply(ref_n), hold.apply(ref_n1)
        if self.lookahead_s > 0.0:  # the predicted state meets the references of its own time
            if not (self.config.lockstep or sampler.on_vehicle_clock) and self._attitude_heard_s is not None:
                # on our clock the telemetry read is 0 to a telemetry period old: predicted over its age
                measured = replace(measured, age_s=max(0.0, now - self._attitude_heard_s))
            ahead_n, ahead_n1 = self.references_ahead.pair(t + self.lookahead_s)
            if hold is not None:
                ahead_n, ahead_n1 = hold.apply(ahead_n), hold.apply(ahead_n1)
            command = self.controller.step(measured, ahead_n, ahead_n1)
        else:
            command = self.controller.step(measured, ref_n, ref_n1)
        why = _diverged(measured)
        if recording:
            if why:
                raise FlightEnd(FlightStatus.DIVERGED, f"at t = {t:.2f} s: {why}")
            wall_s = sampler.recorded(now, t)
            age = getattr(measured, "age_s", None)
            self.rows.append(**control_row(t, measured, ref_n, command), time_boot_ms=measured.time_boot_ms, sample_wall_s=wall_s,
                             telemetry_age_s=math.nan if age is None else age)  # fmt: skip
            err = float(np.linalg.norm(ref_n.pos_ned_m - measured.pos_ned_m))
            if self._progress is not None:
                self._progress(Progress(self._phase_at(t), t, tuple(float(v) for v in measured.pos_ned_m), err))  # type: ignore[arg-type]
            lost = self.track_guard.update(t, err) if self.track_guard is not None else None
            if lost:
                raise FlightEnd(FlightStatus.LOST_TRACK, f"{lost}: handed to the vehicle's landing")
        if not command.is_finite():
            sampler.source = None
            raise FlightEnd(FlightStatus.NAN_COMMAND, f"at t = {t:.2f} s the controller's output is not finite (not sent)")
        if n >= sampler.mission_samples:
            sampler.mission_done = True
        sp = codec.command_setpoint(command, self.scaling, output=self.config.output, model=self.config.model,
                                    controller=self.controller.name)  # fmt: skip
        return self._setpoint_message(sp, measured.time_boot_ms)

    def _say_start(self, measured: MeasuredState) -> None:
        ref0 = self.trajectory.reference(0.0).pos_ned_m
        self._say(f"mission started at t_boot {measured.time_boot_ms / 1000:.2f} s, vehicle at NED "
                  f"({measured.pos_ned_m[0]:.2f}, {measured.pos_ned_m[1]:.2f}, {measured.pos_ned_m[2]:.2f}) m, "
                  f"first reference ({ref0[0]:.2f}, {ref0[1]:.2f}, {ref0[2]:.2f}) m")

    def _start_heading_hold(self, measured: MeasuredState) -> None:
        """At the mission's start: hold the heading the vehicle has while its estimator has yet to
        align it in flight (``heading_hold``): wanted for this vehicle, the vehicle on the ground
        (in the air, EKF2 aligned at its take-off) and a mission that climbs past the height."""
        if not self._hold_heading:
            return
        down = float(measured.pos_ned_m[2])
        heading = float(measured.euler_rad[2])
        if self.client.landed_state not in (None, mavlink.MAV_LANDED_STATE_ON_GROUND, mavlink.MAV_LANDED_STATE_UNDEFINED):
            self._note("take-off heading hold: none, the vehicle is in the air (its estimator aligned its heading at take-off)")
            return
        if not down - self._highest_down_m > EKF2_ALIGN_HEIGHT_M:
            self._note(f"take-off heading hold: none, the mission never climbs {EKF2_ALIGN_HEIGHT_M:g} m above the take-off point")
            return
        hold = self.heading_hold = TakeoffHeadingHold(heading, down, delay_s=alignment_delay_s(self.client.vehicle_params))
        self._note(f"take-off heading hold: the yaw reference stays at {math.degrees(heading):.1f} deg until "
                   f"{hold.delay_s + hold.settle_s:g} s after the vehicle is {hold.align_height_m:g} m above its take-off point "
                   f"(EKF2 aligns its heading from the magnetometer {hold.delay_s:g} s after, EKF2_DELAY_MAX; then "
                   f"{hold.settle_s:g} s to settle, as PX4's own modes; --takeoff-heading-hold off: none)")

    def _watch_heading(self, msg: mavlink.MAVLink_message) -> None:
        """Note the estimator's heading resets as ATTITUDE shows them (``guards.HeadingResetWatch``)."""
        boot_ms = int(msg.time_boot_ms)
        jump = self.heading_resets.observe((boot_ms, msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed))
        if jump is None:
            return
        t = self._mission_time_of(boot_ms)
        when = f"at t = {t:.2f} s" if t is not None else f"before the mission (t_boot {boot_ms / 1000:.2f} s)"
        self._note(f"the vehicle's estimator reset its heading by {jump:+.1f} deg {when} (ATTITUDE's yaw jumped, its body "
                   "rates did not turn it)")

    def _mission_time_of(self, boot_ms: int) -> float | None:
        """The mission time of the vehicle's ``boot_ms`` (s; None before the mission)."""
        if self._mission_boot0_ms is None or boot_ms < self._mission_boot0_ms:
            return None
        return (boot_ms - self._mission_boot0_ms) / 1000.0

    def _heading_hold_summary(self) -> dict[str, object]:
        hold = self.heading_hold
        return {
            "mode": str(self.config.takeoff_heading_hold),
            "held": hold is not None,
            "heading_deg": None if hold is None else math.degrees(hold.heading_rad),
            "released_s": None if hold is None else hold.released_s,
        }

    def _phase_at(self, t: float) -> str:
        for phase in self.phases:
            if phase.start_s <= t < phase.end_s:
                return phase.name
        return self.phases[-1].name if self.phases else "mission"

    # -- small things ------------------------------------------------------------------------------

    def _say(self, text: str) -> None:
        if self._event is not None:
            self._event(text)

    def _note(self, text: str) -> str:
        self.notes.append(text)
        self._say(text)
        return text


def _diverged(measured: MeasuredState) -> str:
    """Why the measured state means the flight is lost ('' if it is not); as run_scenario."""
    vectors = (measured.pos_ned_m, measured.vel_ned_m_s, measured.euler_rad, measured.body_rate_frd_rad_s)
    finite = all(math.isfinite(v) for vector in vectors for v in np.asarray(vector, dtype=float).tolist())  # floats: 5x numpy's on 12 numbers
    return lost_reason(finite, float(measured.euler_rad[0]), float(measured.euler_rad[1]), measured.pos_ned_m, "measured")
