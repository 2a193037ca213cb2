"""`offboard fly MISSION`: fly a mission with the paper's controller over MAVLink.

Against ``sitl-plant`` or a PX4 SITL, exactly as MAVSDK users fly PX4: listen on
``udpin:0.0.0.0:14540`` (PX4's offboard port), wait for the vehicle, read its parameters,
stream setpoints, switch to OFFBOARD, arm, fly, land, disarm. See docs/offboard.md.

Exit code: ``FlightStatus.exit_code`` (0 complete, 3 diverged, 4 NaN command, 5 link lost,
6 failsafe, 7 mode changed, 8 command rejected, 9 lost track, 11 estimate lost, 130
interrupted); 2 for a bad argument or file, no vehicle at all, or a vehicle whose clock runs at
another rate than ours.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import signal
import sys
import time
from pathlib import Path
from typing import TextIO

from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.controller.design import SENSITIVITY_PEAK
from offboard.controllers import ControllerKind
from offboard.model.vehicle import VEHICLE_MODELS

#: ``--controller paper``: Table I's gains (the paper's law as published), one word away.
PAPER_KEYWORD = "paper"
from offboard import jsonout
#: ``--controller se3`` / ``px4``: a baseline (``offboard.controllers``) believing what the law would.
BASELINE_KEYWORDS = ("se3", "px4")
from offboard.errors import UserError
from offboard.signing import SigningKey, SigningKeyError, SigningSession, load_key
from offboard.flight import AUTO_TELEMETRY_RATE, OUTPUTS, ControllerChoice, Flight, FlightConfig, FlightResult, HeadingHoldMode, LogClock, Progress, SampleClock
from offboard.echo import echo_words
from offboard.metrics import LOST_TRACK_M, LOST_TRACK_WINDOW_S, check_tracking, format_table, summarize
from offboard.record import FlightStatus
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_folder



class FlyArgumentError(UserError, ValueError):
    """An option's value is well-formed for argparse but meaningless (e.g. ``--sample-time 0``)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard fly`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "fly",
        help="fly a mission over MAVLink (sitl-plant, PX4 SITL) with the paper's controller",
        description="Connect to a vehicle, stream setpoints, switch to OFFBOARD, arm, fly MISSION with the "
        "Rosales et al. controller, land and disarm; print the tracking table and leave the log, "
        "figures and summary in a run folder. The exit code says how the flight ended.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("mission", type=Path, help="mission file: parametric .toml, QGC WPL .waypoints or .plan")
    link = parser.add_argument_group("link")
    link.add_argument("--connect", default="udpin:0.0.0.0:14540", metavar="URL",
                      help="pymavlink connection string (udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, serial device)")
    link.add_argument("--lockstep", action="store_true",
                      help="sample on each telemetry burst instead of on our own clock (sitl-plant --lockstep)")
    link.add_argument("--clock", choices=[c.value for c in SampleClock], default=SampleClock.AUTO.value,
                      help="real time: sample every To of our clock (wall), or of the vehicle's time_boot_ms (vehicle: "
                           "one running faster or slower than real time, PX4 SITL --speed, sitl-plant --speed), or "
                           "measure the vehicle's clock rate before OFFBOARD and take the one that runs at it (auto)")
    link.add_argument("--target-system", type=int, default=None, metavar="N", help="fly this system id (default: the first autopilot heard)")
    link.add_argument("--sysid", type=int, default=245, metavar="N", help="our MAVLink system id")
    link.add_argument("--compid", type=int, default=191, metavar="N", help="our MAVLink component id (191: onboard computer)")
    link.add_argument("--signing-key", type=Path, default=None, metavar="FILE",
                      help="MAVLink 2 signing: sign what we send, refuse frames not signed with this key (32 bytes, or "
                           "PX4's 40-byte key file, whose timestamp is kept up to date in real time)")
    link.add_argument("--heartbeat-timeout", type=float, default=10.0, metavar="S", help="wait this long for the vehicle's heartbeat")
    link.add_argument("--telemetry-timeout", type=float, default=0.5, metavar="S",
                      help="telemetry older than this stops the setpoints (LINK_LOST)")
    link.add_argument("--reconnect-timeout", type=float, default=5.0, metavar="S",
                      help="give up when telemetry has not come back within this")
    link.add_argument("--telemetry-rate", type=float, default=None, metavar="HZ",
                      help="ask for ATTITUDE and LOCAL_POSITION_NED at this rate (0: keep the vehicle's; default: the "
                           "sample rate 1/To in lockstep, in real time its smallest whole multiple >= 100 Hz)")
    link.add_argument("--keep-streams", action="store_true",
                      help="leave on the vehicle's streams we never read (default: switched off with "
                           "MAV_CMD_SET_MESSAGE_INTERVAL -1, as PX4's clients do)")
    link.add_argument("--no-setpoint-echo", action="store_true",
                      help="do not ask for the vehicle's ATTITUDE_TARGET (default: 10 Hz, paired with the attitude setpoints "
                           "sent: when the vehicle took each, in its clock; not in lockstep)")
    link.add_argument("--land-timeout", type=float, default=60.0, metavar="S", help="wall-clock limit for the landing")
    guard = parser.add_argument_group("when the vehicle is handed to its own landing")
    guard.add_argument("--lost-track-m", type=float, default=LOST_TRACK_M, metavar="M",
                       help=f"when the 3D error stays above M for {LOST_TRACK_WINDOW_S:g} s and does not shrink (LOST_TRACK, "
                            f"exit 9; default {LOST_TRACK_M:g}; inf: never)")
    guard.add_argument("--ignore-estimator", action="store_true",
                       help="fly on when the vehicle's ESTIMATOR_STATUS stops vouching for its attitude, velocity or "
                            "position (default: ESTIMATE_LOST, exit 11)")
    ctl = parser.add_argument_group("controller")
    ctl.add_argument("--takeoff-heading-hold", choices=[m.value for m in HeadingHoldMode], default="auto",
                     help="hold the yaw reference at the take-off heading until EKF2_DELAY_MAX + 1 s after the vehicle is "
                          "1.5 m above its take-off point, where PX4's EKF2 aligns its heading from the magnetometer (a "
                          "turning vehicle is then given a heading that lags the turn); auto: where the vehicle publishes an "
                          "EKF2 fusing a magnetometer (default: auto)")
    ctl.add_argument("--output", choices=OUTPUTS, default=None,
                     help="SET_ATTITUDE_TARGET with an attitude or body rates (what PX4 accepts), or "
                          "SET_ACTUATOR_CONTROL_TARGET (eq. 16 torques) (default: what the controller file's gains were "
                          "designed for, its [law] setpoint_output; else attitude)")
    ctl.add_argument("--model", choices=VEHICLE_MODELS, default="rigid-body",
                     help="what the vehicle is: a rigid body (ZYX angles, W_eta zyx) or sitl-plant --model paper (the file's W_eta)")
    ctl.add_argument("--controller", type=Path, default=None, metavar="FILE|paper|se3|px4",
                     help="controller file, or 'paper' for Table I's gains, or a baseline: 'se3' (Lee's SE(3) controller) "
                          "or 'px4' (PX4's position cascade), believing what the law would (default: with the attitude "
                          "or rates output on a rigid body, gains designed for the vehicle's inner loop from its parameters, "
                          "believing its SIM_*/SIH_* mass and inertia (docs/controller-design.md); else Table I's)")
    ctl.add_argument("--design-latency", type=float, default=None, metavar="S",
                     help="latency the designed gains allow for (default: 0 in lockstep; in real time measured, the "
                          "TIMESYNC round trip plus one telemetry period)")
    ctl.add_argument("--no-integral", action="store_true",
                     help="design the gains without the law's velocity integral (docs/controller-design.md)")
    ctl.add_argument("--sensitivity-peak", type=float, default=None, metavar="MS",
                     help="design the gains for at most this max |1/(1+L)| (> 1; 'inf' for no bound; default: "
                          "offboard tune's, 1.6): lower is a gentler loop that follows the vehicle's estimator "
                          "errors less and the reference less tightly (docs/controller-design.md)")
    ctl.add_argument("--no-predict", action="store_true",
                     help="hand the designed law the measured state, the gains designed for the latency (default, "
                          "with the attitude output and a latency: the state predicted over the latency by the "
                          "inner loop's model, the gains designed for that; docs/controller-design.md)")
    ctl.add_argument("--no-observe", action="store_true",
                     help="with the prediction, take the autopilot's rate-loop integral and motor torque at hover, and "
                          "design the gains for that (default: observed from how the tilt and body rate moved against "
                          "the inner loop's model, the gains designed for that; docs/controller-design.md, \"The rate "
                          "loop observed\")")
    ctl.add_argument("--mass-from-vehicle", action="store_true", help="use the vehicle's SIM_MASS even with --controller")
    ctl.add_argument("--yaw-aware", action=argparse.BooleanOptionalAction, default=None,
                     help="horizontal law in the heading frame (default: the file's; without a file on for rigid-body)")
    ctl.add_argument("--tilt-max-deg", type=float, default=None, metavar="DEG",
                     help="limit on x7ez and x9ez (90: none; default: the file's, else 35)")
    ctl.add_argument("--thrust-min", type=float, default=None, metavar="FRACTION",
                     help="lower bound of u as a fraction of SIM_THR_MAX (default: the file's, else 0.12 "
                     "on a rigid body (PX4's MPC_THR_MIN, keeps torque authority), 0 on the paper's model)")
    ctl.add_argument("--sample-time", type=float, default=None, metavar="S", help="To (default: the file's, 0.05)")
    ctl.add_argument("--thrust-max-n", type=float, default=None, metavar="N",
                     help="thrust at normalised 1, for a vehicle that does not publish SIM_THR_MAX (real PX4)")
    out = parser.add_argument_group("output")
    out.add_argument("--log", type=Path, default=None, metavar="FILE.tlog", help="tlog of every packet (default: RUN_DIR/flight.tlog)")
    out.add_argument("--log-clock", choices=("sim", "wall"), default="sim",
                     help="tlog timestamps in lockstep: the vehicle's time (the same log every run), or the wall clock "
                          "when each packet is sent or handled (to measure the loop's hand-overs, as sitl-plant "
                          "--log-clock wall); in real time always the wall clock")
    out.add_argument("--run-dir", type=Path, default=None, metavar="DIR",
                     help="folder for log, figures, CSV and summary (default: runs/fly-<mission>-<time>)")
    out.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    out.add_argument("--json", action="store_true", help="print the summary as one JSON object instead of a table")
    out.add_argument("--quiet", action="store_true", help="no events or live progress line")
    parser.set_defaults(func=run)


