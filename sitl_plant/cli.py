"""``sitl-plant``: a simulated PX4 quadrotor speaking MAVLink 2 over UDP.

Fly it as you would fly PX4 SITL: an offboard program or MAVSDK on ``udpin:0.0.0.0:14540``, a
ground station on UDP 14550. See ``docs/plant.md`` for messages, parameters, modes and lockstep.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path
from typing import TextIO

try:  # a third of a second of imports (numpy and the plant), before main() can catch a Ctrl-C
    from sitl_plant.autopilot import FAILURE_UNITS, Autopilot
    from sitl_plant.codec import Home
    from offboard.model.clihelp import HelpFormatter, add_version
    from offboard.model.errors import UserError
    from sitl_plant.inner_loops import InnerLoops
    from offboard.signing import SigningKey, SigningKeyError, SigningSession, load_key
    from sitl_plant.impairment import Impairment, ImpairmentError, ImpairmentSpec, parse_impairment
    from offboard.model.tlog import TlogWriter
    from sitl_plant.link import Endpoint, Link, parse_address
    from sitl_plant.params import plant_params
    from offboard.model.tlog import LOCKSTEP_EPOCH_S, wall_clock_us
    from offboard.model.vehicle import DEFAULT_VEHICLE_FILE, load_vehicle
    from sitl_plant.server import Plant, PlantConfig, RunStats, run_lockstep, run_realtime
    from sitl_plant.dynamics.sensors import CleanSensors, SensorModel, sensors_from_spec
    from sitl_plant.dynamics.wind import WindField, wind_from_spec
    from offboard.model.vehicle import VEHICLE_MODELS
except KeyboardInterrupt:
    print("sitl-plant: interrupted while starting", file=sys.stderr)
    sys.exit(130)

API_BIND_PORT, API_REMOTE_PORT = 14580, 14540  # PX4 SITL's offboard link
GCS_BIND_PORT, GCS_REMOTE_PORT = 18570, 14550  # PX4 SITL's ground-station link
#: PX4 SITL's -i N gives the vehicle MAV_SYS_ID N + 1, at most 255.
MAX_INSTANCE = 254


class ArgumentError(UserError, ValueError):
    """An option's value is well-formed for argparse but meaningless (e.g. ``--speed 0``)."""


