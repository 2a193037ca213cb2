"""`offboard sweep SPEC`: many flights of a scenario with parameters drawn per flight (docs/sweeps.md)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from offboard import jsonout
from offboard.errors import UserError
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_folder


class MissingDependency(UserError, ImportError):
    """What a sweep needs is not installed."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard sweep`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "sweep",
        help="fly a sweep file: thousands of flights with drawn parameters, on Dask; Parquet rows and a report",
        description="Fly every flight of a sweep file (a scenario plus distributions or grids over the vehicle, "
        "the controller's beliefs and gains, wind, sensors, start and latency) on a Dask cluster, one Parquet row "
        "a flight, then a report: success rate, percentiles, a sensitivity ranking and plots.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("spec", type=Path, nargs="?", help="sweep file, e.g. missions/sweep-table2.toml")
    parser.add_argument("--run-dir", type=Path, default=None, help="folder for flights.parquet, the report and plots "
                        "(default: runs/sweep-<name>-<time>)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="a running Dask scheduler to fly on (default: a local cluster of this machine's cores)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster (default: the cores)")
    parser.add_argument("--engine", choices=("batch", "one"), default="batch",  # runner.SweepEngine, imported only to fly
                        help="batch: N flights stepped together; one: offboard simulate's loop per flight (the reference)")
    parser.add_argument("--flights-per-task", type=int, default=None, metavar="N",
                        help="flights a Dask task flies (default: about 0.8 s of work, timed on a few flights)")
    parser.add_argument("--limit", type=int, default=None, metavar="N", help="fly only the first N flights")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.add_argument("--list-parameters", action="store_true", help="list what a sweep file may vary, and exit")
    parser.set_defaults(func=run)


def check_cluster(workers: int | None, scheduler: str | None) -> None:
    """The cluster options of a command that flies on Dask (``offboard sweep``, ``offboard tune
    --search``); a UserError naming the bad one."""
    if workers is not None and workers < 1:
        raise UserError(f"--workers must be >= 1, got {workers}")
    if scheduler is not None and workers is not None:
        raise UserError("--workers sizes the local cluster; with --scheduler the cluster has its own workers")
    if scheduler is not None and not scheduler.startswith(("tcp://", "tls://", "ucx://", "inproc://")):
        raise UserError(f"--scheduler: expected tcp://HOST:PORT, got {scheduler!r}")


def _progress(name: str, every_s: float):  # noqa: ANN202
    tty = sys.stderr.isatty()
    last = [-1e9]

    def show(done: int, total: int, elapsed: float) -> None:
        if not tty and done < total and elapsed - last[0] < every_s:
            return
        last[0] = elapsed
        rate = done / elapsed if elapsed > 0 else 0.0
        left = (total - done) / rate if rate > 0 else float("nan")
        line = f"sweep {name}: {done}/{total} flights, {rate:.1f} flights/s, {left:.0f} s left"
        sys.stderr.write(("\r" + line + " " * 8) if tty else line + "\n")
        if tty and done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def run(args: argparse.Namespace) -> int:
    """``offboard sweep``: fly the sweep, write its Parquet rows, report and plots."""
    from offboard.sweep.spec import PARAMETERS, load_sweep

    if args.list_parameters:
        width = max(len(n) for n in PARAMETERS)
        for name, par in PARAMETERS.items():
            print(f"{name:<{width}}  {par.help}")
        return 0
    if args.spec is None:
        raise UserError("a sweep file is needed (e.g. missions/sweep-table2.toml), or --list-parameters")
    for option in ("flights_per_task", "limit"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise UserError(f"--{option.replace('_', '-')} must be >= 1, got {value}")
    check_cluster(args.workers, args.scheduler)
    spec = load_sweep(args.spec)
    try:
        import distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as exc:
        raise MissingDependency(f"{exc.name} is not installed: offboard sweep needs Dask and pyarrow "
                                "(pip install 'rosales-offboard[sweep]')") from None  # fmt: skip
    from offboard.sweep.report import format_report, read_rows, summary, write_plots
    from offboard.sweep.runner import SweepEngine, run_sweep

    from sitl_plant.dynamics.batch import NUMBA

    engine = SweepEngine(args.engine)
    if engine is SweepEngine.BATCH and not NUMBA and not args.quiet:
        print("offboard sweep: numba is not installed here: the batched engine runs interpreted (the same flights, "
              "tens of times slower; pip install 'rosales-offboard[sweep]')", file=sys.stderr)  # fmt: skip
    run_dir = output_folder(args.run_dir or Path("runs") / f"sweep-{spec.name}-{time.strftime('%Y%m%d-%H%M%S')}", "--run-dir")
    progress = None if args.quiet else _progress(spec.name, 2.0)
    try:
        result = run_sweep(spec, run_dir, scheduler=args.scheduler, workers=args.workers, engine=engine,
                           flights_per_task=args.flights_per_task, limit=args.limit, progress=progress)  # fmt: skip
    except OSError as exc:  # the scheduler cannot be reached
        raise UserError(f"--scheduler {args.scheduler}: {exc}") from None
    rows = read_rows(result.parquet)
    report = summary(spec, rows)
    payload = {
        **report,
        "engine": args.engine,
        "scheduler": result.scheduler,
        "workers": result.workers,
        "tasks": result.tasks,
        "flights_per_task": result.flights_per_task,
        "wall_time_s": result.wall_s,
        "compute_s": result.compute_s,
        "overhead_per_flight_s": result.overhead_per_flight_s,
        "flights_per_s": result.flights / result.wall_s if result.wall_s > 0 else None,
        "parquet": str(result.parquet),
    }
    text = format_report(report)
    (run_dir / "report.md").write_text(text + "\n")
    (run_dir / "summary.json").write_text(jsonout.dumps(payload, indent=2) + "\n")
    figures = [] if args.no_plots else write_plots(spec, rows, report, run_dir)
    if args.json:
        print(jsonout.dumps(payload))
    else:
        print(text)
        print(f"\n{result.flights} flights in {result.wall_s:.1f} s ({payload['flights_per_s']:.1f} flights/s) on "
              f"{result.workers} workers ({result.scheduler}), {result.tasks} tasks of {result.flights_per_task}")
        print(f"run folder: {run_dir}" + (f" ({len(figures)} figures)" if figures else ""))
    return 0
