"""`offboard replay LOG.tlog`: report, re-run or re-stream a flight from its MAVLink log.

- **Report** (default): the paper's figures, the aligned series (CSV), the tracking table per
  phase and the log's own figures (message rates and gaps, packet loss per source, mode
  changes, failsafes) in a run folder. Any tlog with ATTITUDE and LOCAL_POSITION_NED works.
- **Re-run** (``--rerun``): the controller fed the recorded telemetry sample by sample; its
  outputs against the logged setpoints (equal to float32 with the flight's controller; a
  figure and a table beside them with ``--controller FILE``).
- **Stream** (``--to udpout:HOST:PORT``): the vehicle's messages re-sent in their original
  timing (``--speed N``: N times faster), for a ground station to watch again.

Exit code: 0; 1 when ``--rerun`` with the flight's own controller does not reproduce the log;
2 for a bad argument or a file that is not a tlog (one line). See docs/replay.md.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import deque
import time
from pathlib import Path

import numpy as np

from offboard import jsonout
from offboard.model.vehicle import VEHICLE_MODELS, VehicleModel
from offboard.errors import UserError
from offboard.model.paths import output_folder

#: pymavlink connection strings ``--to`` accepts (network outputs only).
STREAM_SCHEMES = ("udpout:", "udpbcast:", "udpin:", "tcp:", "tcpin:")


class ReplayArgumentError(UserError, ValueError):
    """An option's value is well-formed for argparse but unusable (``--speed 0``, a bad URL)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard replay`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "replay",
        help="report, re-run or re-stream a flight from its MAVLink log (.tlog)",
        description="Read a MAVLink telemetry log (ours or any system's with ATTITUDE and LOCAL_POSITION_NED) and "
        "write the paper's figures, the aligned series, the tracking table and the log's message statistics, "
        "mode changes and failsafes into a run folder; or re-run the controller on it; or stream it again. "
        "See docs/replay.md.",
    )
    parser.add_argument("log", type=Path, help="the flight's .tlog (offboard fly's RUN_DIR/flight.tlog, sitl-plant --log, a GCS's)")
    parser.add_argument("--mission", type=Path, default=None, metavar="FILE",
                        help="mission flown: references and phases (default: the one named in summary.json beside the log)")
    parser.add_argument("--run-dir", type=Path, default=None, metavar="DIR",
                        help="folder for figures, CSV and summary (default: runs/replay-<log>-<time>)")
    parser.add_argument("--sysid", type=int, default=None, metavar="N",
                        help="the vehicle's system id (default: the autopilot reporting ATTITUDE and LOCAL_POSITION_NED)")
    rerun = parser.add_argument_group("re-run")
    rerun.add_argument("--rerun", action="store_true", help="feed the telemetry to the controller and compare with the logged setpoints")
    rerun.add_argument("--controller", type=Path, default=None, metavar="FILE",
                       help="re-run this controller instead of the flight's (as offboard fly --controller FILE flies it)")
    rerun.add_argument("--model", choices=("rigid-body", "paper"), default=None,
                       help="what the vehicle was (offboard fly --model; default: summary.json's, else rigid-body)")
    rerun.add_argument("--thrust-max-n", type=float, default=None, metavar="N",
                       help="thrust at normalised 1 when the log holds neither SIM_THR_MAX nor SIH_T_MAX (a real airframe)")
    stream = parser.add_argument_group("stream")
    stream.add_argument("--to", default=None, metavar="URL",
                        help="re-send the vehicle's messages to this pymavlink address (e.g. udpout:127.0.0.1:14550) and exit")
    stream.add_argument("--speed", type=float, default=1.0, metavar="N", help="stream N times faster than flown (default: 1)")
    stream.add_argument("--all-systems", action="store_true", help="stream every system's messages, not only the vehicle's")
    out = parser.add_argument_group("output")
    out.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    out.add_argument("--json", action="store_true", help="print the summary as one JSON object instead of tables")
    out.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