def build_parser() -> argparse.ArgumentParser:
    """``sitl-plant``'s options (``--help`` lists them by group)."""
    parser = argparse.ArgumentParser(
        prog="sitl-plant",
        description="A simulated PX4-style quadrotor autopilot speaking MAVLink 2 over UDP. "
        "Connect an offboard program with udpin:0.0.0.0:14540 (plus --instance), a ground station on UDP 14550.",
        formatter_class=HelpFormatter,
    )
    add_version(parser, "sitl-plant")
    sim = parser.add_argument_group("simulation")
    sim.add_argument("--model", choices=VEHICLE_MODELS, default="rigid-body", help="dynamics: Newton-Euler rigid body, or the paper's model (eq. 13, 18)")
    sim.add_argument("--vehicle", metavar="FILE", type=Path, default=DEFAULT_VEHICLE_FILE,
                     help="vehicle parameter file (TOML); bundled: sitl-quad (default, hovers at 0.5 as PX4 SITL), "
                          "paper-quad (the paper's, hovers at 0.25), px4-sih (PX4 SITL's SIH quadrotor)")
    sim.add_argument("--inner-loop", choices=InnerLoops.KINDS, default="px4", help="how attitude setpoints are flown: PX4's attitude/rate controllers, or the paper's tau_tilde with eq. 16")
    sim.add_argument("--wind", metavar="SPEC", default="none", help="wind: none | constant:N,E,D | dryden:SPEED[,dir=DEG,...] | gust:t=S,amp=M_S,dur=S, joined with '+'")
    sim.add_argument("--noise", metavar="SPEC", default="clean", help="sensor model for the telemetry: clean | paper[:FRACTION] | imu[:pos=M,vel=M_S,att=RAD,rate=RAD_S,acc=M_S2]")
    sim.add_argument("--seed", type=int, default=0, help="seed of wind, sensor noise and a lost GPS's dead reckoning")
    sim.add_argument("--home", metavar="LAT,LON,ALT", default="47.397742,8.545594,488.0", help="origin of the local frame: degrees, degrees, metres AMSL")
    sim.add_argument("--physics-dt", metavar="S", type=float, default=0.001, help="RK4 step, seconds")
    sim.add_argument("--unhealthy", metavar="UNITS", default="", help=f"simulated sensor failures that block arming, comma-separated: {', '.join(FAILURE_UNITS.values())}")
    timing = parser.add_argument_group("time")
    timing.add_argument("--speed", metavar="N", type=float, default=1.0, help="run N times faster than real time (ignored in lockstep)")
    timing.add_argument("--lockstep", action="store_true", help="advance one period each time the setpoint answering the latest telemetry arrives (deterministic)")
    timing.add_argument("--lockstep-period", metavar="S", type=float, default=0.05, help="lockstep period, seconds: a whole number of milliseconds and of physics steps")
    timing.add_argument("--duration", metavar="S", type=float, default=None, help="stop after S seconds of simulation time (default: run until Ctrl-C)")
    net = parser.add_argument_group("links")
    net.add_argument("--instance", metavar="N", type=int, default=0,
                     help="added to the default ports, as PX4 SITL's -i N (the GCS remote stays 14550); 10 and 40 or more "
                          "would send the API link to 14550 or another instance's port: refused without --api-remote")
    net.add_argument("--api-bind", metavar="HOST:PORT", default=None, help=f"offboard/API link local address (default 0.0.0.0:{API_BIND_PORT}+instance)")
    net.add_argument("--api-remote", metavar="HOST:PORT", default=None, help=f"where the API link sends until a client talks (default 127.0.0.1:{API_REMOTE_PORT}+instance; 'none': wait to be talked to)")
    net.add_argument("--gcs-bind", metavar="HOST:PORT", default=None, help=f"ground-station link local address (default 0.0.0.0:{GCS_BIND_PORT}+instance; 'none' switches the link off)")
    net.add_argument("--gcs-remote", metavar="HOST:PORT", default=None, help=f"where the GCS link sends until a client talks (default 127.0.0.1:{GCS_REMOTE_PORT}; 'none': wait)")
    net.add_argument("--sysid", metavar="N", type=int, default=1, help="MAVLink system id (component is 1, the autopilot)")
    net.add_argument("--log", metavar="FILE.tlog", type=Path, default=None, help="record every packet sent and received (tlog)")
    net.add_argument("--ftp-root", metavar="DIR", type=Path, default=None,
                     help="the folder MAVLink FTP serves, read-only (default: the folder of --log; none without --log)")
    net.add_argument("--log-clock", choices=("sim", "wall"), default="sim",
                     help="tlog timestamps: start epoch + simulation time (reproducible in lockstep), or the wall "
                     "clock when each packet is sent or handled (to measure latencies)")
    sec = parser.add_argument_group("who may talk to the vehicle")
    sec.add_argument("--signing-key", metavar="FILE", type=Path, default=None,
                     help="MAVLink 2 signing: sign what we send and refuse frames not signed with this key (32 bytes, "
                          "or PX4's 40-byte key file); its timestamp is kept in the file (PX4's layout) in real time")
    sec.add_argument("--allow-sysid", metavar="N[,N...]", default=None,
                     help="handle frames only from these system ids (default: anyone's, as PX4); the others are "
                          "refused, counted and never answered")
    bad = parser.add_argument_group("a bad link (real time; seeded by --seed)")
    bad.add_argument("--link", metavar="SPEC", default=None,
                     help="impair both directions of every link: loss=PCT,delay=MS,jitter=MS,duplicate=PCT,reorder=PCT,"
                          "corrupt=PCT (any of them, e.g. loss=20,delay=50,jitter=20)")
    bad.add_argument("--link-in", metavar="SPEC", default=None, help="impair what the plant receives (replaces --link for it)")
    bad.add_argument("--link-out", metavar="SPEC", default=None, help="impair what the plant sends (replaces --link for it)")
    parser.add_argument("--quiet", action="store_true", help="no banner, status line or summary")
    return parser


def _impairments(args: argparse.Namespace) -> tuple[ImpairmentSpec | None, ImpairmentSpec | None]:
    """The receiving and the sending direction's impairment (None: a clean direction)."""
    try:
        both = parse_impairment(args.link, "--link") if args.link is not None else None
        into = parse_impairment(args.link_in, "--link-in") if args.link_in is not None else both
        out = parse_impairment(args.link_out, "--link-out") if args.link_out is not None else both
    except ImpairmentError as exc:
        raise ArgumentError(str(exc)) from None
    into = into if into is not None and into.active else None
    out = out if out is not None and out.active else None
    if (into or out) and args.lockstep:
        raise ArgumentError("--link: impairs a real-time link (delays are wall-clock time); not with --lockstep")
    return into, out


