"""`offboard tune`: design the law's gains for a vehicle and its inner loop; write a controller file.

The vehicle's parameters come from a parameter file (a JSON object of name -> value, PX4
SITL's ``params.json`` layout, or a QGroundControl ``.params`` file), from a sitl-plant vehicle
file, or live from a vehicle over MAVLink (``--connect``). The design is
``offboard.controller.design`` (docs/controller-design.md); the file it writes flies with
``offboard fly --controller FILE`` (``offboard fly`` without ``--controller`` designs the same
gains at start-up).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from offboard import jsonout
from offboard.codec import Scaling
from offboard.commands.sweep import check_cluster
from offboard.controller import PAPER_CONTROLLER_FILE, load_controller
from offboard.controller.design import Design, MarginSpec, nearby_designs
from offboard.controller.params import ControllerParams
from offboard.controller.tuning import (
    AUTOPILOT_PARAMS,
    PLANT_PARAMS,
    SIH_PARAMS,
    controller_file_text,
    design_for_vehicle,
    design_summary,
    paper_gains_summary,
    se3_gains_summary,
    tuned_params,
    vehicle_values,
)
from offboard.errors import LinkTimeout, UserError
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_file, output_folder
from offboard.model.vehicle import VehicleModel, load_vehicle

if TYPE_CHECKING:  # the search's module loads only with --search (Dask, pyarrow)
    from offboard.sweep.tune import Trial


class TuneArgumentError(UserError, ValueError):
    """A tune option or input file is unusable; the message names it."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard tune`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "tune",
        help="design the law's gains for a vehicle's inner loop and write a controller file",
        description="Model the vehicle's attitude loop, rate loop, motors, sample-and-hold and latency, and "
        "choose the law's gains kx1..kx6 for the fastest closed loop that keeps the stated margins "
        "(docs/controller-design.md). Writes a controller file for offboard fly --controller.",
        formatter_class=HelpFormatter,
    )
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--params", type=Path, metavar="FILE",
                     help="the vehicle's parameters: JSON (name -> value, or PX4 params.json) or a QGC .params file")
    src.add_argument("--vehicle", type=Path, metavar="FILE", help="a sitl-plant vehicle file (its SIM_* and MC_* parameters)")
    src.add_argument("--connect", metavar="URL", help="read the parameters from a live vehicle (pymavlink connection string)")
    parser.add_argument("--sample-time", type=float, default=0.05, metavar="S", help="To of the law")
    parser.add_argument("--latency", type=float, default=0.0, metavar="S",
                        help="from the measurement to the setpoint acting (telemetry age, link)")
    parser.add_argument("--gain-margin", type=float, default=MarginSpec.gain_margin, help="at least this factor")
    parser.add_argument("--phase-margin-deg", type=float, default=MarginSpec.phase_margin_deg, help="at least this")
    parser.add_argument("--delay-margin", type=float, default=MarginSpec.delay_margin_s, metavar="S",
                        help="extra latency the loop must tolerate")
    parser.add_argument("--sensitivity-peak", type=float, default=MarginSpec.sensitivity_peak, metavar="MS",
                        help="at most this max |1/(1+L)| (> 1; 'inf' for no bound)")
    parser.add_argument("--no-integral", action="store_true",
                        help="design without the law's velocity integral (docs/controller-design.md)")
    parser.add_argument("--setpoint-output", choices=("attitude", "rates"), default="attitude",
                        help="what offboard fly --output will send: an attitude, which the autopilot's attitude loop "
                        "closes, or body rates, which only its rate loop flies (the law's angle gains kx7..kx10 "
                        "designed too; docs/controller-design.md)")
    search = parser.add_argument_group("search on the sweep engine (needs --vehicle and Dask: pip install -e '.[sweep]')")
    search.add_argument("--search", type=Path, default=None, metavar="SWEEP.toml",
                        help="fly the designs near the analytic one (each keeping the margins) on this sweep's flights "
                        "through PX4's attitude loop, and write the one with the lowest median error")
    search.add_argument("--search-flights", type=int, default=16, metavar="N", help="flights of the sweep flown per design")
    search.add_argument("--search-designs", type=int, default=12, metavar="N", help="designs flown, the analytic one first")
    search.add_argument("--run-dir", type=Path, default=None,
                        help="folder for each design's flights.parquet and search.json (default: runs/tune-<time>)")
    search.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="a running Dask scheduler to fly on (default: a local cluster of this machine's cores)")
    search.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster (default: the cores)")
    parser.add_argument("--output", type=Path, default=None, metavar="FILE", help="controller file to write (default: stdout)")
    parser.add_argument("--plot", type=Path, default=None, metavar="FILE.png",
                        help="the loop's frequency response and poles, designed against Table I's gains")
    parser.set_defaults(func=run)