class _Progress:
    """A progress bar on stderr, only on a terminal and not with --quiet/--json."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label = label
        self.enabled = enabled and sys.stderr.isatty()
        self._shown = -1

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        percent = int(100 * fraction)
        if percent == self._shown:
            return
        self._shown = percent
        bar = "#" * (percent // 4) + "." * (25 - percent // 4)
        sys.stderr.write(f"\r{self.label} [{bar}] {percent:3d} %")
        sys.stderr.flush()

    def end(self) -> None:
        if self.enabled and self._shown >= 0:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()


def _check(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.speed) and args.speed > 0):
        raise ReplayArgumentError(f"--speed: must be > 0, got {args.speed}")
    if args.to is not None and not args.to.startswith(STREAM_SCHEMES):
        raise ReplayArgumentError(f"--to: expected a pymavlink network address ({', '.join(s + 'HOST:PORT' for s in STREAM_SCHEMES[:1])}, "
                                  f"{', '.join(STREAM_SCHEMES[1:])}), got {args.to!r}")
    if args.sysid is not None and not 1 <= args.sysid <= 255:
        raise ReplayArgumentError(f"--sysid: must be 1..255, got {args.sysid}")
    if args.thrust_max_n is not None and not (math.isfinite(args.thrust_max_n) and args.thrust_max_n > 0):
        raise ReplayArgumentError(f"--thrust-max-n: must be > 0, got {args.thrust_max_n}")
    if args.controller is not None and not args.rerun:
        raise ReplayArgumentError("--controller: only with --rerun")


def _warn(text: str) -> None:
    print(f"offboard replay: warning: {text}", file=sys.stderr)


def _flight_summary(log: Path, vehicle: int | None) -> tuple[dict | None, str]:
    """``offboard fly``'s summary.json beside the log, if it describes this flight, and a note
    when it names another log (None, '' otherwise).

    It describes this flight when it names this log, or when it names another log of the same
    vehicle in the same folder (the demo's ``plant.tlog`` beside ``flight.tlog``: the vehicle's
    side of the same run), or a log no longer there (this one, renamed).
    """
    path = log.parent / "summary.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None, ""
    if not isinstance(data, dict) or "log" not in data:
        return None, ""
    named = Path(str(data["log"])).name
    if named == log.name:
        return data, ""
    flown_by = (data.get("vehicle") or {}).get("system") if isinstance(data.get("vehicle"), dict) else None
    if vehicle is None or flown_by != vehicle:
        return None, f"summary.json beside it describes {named}, a flight of another vehicle"
    if (log.parent / named).is_file():
        return data, f"summary.json of {named}, the same run's log of vehicle {vehicle}"
    return data, f"summary.json of {named} (not there: this log, renamed?)"


def _heading_hold_as_flown(summary: dict | None):  # -> TakeoffHeadingHold | None
    """The flight's take-off heading hold, from summary.json's ``takeoff_heading_hold`` (None: it
    held nothing, or the summary is older than the hold)."""
    from offboard.flight.heading_hold import TakeoffHeadingHold

    hold = (summary or {}).get("takeoff_heading_hold")
    if not isinstance(hold, dict) or hold.get("held") is not True:
        return None
    heading, released = hold.get("heading_deg"), hold.get("released_s")
    released_ok = released is None or (isinstance(released, (int, float)) and not isinstance(released, bool) and math.isfinite(released))
    if not isinstance(heading, (int, float)) or isinstance(heading, bool) or not math.isfinite(heading) or not released_ok:
        raise ReplayArgumentError(f"--rerun: summary.json: takeoff_heading_hold held, but its heading_deg {heading!r} or "
                                  f"released_s {released!r} is not a finite number (released_s may be null)")
    return TakeoffHeadingHold.as_flown(math.radians(float(heading)), None if released is None else float(released))


def _observed_as_flown(summary: dict | None) -> bool:
    """Whether the flight's prediction observed the rate loop (summary.json's ``observed_rate_loop``;
    absent in flights before the observer, which took it at hover)."""
    observed = (summary or {}).get("observed_rate_loop")
    if observed is not None and not isinstance(observed, bool):
        raise ReplayArgumentError(f"--rerun: summary.json: observed_rate_loop {observed!r} is not true, false or null")
    return bool(observed)


def _observer_memory_as_flown(summary: dict | None) -> float:
    """The observer's memory the flight flew (summary.json's ``observer_memory_s``; absent in the
    flights that observed before it, whose observer was deadbeat: 0)."""
    memory = (summary or {}).get("observer_memory_s")
    if memory is None:
        return 0.0
    if isinstance(memory, bool) or not isinstance(memory, (int, float)) or not (math.isfinite(memory) and memory >= 0):
        raise ReplayArgumentError(f"--rerun: summary.json: observer_memory_s {memory!r} is not a time (s, >= 0)")
    return float(memory)


def _predicted_latency_as_flown(log: Path, summary: dict | None, record) -> tuple[float | None, np.ndarray | None, str]:
    """The latency the flight predicted its state over (summary.json's ``predicted_latency_s``),
    the telemetry ages it handed the prediction at each of ``record``'s samples (series.csv's
    ``telemetry_age_s`` beside the log, by ``time_boot_ms``), and a note for the re-run's label."""
    latency = (summary or {}).get("predicted_latency_s")
    if latency is None:
        return None, None, ""
    if not isinstance(latency, (int, float)) or isinstance(latency, bool) or not (math.isfinite(latency) and latency >= 0):
        raise ReplayArgumentError(f"--rerun: summary.json: predicted_latency_s {latency!r} is not a latency (s, >= 0)")
    observed = ""
    if _observed_as_flown(summary):
        memory = _observer_memory_as_flown(summary)
        observed = f", the rate loop observed ({f'{memory:g} s of memory' if memory > 0 else 'deadbeat'})"
    note = f"; state predicted over {latency * 1000:.0f} ms{observed}"
    series = log.parent / "series.csv"
    try:
        with series.open() as fh:
            header = fh.readline().strip().split(",")
            wanted = "telemetry_age_s" in header and "time_boot_ms" in header
            data = np.loadtxt(fh, delimiter=",", ndmin=2) if wanted else None
    except (OSError, ValueError):
        data = None
    if data is None or not len(data):
        return float(latency), None, note + " (no readable series.csv with the telemetry's ages beside the log: predicted over the latency alone)"
    # by stamp, in order: two samples that read the same telemetry share its stamp, each with its own age
    ages_by_stamp: dict[int, deque[float]] = {}
    for stamp, age in zip(data[:, header.index("time_boot_ms")].astype(np.int64).tolist(), data[:, header.index("telemetry_age_s")].tolist()):
        ages_by_stamp.setdefault(stamp, deque()).append(age)
    stamps = np.asarray(record.meta["time_boot_ms"], dtype=np.int64).tolist()
    ages = np.array([queue.popleft() if (queue := ages_by_stamp.get(stamp)) else math.nan for stamp in stamps], dtype=float)
    return float(latency), ages, note + " and the telemetry's ages from series.csv"