def _check(args: argparse.Namespace) -> None:
    def positive(name: str, value: float | None) -> None:
        if value is not None and not (math.isfinite(value) and value > 0):
            raise FlyArgumentError(f"--{name}: must be > 0, got {value}")

    for name in ("heartbeat-timeout", "telemetry-timeout", "reconnect-timeout", "land-timeout", "sample-time", "thrust-max-n"):
        positive(name, getattr(args, name.replace("-", "_")))
    if args.signing_key is not None:
        _signing_key(args.signing_key)  # a bad key file: one line before anything starts
    if args.telemetry_rate is not None and not (math.isfinite(args.telemetry_rate) and args.telemetry_rate >= 0):
        raise FlyArgumentError(f"--telemetry-rate: must be >= 0, got {args.telemetry_rate}")
    if args.clock == "vehicle" and args.lockstep:
        raise FlyArgumentError("--clock vehicle: not with --lockstep (which samples on every telemetry burst)")
    if args.sensitivity_peak is not None and not args.sensitivity_peak > 1.0:  # inf: no bound; NaN refused
        raise FlyArgumentError(f"--sensitivity-peak: must be > 1 ('inf' for no bound), got {args.sensitivity_peak}")
    if args.design_latency is not None and not (math.isfinite(args.design_latency) and 0 <= args.design_latency < 10):
        raise FlyArgumentError(f"--design-latency: must be a latency in [0, 10) s, got {args.design_latency}")
    if args.thrust_min is not None and not (math.isfinite(args.thrust_min) and 0 <= args.thrust_min < 1):
        raise FlyArgumentError(f"--thrust-min: must be a fraction in [0, 1), got {args.thrust_min}")
    if not args.lost_track_m > 0:  # inf: never; NaN is not > 0
        raise FlyArgumentError(f"--lost-track-m: must be > 0 (inf: never), got {args.lost_track_m}")
    if args.tilt_max_deg is not None and not (math.isfinite(args.tilt_max_deg) and args.tilt_max_deg > 0):
        raise FlyArgumentError(f"--tilt-max-deg: must be > 0 (90 or more: no limit), got {args.tilt_max_deg}")
    for name in ("sysid", "compid", "target_system"):
        value = getattr(args, name)
        if value is not None and not 1 <= value <= 255:
            raise FlyArgumentError(f"--{name.replace('_', '-')}: must be 1..255, got {value}")
    kind = _baseline(args)
    if kind is not None and (args.output not in (None, "attitude") or args.model != "rigid-body"):
        raise FlyArgumentError(f"--controller {kind}: flies --output attitude on a --model rigid-body vehicle only "
                               f"(it gives an attitude target, thrust and yaw-rate feed-forward)")