def _allowed_senders(text: str | None) -> frozenset[int] | None:
    if text is None:
        return None
    try:
        ids = frozenset(int(part) for part in text.split(","))
    except ValueError:
        raise ArgumentError(f"--allow-sysid: expected system ids separated by commas, such as 245,255, got {text!r}") from None
    if not ids or not all(1 <= n <= 255 for n in ids):
        raise ArgumentError(f"--allow-sysid: system ids are 1..255, got {text!r}")
    return ids


def _check(args: argparse.Namespace) -> None:
    if not 1 <= args.sysid <= 255:
        raise ArgumentError(f"--sysid: must be 1..255, got {args.sysid}")
    if not 0 <= args.instance <= MAX_INSTANCE:
        raise ArgumentError(f"--instance: must be 0..{MAX_INSTANCE} (PX4 SITL's -i N flies system id N + 1), got {args.instance}")
    if not args.speed > 0 or args.speed != args.speed:
        raise ArgumentError(f"--speed: must be > 0, got {args.speed}")
    if not args.physics_dt > 0:
        raise ArgumentError(f"--physics-dt: must be > 0, got {args.physics_dt}")
    if args.duration is not None and not args.duration > 0:
        raise ArgumentError(f"--duration: must be > 0, got {args.duration}")


def _instance_collision(n: int) -> str | None:
    """Where PX4's port layout (``px4-rc.mavlink``) makes instance ``n``'s API link send to a port
    that is someone else's: the ground stations' 14550 (n = 10), or another instance's API bind
    port (n >= 40: 14540 + n = 14580 + (n - 40)). None when it does not collide."""
    remote = API_REMOTE_PORT + n
    if remote == GCS_REMOTE_PORT:
        return f"{remote}, the ground stations' port (QGroundControl listens there)"
    if API_BIND_PORT <= remote <= API_BIND_PORT + MAX_INSTANCE:
        other = remote - API_BIND_PORT
        return f"{remote}, instance {other}'s own API port ({API_BIND_PORT} + {other})"
    return None


def _address(text: str | None, default: str, what: str) -> tuple[str, int] | None:
    try:
        return parse_address(default if text is None else text, what)
    except ValueError as exc:
        raise ArgumentError(str(exc)) from None


def _unhealthy(text: str) -> set[str]:
    units = {u.strip().lower() for u in text.split(",") if u.strip()}
    unknown = units - set(FAILURE_UNITS.values())
    if unknown:
        raise ArgumentError(f"--unhealthy: unknown unit(s) {', '.join(sorted(unknown))}; expected some of {', '.join(FAILURE_UNITS.values())}")
    return units


def _wind_and_sensors(args: argparse.Namespace) -> tuple[WindField | None, SensorModel | None]:
    wind = None if args.wind.strip().lower() == "none" else wind_from_spec(args.wind, args.seed)
    sensors = sensors_from_spec(args.noise, args.seed)
    return wind, (None if isinstance(sensors, CleanSensors) else sensors)