def _mission(args: argparse.Namespace, summary: dict | None):
    """The mission (``offboard.missions.Mission``) and a note saying where it came from (None, ''
    without one)."""
    from offboard.missions import MISSIONS_DIR, load_mission

    if args.mission is not None:
        return load_mission(args.mission), str(args.mission)
    recorded = (summary or {}).get("mission_file")  # its full path (summaries before it: only the name)
    if isinstance(recorded, str) and recorded:
        if Path(recorded).is_file():
            return load_mission(recorded), f"{recorded} (summary.json's mission_file)"
        _warn(f"summary.json's mission file {recorded} no longer exists; looking for it by name")
    name = (summary or {}).get("mission_source")
    if isinstance(name, str) and name:
        for folder in (args.log.parent, Path.cwd(), MISSIONS_DIR):
            candidate = folder / name
            if candidate.is_file():
                return load_mission(candidate), f"{candidate} (named in summary.json)"
        _warn(f"summary.json names the mission {name!r}, not found beside the log, here or in {MISSIONS_DIR}; pass --mission FILE")
    return None, ""


def _mission_offset(mission, scan, vehicle: int | None, summary: dict | None) -> tuple[tuple[float, float, float] | None, str]:
    """Where a geo-referenced mission was flown: its origin in the vehicle's frame (NED, m), and
    where that came from. ``offboard fly`` moves a mission with a home by this offset
    (``mission_offset_ned_m`` in summary.json); without a summary, the vehicle's HOME_POSITION
    in the log gives it. A mission without a home was flown as written."""
    from offboard.replay import logged_mission_offset

    if mission.home is None:
        return None, ""
    if summary is not None and "mission_offset_ned_m" in summary:
        recorded = summary["mission_offset_ned_m"]
        if recorded is None:
            return None, "flown as written (summary.json: no HOME_POSITION from the vehicle)"
        north, east, down = (float(v) for v in recorded)
        return (north, east, down), "summary.json's mission_offset_ned_m"
    offset = logged_mission_offset(scan, vehicle, mission.home) if vehicle is not None else None
    if offset is None:
        _warn("the mission is geo-referenced but neither summary.json nor the log (HOME_POSITION) says where the "
              "vehicle's home was: references as the file places them about the vehicle's origin")
        return None, ""
    return offset, "the vehicle's HOME_POSITION in the log"


