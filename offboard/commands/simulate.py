"""`offboard simulate SCENARIO`: fly a scenario in-process and report it like the paper does."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from offboard import jsonout
from offboard.model.vehicle import VEHICLE_MODELS
from offboard.inprocess import SCENARIO_DRIVES, run_scenario
from offboard.metrics import check_tracking, format_table, summarize
from offboard.record import FlightStatus
from offboard.errors import ParameterFileError
from offboard.scenario import load_scenario
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_folder


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard simulate`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "simulate",
        help="fly a scenario file in-process (controller + simulated vehicle) and report it",
        description="Fly a scenario (mission + vehicle + controller + sensors) in one process, print the "
        "tracking table and write the paper's figures, a CSV and the summary into a run folder.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("scenario", type=Path, help="scenario file, e.g. missions/paper-sim1.toml")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="folder for figures, CSV and summary (default: runs/<scenario>-<time>)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object instead of a table")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument("--drive", choices=SCENARIO_DRIVES, default=None, help="override the scenario's way of driving the model")
    parser.add_argument("--model", choices=sorted(VEHICLE_MODELS), default=None, help="override the scenario's vehicle model")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``offboard simulate``: fly the scenario in-process and report it; the flight status's exit code."""
    scenario = load_scenario(args.scenario)
    overrides = {k: v for k, v in (("drive", args.drive), ("model", args.model)) if v is not None}
    if overrides:
        from dataclasses import replace

        try:
            scenario = replace(scenario, **overrides)
        except ValueError as exc:  # a cross-field check (Scenario.__post_init__) the override fails
            raise ParameterFileError(f"{args.scenario}: with {' '.join(f'--{k} {v}' for k, v in overrides.items())}: {exc}") from None
    show_progress = not args.quiet and not args.json and sys.stderr.isatty()

    def progress(fraction: float) -> None:
        sys.stderr.write(f"\r{scenario.name}: {100 * fraction:5.1f} %")

    run_dir = output_folder(args.run_dir or Path("runs") / f"{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}", "--run-dir")
    started = time.perf_counter()
    record = run_scenario(scenario, progress if show_progress else None)
    wall = time.perf_counter() - started
    if show_progress:
        sys.stderr.write("\r" + " " * 40 + "\r")
    summary = summarize(check_tracking(record))

    record.write_csv(run_dir / "series.csv")
    table = format_table(summary)
    (run_dir / "summary.txt").write_text(table + "\n")
    payload = {"scenario": scenario.name, "source": scenario.source, "model": scenario.model,
               "drive": scenario.drive, "wall_time_s": wall, **summary.to_dict()}
    (run_dir / "summary.json").write_text(jsonout.dumps(payload, indent=2) + "\n")
    figures: list[Path] = []
    if not args.no_plots and len(record):
        from offboard.plots import write_figures

        figures = write_figures(record, run_dir, title=f"{scenario.name} ({scenario.model}, {scenario.drive})")

    if args.json:
        print(jsonout.dumps(payload))
    else:
        print(f"{scenario.name}: model {scenario.model}, drive {scenario.drive}, sensors {scenario.sensors}, "
              f"wind {scenario.wind}  ({wall:.2f} s wall)")
        print(table)
        print(f"run folder: {run_dir}" + (f" ({len(figures)} figures)" if figures else ""))
    if record.status is not FlightStatus.COMPLETE:
        print(f"offboard simulate: {record.status.name}: {record.status_detail}", file=sys.stderr)
    return record.status.exit_code