def flown_output(asked: str | None, designed: str | None, controller_file: Path | None) -> str:
    """The setpoint a flight sends: ``--output`` (``asked``, None when not given), else the one the
    controller file's gains were designed for (``designed``, its ``[law] setpoint_output``), else
    the attitude.

    Raises
    ------
    FlyArgumentError
        ``--output`` asks for another setpoint than the file's gains were designed for: they
        would close a loop their design never saw (an attitude design's kx7..kx10 are Table I's,
        and a rates design's position gains were chosen around the law's own angle stage).
    """
    if asked is None:
        return designed or "attitude"
    if designed is not None and asked != designed:
        tune = "offboard tune --setpoint-output " + ("attitude" if asked == "attitude" else "rates")
        raise FlyArgumentError(f"--output {asked}: the gains of {controller_file} were designed for --output {designed} (its "
                               f"[law] setpoint_output); fly it with --output {designed}" +
                               (f", or design a file for {asked}: {tune}" if asked in ("attitude", "rates") else ""))
    return asked


def _baseline(args: argparse.Namespace) -> str | None:
    """The baseline ``--controller`` names, or None (a file, the paper's law, the default)."""
    name = None if args.controller is None else str(args.controller)
    return name if name in BASELINE_KEYWORDS else None


class _Console:
    """Events as lines, progress as one line refreshed in place (only on a terminal)."""

    def __init__(self, stream: TextIO, quiet: bool) -> None:
        self.stream = stream
        self.quiet = quiet
        self.live = not quiet and stream.isatty()
        self._shown = False
        self._last = 0.0

    def event(self, text: str) -> None:
        if self.quiet:
            return
        self._clear()
        print(f"offboard: {text}", file=self.stream, flush=True)

    def progress(self, p: Progress) -> None:
        if not self.live:
            return
        now = time.monotonic()
        if now - self._last < 0.1:
            return
        self._last = now
        n, e, d = p.pos_ned_m
        # the mission: its time and the 3D error; the landing (no reference): time since it began
        tail = f"  error {p.error_m:6.3f} m" if math.isfinite(p.error_m) else f"  {-d:6.2f} m above home"
        clock = f"t={p.t_s:7.2f} s" if math.isfinite(p.error_m) else f"+{p.t_s:6.2f} s"
        self.stream.write(f"\r{p.phase:<14.14} {clock}  N {n:7.2f}  E {e:7.2f}  D {d:7.2f} m{tail}\x1b[K")
        self.stream.flush()
        self._shown = True

    def _clear(self) -> None:
        if self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._shown = False

    def end(self) -> None:
        self._clear()