def run(args: argparse.Namespace) -> int:
    """``offboard replay``: report, re-run or re-stream the log; 0, or 1 when a re-run of the flight's own
    controller does not reproduce it.
    """
    from offboard.replay import TlogReader, scan_log

    _check(args)
    quiet = args.quiet or args.json
    if args.to is not None:
        return _stream(args, quiet)

    progress = _Progress(f"reading {args.log.name}", not quiet)
    reader = TlogReader(args.log, progress)
    try:
        scan = scan_log(reader)
    finally:
        progress.end()
    if reader.damages:
        _warn(reader.describe_damage())
    return _report(args, reader, scan)


def _report(args: argparse.Namespace, reader, scan) -> int:
    from offboard import replay
    from offboard.metrics import check_complete, check_tracking, format_table, summarize
    from offboard.trajectory.shifted import shift_trajectory

    vehicle = args.sysid if args.sysid is not None else scan.vehicle_sysid()
    summary_json, summary_note = _flight_summary(args.log, vehicle)
    mission, mission_note = _mission(args, summary_json)
    if mission is not None and summary_note and args.mission is None:
        mission_note += f"; {summary_note}"
    trajectory, offset = None, None
    if mission is not None:
        offset, offset_note = _mission_offset(mission, scan, vehicle, summary_json)
        trajectory = shift_trajectory(mission.trajectory, offset)
        if trajectory is not mission.trajectory and offset is not None:
            mission_note += f"; moved by NED ({offset[0]:.2f}, {offset[1]:.2f}, {offset[2]:.2f}) m, {offset_note}"
    params_log = scan.params.get(vehicle, {}) if vehicle is not None else {}
    thrust_max = replay.logged_scale(params_log, args.thrust_max_n)[0]
    recorded_to = ((summary_json or {}).get("controller") or {}).get("sample_time_s")
    record = replay.build_record(scan, sysid=args.sysid, trajectory=trajectory, thrust_max_n=args.thrust_max_n, source=str(args.log),
                                 sample_time_s=recorded_to)  # fmt: skip
    log_report = replay.log_report(reader, scan, float(record.meta["start_log_time_s"]), float(record.meta["clock_rate"]))  # type: ignore[arg-type]
    if record.meta["references"] == "none":
        why = summary_note or "no summary.json beside it describing this log"
        _warn(f"{args.log.name}: no references, so no tracking errors (no --mission; {why}; no POSITION_TARGET_LOCAL_NED "
              "in the log): pass --mission FILE")
    if mission is not None:
        check_complete(record, mission.trajectory.duration_s)

    exit_code = 0
    rerun_text, rerun_payload, rerun_result = "", None, None
    if args.rerun:
        rerun_result, rerun_text, rerun_payload, reproduces = _rerun(args, scan, record, trajectory, summary_json, thrust_max)
        if reproduces:
            # the flight's own controller, reproduced exactly: its law outputs fill the columns the
            # messages do not carry (u before normalisation, eq. 16 torques, tau_tilde)
            record.columns.update({k: rerun_result.record[k] for k in ("ref_euler_rad", "thrust_n", "torques_nm", "tau_tilde")})
            record.meta["commands_from_rerun"] = True
        elif args.controller is None:
            exit_code = 1

    summary = summarize(check_tracking(record))
    run_dir = args.run_dir or Path("runs") / f"replay-{args.log.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    output_folder(run_dir, "--run-dir")
    record.write_csv(run_dir / "series.csv")
    figures = []
    title = args.log.name
    if not args.no_plots and len(record):
        from offboard.plots import comparison_figure, save_figure, write_figures

        figures = write_figures(record, run_dir, title=title)
        if rerun_result is not None and len(rerun_result.t_s):
            panels = replay.rerun_panels(rerun_result, thrust_max)
            label = "re-run" if args.controller is None else f"re-run {args.controller.name}"
            figures.append(save_figure(comparison_figure(rerun_result.t_s, panels, title, ("logged", label)), run_dir / "rerun.png"))
    if rerun_result is not None:
        rerun_result.record.write_csv(run_dir / "rerun.csv")

    head = (f"{args.log}: vehicle {record.meta['vehicle_sysid']}, {len(record)} samples, commands {record.meta['commands']}, "
            f"references {record.meta['references']}" + (f" ({mission_note})" if mission_note else "")
            + (" (pass --mission FILE for the tracking errors)" if record.meta["references"] == "none" else ""))
    table = format_table(summary) if len(record) else "no samples to tabulate"
    text = "\n\n".join(part for part in (head, table, rerun_text, replay.format_log_report(log_report)) if part)
    (run_dir / "summary.txt").write_text(text + "\n")
    meta = {k: v for k, v in record.meta.items() if k not in ("setpoint_rows", "time_boot_ms")}
    payload = {
        "log": str(args.log),
        "run_dir": str(run_dir),
        "mission": mission_note or None,
        "mission_offset_ned_m": None if offset is None else list(offset),
        **meta,
        "samples": len(record),
        **summary.to_dict(),
        "log_report": log_report.to_dict(),
        "rerun": rerun_payload,
        "figures": [str(p) for p in figures],
    }
    (run_dir / "summary.json").write_text(jsonout.dumps(payload, indent=2, default=str) + "\n")
    if args.json:
        print(jsonout.dumps(payload, default=str))
    else:
        print(text)
        print(f"\nrun folder: {run_dir}" + (f" ({len(figures)} figures)" if figures else ""))
    return exit_code