def read_params_file(path: Path) -> dict[str, float]:
    """Parameters from JSON (name -> number or {"value": number}) or a QGC .params file."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise TuneArgumentError(f"--params {path}: {exc.strerror or exc}") from None
    out: dict[str, float] = {}
    if text.lstrip()[:1] in ("{", "["):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise TuneArgumentError(f"--params {path}: not JSON: {exc.msg} at line {exc.lineno}") from None
        if not isinstance(data, dict):
            raise TuneArgumentError(f"--params {path}: expected an object of name -> value")
        for name, value in data.items():
            if isinstance(value, dict):
                value = value.get("value")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise TuneArgumentError(f"--params {path}: {name}: expected a finite number, got {value!r}")
            out[str(name)] = float(value)
        return out
    for lineno, line in enumerate(text.splitlines(), 1):  # QGC: vehicle, component, name, value, type
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split("\t") if "\t" in line else line.split()
        if len(fields) < 4:
            raise TuneArgumentError(f"--params {path}:{lineno}: expected 'vehicle component name value type'")
        try:
            value = float(fields[3])
        except ValueError:
            raise TuneArgumentError(f"--params {path}:{lineno}: {fields[2]}: not a number: {fields[3]!r}") from None
        if not math.isfinite(value):
            raise TuneArgumentError(f"--params {path}:{lineno}: {fields[2]}: not finite")
        out[fields[2]] = value
    return out


def read_vehicle_file(path: Path) -> dict[str, float]:
    """The parameters a sitl-plant flying this vehicle file publishes."""
    from sitl_plant.params import plant_params  # the simulator's vehicle file: only for this option

    table = plant_params(load_vehicle(path))
    return {name: table[name] for name in table}


def read_live_params(url: str, timeout_s: float = 10.0) -> dict[str, float]:
    """The parameters the design needs, read with PARAM_REQUEST_READ from a live vehicle."""
    from pymavlink import mavutil

    try:
        conn = mavutil.mavlink_connection(url, source_system=245, source_component=191)
    except OSError as exc:
        raise TuneArgumentError(f"--connect {url}: {exc.strerror or exc}") from None
    try:
        hb = conn.wait_heartbeat(timeout=timeout_s)
        if hb is None:
            raise LinkTimeout(f"no vehicle heartbeat on {url} within {timeout_s:g} s")
        out: dict[str, float] = {}
        for name in (*PLANT_PARAMS, *SIH_PARAMS, *AUTOPILOT_PARAMS):
            # one simulator's family only: sitl-plant's SIM_* or PX4 SIH's SIH_* (the other is absent)
            if (name in SIH_PARAMS and "SIM_THR_MAX" in out) or (name in PLANT_PARAMS and "SIH_MASS" in out):
                continue
            for _ in range(2):
                conn.mav.param_request_read_send(conn.target_system, conn.target_component, name.encode(), -1)
                msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
                while msg is not None and msg.param_id != name:
                    msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
                if msg is not None:
                    value = msg.param_value
                    if msg.param_type in (1, 2, 3, 4, 5, 6):  # integers travel bytewise in the float (PX4)
                        value = struct.unpack("<i", struct.pack("<f", value))[0]
                    out[name] = float(value)
                    break
        return out
    finally:
        conn.close()


def _check(args: argparse.Namespace) -> None:
    for name in ("sample_time", "gain_margin"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise TuneArgumentError(f"--{name.replace('_', '-')} must be > 0, got {value}")
    for name in ("latency", "phase_margin_deg", "delay_margin"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value >= 0):
            raise TuneArgumentError(f"--{name.replace('_', '-')} must be >= 0, got {value}")
    if not (args.sensitivity_peak > 1.0):  # inf allowed: no bound; NaN refused
        raise TuneArgumentError(f"--sensitivity-peak must be > 1, got {args.sensitivity_peak}")
    if args.search is not None:
        if args.setpoint_output == "rates":
            raise TuneArgumentError("--search flies PX4's attitude loop in process: it searches --setpoint-output attitude only")
        if args.vehicle is None:
            raise TuneArgumentError("--search flies the vehicle in process: give it as --vehicle FILE")
        for option in ("search_flights", "search_designs"):
            value = getattr(args, option)
            if value < 1:
                raise TuneArgumentError(f"--{option.replace('_', '-')} must be at least 1, got {value}")
        check_cluster(args.workers, args.scheduler)
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise TuneArgumentError(f"--plot {args.plot}: expected a .png file")
    for option, path in (("--output", args.output), ("--plot", args.plot)):
        if path is not None:
            output_file(path, option)


def run(args: argparse.Namespace) -> int:
    """``offboard tune``: design (or search) the gains for the vehicle and write the controller file."""
    from offboard.flight import ControllerChoice, resolve_controller

    _check(args)
    if args.params is not None:
        raw, source = read_params_file(args.params), f"parameter file {args.params}"
    elif args.vehicle is not None:
        raw, source = read_vehicle_file(args.vehicle), f"sitl-plant vehicle file {args.vehicle}"
    else:
        raw, source = read_live_params(args.connect), f"the vehicle on {args.connect}"
    values = vehicle_values(raw)
    if "SIM_THR_MAX" not in values:
        raise TuneArgumentError(f"{source}: no SIM_THR_MAX or SIH_T_MAX (the vehicle's thrust at normalised 1)")
    spec = MarginSpec(args.gain_margin, args.phase_margin_deg, args.delay_margin, args.sensitivity_peak)
    try:
        design = design_for_vehicle(values, sample_time_s=args.sample_time, latency_s=args.latency, spec=spec,
                                    velocity_integral=not args.no_integral, body_rates=args.setpoint_output == "rates")
    except KeyError as exc:
        raise TuneArgumentError(f"{source}: {exc.args[0]}") from None
    except ValueError as exc:
        raise TuneArgumentError(str(exc)) from None
    choice = ControllerChoice(base=load_controller(PAPER_CONTROLLER_FILE), sample_time_s=args.sample_time)
    params, _ = resolve_controller(choice, VehicleModel.RIGID_BODY, values, Scaling(values["SIM_THR_MAX"]))
    base = params
    params = tuned_params(base, design, values)
    text = controller_file_text(params, design, source=source)
    if args.search is not None:
        design, params, text = _search(args, design, lambda d: tuned_params(base, d, values), source)
    if args.output is not None:
        try:
            args.output.write_text(text)
        except OSError as exc:
            raise TuneArgumentError(f"--output {args.output}: {exc.strerror or exc}") from None
    for line in (*design_summary(design), paper_gains_summary(design), se3_gains_summary(design)):
        print(line, file=sys.stderr)
    if args.output is None:
        sys.stdout.write(text)
    else:
        print(f"controller file {args.output}", file=sys.stderr)
    if args.plot is not None:
        from offboard.plots import design_figure

        try:
            design_figure(design, args.plot)
        except OSError as exc:
            raise TuneArgumentError(f"--plot {args.plot}: {exc.strerror or exc}") from None
        print(f"figure {args.plot}", file=sys.stderr)
    return 0


def _search(args: argparse.Namespace, design: Design, params_of: Callable[[Design], ControllerParams],
            source: str) -> tuple[Design, ControllerParams, str]:  # fmt: skip
    """``--search``: the designs near ``design`` flown on the sweep (``offboard.sweep.tune``); the
    best one's design, controller parameters and controller file (with the search as comments)."""
    try:
        import distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as exc:
        raise TuneArgumentError(f"--search needs Dask and pyarrow (pip install -e '.[sweep]'): {exc}") from None
    from offboard.sweep import tune as sweep_tune
    from offboard.sweep.spec import load_sweep

    spec = load_sweep(args.search)  # a ParameterFileError names the field
    try:
        sweep_tune.check_sweep(spec)
    except ValueError as exc:
        raise TuneArgumentError(f"--search {exc}") from None
    run_dir = output_folder(args.run_dir or Path("runs") / f"tune-{time.strftime('%Y%m%d-%H%M%S')}", "--run-dir")
    designs = nearby_designs(design, args.search_designs)
    flights = min(args.search_flights, spec.flights)
    print(f"search: {len(designs)} designs keeping the margins, {flights} flights of {args.search} each "
          f"(through PX4's attitude loop), into {run_dir}", file=sys.stderr)  # fmt: skip
    try:
        trials = sweep_tune.search(designs, params_of, spec, load_vehicle(args.vehicle), run_dir, flights=flights,
                                   latency_s=args.latency, scheduler=args.scheduler, workers=args.workers,
                                   say=lambda text: print(f"search: {text}", file=sys.stderr))  # fmt: skip
    except OSError as exc:  # the scheduler cannot be reached, or the run folder written
        where = f"--scheduler {args.scheduler}" if args.scheduler is not None else f"--run-dir {run_dir}"
        raise TuneArgumentError(f"{where}: {exc}") from None
    chosen = sweep_tune.best(trials)
    table = _search_table(trials, chosen, sweep_tune.error_column(spec))
    (run_dir / "search.json").write_text(jsonout.dumps({
        "sweep": str(args.search), "flights_per_design": flights, "error": sweep_tune.error_column(spec),
        "chosen": None if chosen is None else trials.index(chosen),
        "designs": [{"k_pos": float(t.design.horizontal.k_pos), "k_vel": float(t.design.horizontal.k_vel),
                     "tilt_lead": float(t.design.horizontal.lead),
                     "velocity_integral_per_s2": float(t.design.horizontal.velocity_integral_per_s2),
                     "flights": t.flights, "complete": t.complete, "median_rms_m": t.median_rms_m,
                     "p90_rms_m": t.p90_rms_m, "run_dir": str(t.run_dir)} for t in trials],
    }, indent=2) + "\n")  # fmt: skip
    for line in table:
        print(line, file=sys.stderr)
    if chosen is None:
        raise TuneArgumentError(f"--search: no design completed every one of the {flights} flights of {args.search} "
                                f"(see {run_dir})")  # fmt: skip
    text = controller_file_text(chosen.params, chosen.design, source=source)
    comment = [f"# Searched (offboard tune --search {args.search}): {len(trials)} designs keeping these margins, "
               f"{flights} flights each through PX4's attitude loop; the lowest median error kept:",
               *(f"#   {line}" for line in table)]  # fmt: skip
    head, _, rest = text.partition("\n[law]\n")
    return chosen.design, chosen.params, head.rstrip("\n") + "\n" + "\n".join(comment) + "\n\n[law]\n" + rest


def _search_table(trials: list[Trial], chosen: Trial | None, column: str) -> list[str]:
    lines = [f"design  k_pos   k_vel   lead  vel. integral  complete  median {column}  p90"]
    for k, t in enumerate(trials):
        h = t.design.horizontal
        mark = "  <- kept" if t is chosen else ("  (analytic)" if k == 0 else "")
        lines.append(f"{k:6d}  {float(h.k_pos):.4f}  {float(h.k_vel):.4f}  {float(h.lead):4.2f}  "
                     f"{float(h.velocity_integral_per_s2):8.4f}/s^2  {t.complete:3d}/{t.flights:<3d}  "
                     f"{t.median_rms_m:10.4f} m  {t.p90_rms_m:.4f} m{mark}")  # fmt: skip
    return lines