class _Interrupts:
    """Ctrl-C: the first asks the flight to land and stop; the second stops waiting at once."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, object] = {}

    def __enter__(self) -> _Interrupts:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]


def run(args: argparse.Namespace) -> int:
    """``offboard fly``: fly the mission; the flight status's exit code (``FlightStatus``)."""
    from offboard.missions import load_mission

    _check(args)
    mission = load_mission(args.mission)
    kind = ControllerKind(_baseline(args) or ControllerKind.PAPER)
    from_file = args.controller is not None and str(args.controller) not in (PAPER_KEYWORD, *BASELINE_KEYWORDS)
    base = load_controller(args.controller if from_file else PAPER_CONTROLLER_FILE)
    args.output = flown_output(args.output, base.setpoint_output, args.controller if from_file else None)
    latency = 0.0 if args.lockstep and args.design_latency is None else args.design_latency
    # the design models an autopilot's attitude loop (the attitude output) or its rate loop (the
    # rates output) on a rigid body; the paper model's own inner loop and the actuator output fly
    # the paper's gains
    tuned = args.controller is None and args.model == "rigid-body" and args.output in ("attitude", "rates")
    if args.sensitivity_peak is not None and not tuned:
        raise FlyArgumentError("--sensitivity-peak: only for the gains offboard fly designs (no --controller, "
                               "--model rigid-body, the attitude or rates output)")
    choice = ControllerChoice(
        base=base,
        kind=kind,
        from_file=from_file,
        tuned=tuned,
        sensitivity_peak=SENSITIVITY_PEAK if args.sensitivity_peak is None else args.sensitivity_peak,
        latency_s=latency,
        mass_from_vehicle=args.mass_from_vehicle,
        yaw_aware=args.yaw_aware,
        tilt_max_deg=args.tilt_max_deg,
        thrust_min_fraction=args.thrust_min,
        sample_time_s=args.sample_time,
        velocity_integral=not args.no_integral,
        body_rates=args.output == "rates",
        predict=not args.no_predict,
        observe=not args.no_observe,
    )
    config = FlightConfig(
        output=args.output,
        model=args.model,
        lockstep=args.lockstep,
        clock=SampleClock(args.clock),
        telemetry_timeout_s=args.telemetry_timeout,
        reconnect_timeout_s=args.reconnect_timeout,
        heartbeat_timeout_s=args.heartbeat_timeout,
        land_timeout_s=args.land_timeout,
        telemetry_rate_hz=AUTO_TELEMETRY_RATE if args.telemetry_rate is None else (args.telemetry_rate or None),
        unread_streams_off=not args.keep_streams,
        setpoint_echo=not args.no_setpoint_echo,
        lost_track_m=args.lost_track_m,
        watch_estimator=not args.ignore_estimator,
        takeoff_heading_hold=HeadingHoldMode(args.takeoff_heading_hold),
        target_system=args.target_system,
        connect=args.connect,
    )
    run_dir = args.run_dir or Path("runs") / f"fly-{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    created = [p for p in (run_dir, *run_dir.parents) if not p.exists()]  # ours to remove if nothing is flown
    output_folder(run_dir, "--run-dir")
    tlog = args.log if args.log is not None else run_dir / "flight.tlog"
    log_clock = LogClock(args.lockstep, wall=args.log_clock == "wall")
    console = _Console(sys.stderr, args.quiet)
    # the files behind the flight, by their full paths, so that `offboard replay --rerun` finds them
    # from anywhere: the mission, and the controller file (None: the paper's gains believing the
    # vehicle's SIM_* values, offboard fly's default)
    meta = {"mission": mission.name, "mission_source": mission.source, "mission_file": str(args.mission.resolve()),
            "controller_file": str(args.controller.resolve()) if from_file else None,
            "controller_choice": "file" if from_file else ("tuned" if choice.tuned else "paper"),
            "controller_kind": kind,
            "output": args.output, "model": args.model, "lockstep": args.lockstep, "clock": args.clock,
            "connect": args.connect,
            # the guards (docs/offboard.md, "In flight"): null, never
            "lost_track_m": args.lost_track_m if math.isfinite(args.lost_track_m) else None,
            "watch_estimator": not args.ignore_estimator}  # fmt: skip
    started = time.monotonic()
    try:
        return _fly(args, mission, choice, config, meta, run_dir, tlog, log_clock, console, started)
    except UserError:
        _remove_if_empty(tlog, created)
        raise