def _rerun(args: argparse.Namespace, scan, record, trajectory, summary_json: dict | None, thrust_max: float):
    from offboard import codec, replay

    if trajectory is None:
        raise ReplayArgumentError("--rerun needs the mission that was flown: --mission FILE")
    if not math.isfinite(thrust_max):
        raise ReplayArgumentError("--rerun: the log holds no SIM_THR_MAX or SIH_T_MAX (the vehicle's thrust scaling); pass "
                                  "--thrust-max-n N")
    vehicle = int(record.meta["vehicle_sysid"])
    params_log = scan.params.get(vehicle, {})
    try:
        scaling = codec.Scaling(thrust_max, params_log.get("SIM_TQ_RP_MAX"), params_log.get("SIM_TQ_Y_MAX"))
    except ValueError as exc:
        raise ReplayArgumentError(f"--rerun: the vehicle's scaling in the log is unusable: {exc}") from None
    model = args.model or (summary_json or {}).get("model") or "rigid-body"
    model = VehicleModel(model) if model in VEHICLE_MODELS else VehicleModel.RIGID_BODY
    output = str(record.meta.get("commands") or "attitude")
    # offboard fly --output rates travels in SET_ATTITUDE_TARGET too: summary.json says so, else the
    # mission's setpoints do (attitude ignored, type_mask 128, on a rigid body)
    flown_output = (summary_json or {}).get("output")
    if flown_output is None and output == "attitude" and model is VehicleModel.RIGID_BODY:
        masks = replay.setpoints_for(scan, vehicle).values[np.asarray(record.meta["setpoint_rows"], dtype=np.int64), 0]
        if len(masks) and np.all(masks.astype(int) & codec.PAPER_TYPE_MASK):
            flown_output = "rates"
    encoding = codec.SetpointOutput.RATES if flown_output == "rates" and output == "attitude" else None
    try:
        params, origin = replay.flight_controller(params_log, scaling, model=model, output=encoding or output,
                                                  controller_file=args.controller,
                                                  summary=None if args.controller is not None else summary_json)  # fmt: skip
    except ValueError as exc:
        raise ReplayArgumentError(f"--rerun: {exc}") from None
    from offboard.controllers import CONTROLLER_KINDS, ControllerKind

    named = str((summary_json or {}).get("controller_kind") or "paper") if args.controller is None else "paper"
    if named not in CONTROLLER_KINDS:
        raise ReplayArgumentError(f"--rerun: summary.json: controller_kind {named!r} is none of {', '.join(CONTROLLER_KINDS)}")
    kind = ControllerKind(named)
    latency, ages, age_note = None, None, ""
    if args.controller is None:  # the flight's own controller: its latency prediction too
        latency, ages, age_note = _predicted_latency_as_flown(args.log, summary_json, record)
    result = replay.rerun_controller(scan, record, params, trajectory, scaling, model, encoding, kind,
                                     heading_hold=_heading_hold_as_flown(summary_json), predicted_latency_s=latency,
                                     observed_rate_loop=args.controller is None and _observed_as_flown(summary_json),
                                     observer_memory_s=_observer_memory_as_flown(summary_json),
                                     vehicle_params=params_log, telemetry_age_s=ages)  # fmt: skip
    origin += age_note
    label = f"controller: {origin}{'' if kind is ControllerKind.PAPER else f', {kind}'}; model {model}"
    text = replay.format_rerun(result, label)
    payload = {"controller": origin, "model": model, **result.to_dict()}
    return result, text, payload, args.controller is None and result.exact