class _StatusLine:
    """The one-line status: refreshed in place on a terminal, a line every 10 s otherwise."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self._last = 0.0
        self._shown = False

    def __call__(self, line: str) -> None:
        if self.tty:
            self.stream.write("\r" + line + "\x1b[K")
            self.stream.flush()
            self._shown = True
        elif time.monotonic() - self._last >= 10.0:
            self._last = time.monotonic()
            print(line, file=self.stream, flush=True)

    def end(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()


def main(argv: list[str] | None = None) -> int:
    """``sitl-plant``: run until interrupted; 0, or 2 with one line for a bad option or file, 130 when
    interrupted while starting.
    """
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except UserError as exc:
        print(f"sitl-plant: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C before the run loop takes SIGINT itself (numba's load, the files, the links)
        print("sitl-plant: interrupted while starting", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    _check(args)
    n = args.instance
    collision = _instance_collision(n) if args.api_remote is None else None
    if collision is not None:
        raise ArgumentError(f"--instance {n}: the API link would send to 127.0.0.1:{collision}, as PX4 SITL's -i {n} "
                            f"would; choose an instance in 0..9 or 11..39, or give --api-remote HOST:PORT")
    api_bind = _address(args.api_bind, f"0.0.0.0:{API_BIND_PORT + n}", "--api-bind")
    api_remote = _address(args.api_remote, f"127.0.0.1:{API_REMOTE_PORT + n}", "--api-remote")
    gcs_bind = _address(args.gcs_bind, f"0.0.0.0:{GCS_BIND_PORT + n}", "--gcs-bind")
    gcs_remote = _address(args.gcs_remote, f"127.0.0.1:{GCS_REMOTE_PORT}", "--gcs-remote")
    if api_bind is None:
        raise ArgumentError("--api-bind: the API link cannot be switched off")
    try:
        home = Home.parse(args.home)
    except ValueError as exc:
        raise ArgumentError(f"--home: {exc}") from None
    failures = _unhealthy(args.unhealthy)
    vehicle = load_vehicle(args.vehicle)
    wind, sensors = _wind_and_sensors(args)

    config = PlantConfig(
        model=args.model,
        inner_loop=args.inner_loop,
        physics_dt_s=args.physics_dt,
        lockstep=args.lockstep,
        lockstep_period_s=args.lockstep_period,
        home=home,
        sysid=args.sysid,
        seed=args.seed,
        start_epoch_s=LOCKSTEP_EPOCH_S if args.lockstep else time.time(),
        log_path=args.log,
        ftp_root=_ftp_root(args),
        signing=args.signing_key is not None,
    )
    params = plant_params(vehicle, sysid=args.sysid)
    autopilot = Autopilot(params, home_alt_amsl_m=home.alt_m, failures=failures)
    try:
        plant = Plant(config, vehicle, params, autopilot, wind=wind, sensors=sensors)
    except ValueError as exc:
        raise ArgumentError(str(exc)) from None

    allowed = _allowed_senders(args.allow_sysid)
    key = _signing_key(args.signing_key)
    # the signing clock is the plant's (start epoch + simulation time): in lockstep, the same bytes
    # every run, and no timestamp persisted (offboard/signing.py)
    key_path = None if args.lockstep else args.signing_key

    def session(link_id: int) -> SigningSession | None:
        return None if key is None else SigningSession(key, plant.epoch_us, link_id=link_id, key_path=key_path, lockstep=args.lockstep)

    impair_in, impair_out = _impairments(args)

    def endpoint(name: str, link_id: int, bind, remote) -> Endpoint:
        # each direction of each link its own generator, from --seed: the same seed, the same fates
        return Endpoint(name, bind, remote, args.sysid, config.compid, signing=session(link_id), allowed_senders=allowed,
                        impair_in=Impairment(impair_in, f"{args.seed}/{name}/in") if impair_in else None,
                        impair_out=Impairment(impair_out, f"{args.seed}/{name}/out") if impair_out else None)  # fmt: skip

    endpoints = [endpoint("api", 0, api_bind, api_remote)]
    try:
        if gcs_bind is not None:
            endpoints.append(endpoint("gcs", 1, gcs_bind, gcs_remote))
        tlog = TlogWriter(args.log) if args.log is not None else None
    except UserError:
        for e in endpoints:
            e.close()
        raise
    link = Link(endpoints, tlog, plant.epoch_us if args.log_clock == "sim" else wall_clock_us, lockstep=args.lockstep)
    for direction, spec in (("in", impair_in), ("out", impair_out)):
        if spec is not None:
            link.note(f"sitl-plant --link-{direction} {spec.as_option()} --seed {args.seed}: {spec.describe()}")

    stopping = {"flag": False}

    def request_stop(signum: int, frame: object) -> None:
        stopping["flag"] = True

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    status = None if args.quiet else _StatusLine(sys.stderr)
    if not args.quiet:
        _banner(args, plant, link)
    try:
        if args.lockstep:
            stats = run_lockstep(plant, link, stop=lambda: stopping["flag"], status=status, max_sim_s=args.duration)
        else:
            stats = run_realtime(plant, link, speed=args.speed, stop=lambda: stopping["flag"], status=status, max_sim_s=args.duration)
    finally:
        link.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
        if status is not None:
            status.end()
    if not args.quiet:
        _summary(plant, link, stats)
    return 0


def _signing_key(path: Path | None) -> SigningKey | None:
    if path is None:
        return None
    try:
        return load_key(path)
    except SigningKeyError as exc:
        raise ArgumentError(str(exc)) from None
def _ftp_root(args: argparse.Namespace) -> Path | None:
    if args.ftp_root is not None:
        if not args.ftp_root.is_dir():
            raise ArgumentError(f"--ftp-root {args.ftp_root}: not a folder")
        return args.ftp_root
    return None if args.log is None else (args.log.parent if str(args.log.parent) else Path("."))


def _banner(args: argparse.Namespace, plant: Plant, link: Link) -> None:
    lines = [f"sitl-plant: {args.model} model of {plant.vehicle.name} ({args.vehicle}), inner loop {args.inner_loop}"]
    for e in link.endpoints:
        host, port = e.local_address
        remote = "whoever talks first" if e.remote is None else f"{e.remote[0]}:{e.remote[1]}"
        lines.append(f"  {e.name} link: UDP {host}:{port} -> {remote}")
    if args.lockstep:
        lines.append(f"  lockstep, period {args.lockstep_period:g} s (physics {args.physics_dt:g} s)")
    else:
        lines.append(f"  real time x{args.speed:g} (physics {args.physics_dt:g} s)")
    lines.append(f"  wind {args.wind}, sensors {args.noise}" + (f" (seed {args.seed})" if args.wind != "none" or args.noise != "clean" else ""))
    if args.log is not None:
        lines.append(f"  logging to {args.log}")
    if args.signing_key is not None:
        lines.append(f"  signing with {args.signing_key}: unsigned and badly signed frames refused")
    e = link.endpoints[0]
    for direction, impair in (("received", e.impair_in), ("sent", e.impair_out)):
        if impair is not None:
            lines.append(f"  a bad link, what is {direction}: {impair.spec.describe()} (seed {args.seed})")
    if args.allow_sysid is not None:
        lines.append(f"  frames handled from system ids {args.allow_sysid} only")
    if plant.config.ftp_root is not None:
        lines.append(f"  MAVLink FTP serves {plant.config.ftp_root} (read-only)")
    print("\n".join(lines), file=sys.stderr, flush=True)


def _summary(plant: Plant, link: Link, stats: RunStats) -> None:
    c = plant.counters
    api = link.endpoints[0].counters
    bad = sum(e.counters.bad_packets for e in link.endpoints)
    wall = stats.wall_s
    periods = stats.periods
    rate = f", {periods / wall:.0f} periods/s" if wall > 0 else ""
    overruns = stats.overruns
    if overruns:
        rate += f", fell behind real time {overruns} times"
    print(
        f"sitl-plant: stopped at t={plant.time_s:.2f} s after {wall:.1f} s{rate}; "
        f"api in {api.packets_in} out {api.packets_out}; bad packets {bad}, refused setpoints {c.refused_setpoints}, "
        f"foreign {c.foreign}, unhandled {c.unhandled}",
        file=sys.stderr,
    )
    for e in link.endpoints[1:]:  # the ground-station link's traffic (the API link's is above)
        g = e.counters
        print(f"sitl-plant: {e.name} link in {g.packets_in} out {g.packets_out}; bad packets {g.bad_packets}", file=sys.stderr)
    for e in link.endpoints:
        for direction, impair in (("in", e.impair_in), ("out", e.impair_out)):
            if impair is not None:
                print(f"sitl-plant: {e.name} link {direction}: {impair.counts.describe()}", file=sys.stderr)
    refused: dict[str, int] = {}
    senders: dict[int, int] = {}
    for e in link.endpoints:
        for why, n in e.counters.refused.items():
            refused[why] = refused.get(why, 0) + n
        for who, n in e.counters.refused_senders.items():
            senders[who] = senders.get(who, 0) + n
    if refused:
        whys = ", ".join(f"{why} {n}" for why, n in sorted(refused.items()))
        whos = ", ".join(f"system {who}: {n}" for who, n in sorted(senders.items()))
        print(f"sitl-plant: refused {sum(refused.values())} frames before handling ({whys}; {whos})", file=sys.stderr)
    if c.ignored:
        kinds = ", ".join(f"{kind} {n}" for kind, n in sorted(c.ignored.items()))
        print(f"sitl-plant: ignored {sum(c.ignored.values())} messages as PX4 v1.16 does ({kinds}: the plant does not sign)", file=sys.stderr)
    if c.breakdowns:
        print(f"sitl-plant: the simulation broke down {c.breakdowns} times (state not finite)", file=sys.stderr)
    if c.internal_errors:
        print(f"sitl-plant: {c.internal_errors} messages raised an error (last: {c.last_error}); please report it", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