def _remove_if_empty(tlog: Path, created: list[Path]) -> None:
    """After a flight that never started (no vehicle, a refused link): no 0-byte log and no empty
    run folder left behind; a log with packets in it stays, for the diagnosis."""
    try:
        if tlog.is_file() and tlog.stat().st_size == 0:
            tlog.unlink()
        for folder in created:  # deepest first
            folder.rmdir()  # only if empty
    except OSError:
        pass


def _signing_key(path: Path) -> SigningKey:
    try:
        return load_key(path)
    except SigningKeyError as exc:
        raise FlyArgumentError(str(exc)) from None


def _fly(args: argparse.Namespace, mission, choice: ControllerChoice, config: FlightConfig, meta: dict, run_dir: Path,
         tlog: Path, log_clock: LogClock, console: _Console, started: float) -> int:
    from offboard.link import MavLink
    from offboard.model.busywait import LOCKSTEP_SPIN_S

    signing = None
    if args.signing_key is not None:
        # the log's simulation clock signs: simulation time in lockstep (the same bytes every run, nothing
        # persisted), the wall clock otherwise (the timestamp kept in the key file)
        signing = SigningSession(_signing_key(args.signing_key), log_clock.sim_us, key_path=None if args.lockstep else args.signing_key,
                                 lockstep=args.lockstep)  # fmt: skip
    link = MavLink(args.connect, sysid=args.sysid, compid=args.compid, tlog_path=tlog, log_time_us=log_clock, signing=signing,
                   spin_s=LOCKSTEP_SPIN_S if args.lockstep else 0.0)  # fmt: skip
    console.event(f"listening on {args.connect}" if args.connect.startswith("udpin") else f"connecting to {args.connect}")
    try:
        with _Interrupts() as interrupts:
            flight = Flight(
                link, mission.trajectory, choice, config,
                thrust_max_n=args.thrust_max_n,
                stop_requested=lambda: interrupts.requested,
                log_clock=log_clock,
                progress=console.progress,
                event=console.event,
                meta=meta,
                mission_home=mission.home,
            )  # fmt: skip
            result = flight.run()
    finally:
        console.end()
        link.close()
    wall = time.monotonic() - started
    if result.status is FlightStatus.COMPLETE and check_tracking(result.record).status is not FlightStatus.COMPLETE:
        result = dataclasses.replace(result, status=result.record.status, detail=result.record.status_detail)
    payload, table = _report(result, link.stats.to_dict(), wall, run_dir, tlog, meta, args.no_plots)
    if args.json:
        print(jsonout.dumps(payload))
    else:
        if table:
            print(table)
        print(f"run folder: {run_dir} (log {tlog})")
    if result.status is not FlightStatus.COMPLETE:
        print(f"offboard fly: {result.status.name}: {result.detail}", file=sys.stderr)
    return result.status.exit_code