def _stream(args: argparse.Namespace, quiet: bool) -> int:
    from pymavlink import mavutil

    from offboard.replay import TlogReader, scan_log, stream_log

    systems: set[int] | None = None
    if not args.all_systems:
        if args.sysid is not None:
            systems = {args.sysid}
        else:
            scan = scan_log(TlogReader(args.log))
            vehicle = scan.vehicle_sysid()
            if vehicle is None:
                heard = sorted({s for (s, _c) in scan.seq})
                if not heard:
                    raise ReplayArgumentError(f"{args.log}: no messages to stream")
                vehicle = heard[0]
                _warn(f"no system reports ATTITUDE and LOCAL_POSITION_NED; streaming system {vehicle} (or use --all-systems)")
            systems = {vehicle}
    try:
        conn = mavutil.mavlink_connection(args.to, source_system=255)
    except (OSError, ValueError) as exc:
        raise ReplayArgumentError(f"--to {args.to}: cannot open it: {exc}") from None
    progress = _Progress(f"streaming {args.log.name} to {args.to}", not quiet)
    reader = TlogReader(args.log, progress)
    started = time.monotonic()
    try:
        sent = stream_log(iter(reader), conn.write, speed=args.speed, systems=systems)
    finally:
        progress.end()
        conn.close()
    if reader.damages:
        _warn(reader.describe_damage())
    who = "all systems" if systems is None else f"system {', '.join(str(s) for s in sorted(systems))}"
    if not quiet:
        print(f"sent {sent} messages of {who} to {args.to} in {time.monotonic() - started:.2f} s (speed x{args.speed:g})")
    elif args.json:
        print(json.dumps({"sent": sent, "systems": None if systems is None else sorted(systems), "to": args.to, "speed": args.speed}))
    return 0