def fly_summary(result: FlightResult, link_stats: dict, wall_s: float) -> dict:
    """Everything the summary reports beyond the tracking table, as plain data."""
    to = result.controller.sample_time_s if result.controller is not None else math.nan
    c = result.controller
    return {
        "status": result.status.value,
        "exit_code": result.status.exit_code,
        "detail": result.detail,
        "wall_time_s": wall_s,
        "vehicle": None if result.vehicle is None else {"system": result.vehicle[0], "component": result.vehicle[1]},
        "vehicle_params": result.vehicle_params,
        "controller": None if c is None else {
            "sample_time_s": c.sample_time_s, "mass_kg": c.mass_kg, "arm_length_m": c.arm_length_m,
            "inertia_kg_m2": list(c.inertia_kg_m2), "gravity_m_s2": c.gravity_m_s2,
            "drag_to_thrust_m": c.drag_to_thrust_m, "euler_rate_form": c.euler_rate_form, "yaw_aware": c.yaw_aware,
            "gains": dataclasses.asdict(c.gains),
            "integral_gain_per_s": c.integral_gain_per_s, "integral_limit_m_s": c.integral_limit_m_s,
            "velocity_integral_gain_per_s2": c.velocity_integral_gain_per_s2,
            "vertical_velocity_integral_gain_per_s2": c.vertical_velocity_integral_gain_per_s2,
            "velocity_integral_limit_m_s2": c.velocity_integral_limit_m_s2,
            "reference_lead_s2": list(c.reference_lead_s2), "tilt_lead": c.tilt_lead,
            "linear_drag_n_s_m": c.linear_drag_n_s_m, "velocity_from_position_s": c.velocity_from_position_s,
            "velocity_from_position_identify": c.velocity_from_position_identify,
            "velocity_integral_hold_s": c.velocity_integral_hold_s,
            "setpoint_output": c.setpoint_output,
            "thrust_min_n": c.limits.thrust_min_n, "thrust_max_n": c.limits.thrust_max_n,
            "tilt_max_deg": None if c.limits.tilt_max_rad is None else math.degrees(c.limits.tilt_max_rad),
            "tilt_cone": c.limits.tilt_cone, "speed_xy_max_m_s": c.limits.speed_xy_max_m_s,
            "speed_up_max_m_s": c.limits.speed_up_max_m_s, "speed_down_max_m_s": c.limits.speed_down_max_m_s,
            "yaw_rate_max_rad_s": c.limits.yaw_rate_max_rad_s, "rate_carry_s": c.limits.rate_carry_s,
        },  # fmt: skip
        "messages": link_stats,
        "loop": result.loop.to_dict(to),
        "link_outages_s": result.outages,
        # where the mission's origin (its home) lies in the vehicle's local frame (waypoint files)
        "mission_offset_ned_m": None if result.home_offset_ned_m is None else list(result.home_offset_ned_m),
        "timesync": result.timesync,
        "landed": result.landed,
        "disarmed": result.disarmed,
        "takeoff_heading_hold": result.heading_hold,
        "estimator_heading_resets": result.heading_resets,
        # the latency the law's state was predicted over (null: the measured state), for replay --rerun
        "predicted_latency_s": result.predicted_latency_s,
        # whether that prediction observed the autopilot's rate-loop integral and torque (null: not predicted)
        "observed_rate_loop": result.observed_rate_loop,
        # how long the observer took to forget an error of its estimates (s; null: not observed)
        "observer_memory_s": result.observer_memory_s,
        # when the vehicle took the setpoints, after the telemetry they answer, in its clock (its
        # ATTITUDE_TARGET echo, offboard.echo; null: not asked for)
        "setpoint_echo": result.setpoint_echo,
        "notes": result.notes,
    }


def format_timesync(offset_ms: float, rtt_ms: float) -> str:
    """The TIMESYNC line: offset = the vehicle's clock minus ours (MAVLink's TIMESYNC), which only
    says where the two clocks started (its boot, our monotonic clock's origin), not an error."""
    side = "ahead of" if offset_ms >= 0 else "behind"
    return (f"timesync: the vehicle's clock is {abs(offset_ms) / 1000:.3f} s {side} ours (offset {offset_ms:.3f} ms: "
            f"where the two clocks started, not an error), round trip {rtt_ms:.3f} ms")  # fmt: skip


def format_fly_lines(extra: dict, lockstep: bool = False, vehicle_clock: bool = False) -> str:
    """The lines under the tracking table: messages, loop timing, outages, landing.

    In lockstep the vehicle paces the samples, so the period's jitter against To means nothing
    and is not shown (summary.json keeps it); on the vehicle's clock it is the vehicle's.
    """
    m, loop = extra["messages"], extra["loop"]
    lost_pct = 100.0 * m["lost"] / max(m["received"] + m["lost"], 1)
    jitter = (f"period jitter p50 {loop['jitter_p50_ms']:.2f} ms, p99 {loop['jitter_p99_ms']:.2f} ms, "
              f"max {loop['jitter_max_ms']:.2f} ms")  # fmt: skip
    timing = ("lockstep: paced by the vehicle" if lockstep else f"on the vehicle's clock, its {jitter}" if vehicle_clock else jitter)
    lines = [
        f"messages: sent {m['sent']}, received {m['received']}, lost {m['lost']} ({lost_pct:.2f} %), "
        f"duplicates {m['duplicates']}, bad {m['bad']}"
        + (f", refused by signing {sum(m['refused'].values())} ({', '.join(f'{k} {v}' for k, v in m['refused'].items())})"
           if m.get("refused") else ""),
        f"loop: {loop['samples']} samples in {loop['mission_wall_s']:.2f} s wall ({loop['rate_hz']:.1f} Hz), "
        f"{timing}, overruns {loop['overruns']}, missed {loop['missed']}",
    ]
    if extra["link_outages_s"]:
        lines.append(f"link outages: {len(extra['link_outages_s'])} ({', '.join(f'{g:.2f} s' for g in extra['link_outages_s'])})")
    if extra["timesync"]:
        lines.append(format_timesync(extra["timesync"]["offset_ms"], extra["timesync"]["rtt_ms"]))
    if extra.get("setpoint_echo") is not None:
        lines.append(echo_words(extra["setpoint_echo"], extra.get("predicted_latency_s")))
    landing = "landed and disarmed" if extra["landed"] and extra["disarmed"] else (
        "landed, still armed" if extra["landed"] else "landing not confirmed")
    lines.append(f"{landing}; {extra['wall_time_s']:.1f} s wall in all")
    return "\n".join(lines)


def _report(result: FlightResult, link_stats: dict, wall_s: float, run_dir: Path, tlog: Path,
            meta: dict, no_plots: bool) -> tuple[dict, str]:
    """Write series.csv, summary.txt and summary.json, then the figures (and summary.json again,
    naming them): a Ctrl-C while the figures are drawn costs only the figures."""
    record = result.record
    # the flight resolves the sample clock (--clock auto) and measures the vehicle's rate
    meta = {**meta, **{k: record.meta[k] for k in ("clock", "clock_rate") if k in record.meta}}
    extra = fly_summary(result, link_stats, wall_s)
    payload: dict = {**meta, "run_dir": str(run_dir), "log": str(tlog)}
    table = format_fly_lines(extra, bool(meta["lockstep"]), meta.get("clock") == "vehicle")
    if len(record):
        summary = summarize(record)
        table = format_table(summary) + "\n" + table
        payload.update(summary.to_dict())
        record.write_csv(run_dir / "series.csv")
    payload.update(extra)
    (run_dir / "summary.txt").write_text(table + "\n")
    _write_summary_json(run_dir, payload)
    if len(record) and not no_plots:
        try:
            from offboard.plots import write_figures  # matplotlib: a second or more

            figures = write_figures(record, run_dir, title=f"{meta['mission']} over MAVLink ({meta['output']})")
        except KeyboardInterrupt:
            print(f"offboard fly: interrupted while drawing the figures; the log, series.csv and the summaries "
                  f"are in {run_dir}", file=sys.stderr)
            raise
        payload["figures"] = [str(p) for p in figures]
        _write_summary_json(run_dir, payload)
    return payload, table


def _write_summary_json(run_dir: Path, payload: dict) -> None:
    """summary.json whole or not at all: written aside, then renamed over the old one."""
    partial = run_dir / "summary.json.partial"
    partial.write_text(jsonout.dumps(payload, indent=2) + "\n")
    partial.replace(run_dir / "summary.json")
