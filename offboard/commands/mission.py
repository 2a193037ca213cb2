"""`offboard mission show|check|convert FILE`: look at, validate, or convert a mission file.

- ``show``: a table of the segments (type, kind, start, duration, length, peak speed and
  acceleration), totals, NED bounds, the reference's jumps between segments and its phases;
  ``--plot PNG`` also draws the path (3D and top view). Without ``--plot`` nothing is written.
- ``check``: validation only; exit 0 and one ``OK`` line when the file is valid, exit 2 with
  the one-line error otherwise (for scripts and CI).
- ``convert``: a waypoint file (QGC WPL 110 or ``.plan``) to the other kind, by the output's
  suffix (``.plan``, anything else is QGC WPL 110).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TextIO

from offboard.errors import MissionFormatError, UserError
from offboard.missions import Mission, load_mission
from offboard.missions.plan import write_plan
from offboard.missions.wpl import write_wpl
from offboard.trajectory.sampling import DEFAULT_DT_S, summarize
from offboard.model.clihelp import HelpFormatter
from offboard.model.paths import output_file


class MissionArgumentError(UserError, ValueError):
    """An argument of ``offboard mission`` is well-formed for argparse but unusable."""


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a step > 0 s, got {text!r}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``offboard mission`` and its options to the top-level parser."""
    parser = subparsers.add_parser(
        "mission",
        help="show, check or convert a mission file (.toml, .plan, QGC WPL 110)",
        description=__doc__.split("\n\n", 1)[1].replace("``", "") if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="mission_command", required=True, metavar="ACTION")

    show = sub.add_parser(
        "show", help="summary table of a mission (and a plot with --plot)", formatter_class=HelpFormatter
    )
    show.add_argument("file", type=Path, help="mission file")
    show.add_argument("--plot", type=Path, metavar="PNG", default=None, help="also write a picture of the path to PNG")
    show.add_argument("--dt", type=_positive_seconds, default=DEFAULT_DT_S, metavar="S", help="sampling step for peaks and lengths (s)")
    show.set_defaults(func=_show)

    check = sub.add_parser("check", help="validate a mission file: exit 0 if valid, 2 with the error otherwise")
    check.add_argument("file", type=Path, help="mission file")
    check.set_defaults(func=_check)

    convert = sub.add_parser("convert", help="convert a waypoint file between QGC WPL 110 and .plan")
    convert.add_argument("file", type=Path, help="input waypoint file (QGC WPL 110 or .plan)")
    convert.add_argument("output", type=Path, help="output file: .plan, or QGC WPL 110 for any other suffix")
    convert.set_defaults(func=_convert)


def _check(args: argparse.Namespace) -> int:
    mission = load_mission(args.file)
    segments = getattr(mission.trajectory, "segments", (mission.trajectory,))
    print(f"{args.file}: OK: {mission.name}, {len(segments)} segments, {mission.trajectory.duration_s:.2f} s")
    return 0


def _plot_format(path: Path) -> None:
    """Refuse, before any work, a picture name whose suffix matplotlib cannot write."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    formats = FigureCanvasAgg.get_supported_filetypes()
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in formats:
        given = f"'.{suffix}'" if suffix else "a name without a suffix"
        raise MissionArgumentError(f"--plot {path}: cannot tell a picture format from {given}; end the name in .png "
                                   f"(or {', '.join('.' + f for f in sorted(formats) if f != 'png')})")


def _show(args: argparse.Namespace) -> int:
    if args.plot is not None:
        _plot_format(args.plot)
        output_file(args.plot, "--plot")
    mission = load_mission(args.file)
    print_summary(mission, sys.stdout, args.dt)
    if args.plot is not None:
        from offboard.missions.plot import plot_path

        out = plot_path(mission.trajectory, args.plot, f"{mission.name} ({mission.source})", mission.start_ned_m, args.dt)
        print(f"plot: {out}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    output_file(args.output, "output")
    mission = load_mission(args.file)
    if mission.items is None:
        raise MissionFormatError(f"{args.file.name}: only waypoint files (QGC WPL 110, .plan) convert; a parametric mission has no MAVLink items")
    if args.output.suffix.lower() == ".plan":
        if mission.items.home_global is None:
            raise MissionFormatError(f"{args.file.name}: a .plan needs a global home position; this mission is in a local frame")
        write_plan(mission.items, args.output)
    else:
        write_wpl(mission.items, args.output)
    print(f"{args.file} -> {args.output}: {len(mission.items.items)} items")
    return 0


def print_summary(mission: Mission, out: TextIO, dt_s: float = DEFAULT_DT_S) -> None:
    """The ``show`` report: header, segment table, totals, bounds, jumps, phases."""
    traj = mission.trajectory
    s = summarize(traj, dt_s)
    w = out.write
    w(f"mission   {mission.name}  ({mission.source})\n")
    if mission.description:
        w(_wrapped("          ", mission.description))
    if mission.home is not None:
        lat, lon, alt = mission.home
        w(f"home      {lat:.7f} deg, {lon:.7f} deg, {alt:.2f} m AMSL (origin of the local NED frame)\n")
    else:
        w("home      none: local frame only\n")
    first = traj.reference(0.0)
    n0, e0, d0 = mission.start_ned_m
    gap = math.dist(mission.start_ned_m, tuple(first.pos_ned_m))
    w(
        f"start     vehicle at N {n0:.2f} E {e0:.2f} D {d0:.2f} m, yaw {math.degrees(mission.start_yaw_rad):.1f} deg; "
        f"reference starts {gap:.2f} m from it\n\n"
    )
    header = ("#", "segment", "type", "kind", "start s", "dur s", "len m", "max v m/s", "max a m/s2", "max yaw deg/s")
    rows = [
        (
            str(k),
            r.name,
            r.type,
            r.kind,
            f"{r.start_s:.2f}",
            f"{r.duration_s:.2f}",
            f"{r.length_m:.2f}",
            f"{r.max_speed_m_s:.2f}",
            f"{r.max_accel_m_s2:.2f}" if not any(v.where == r.name for v in s.velocity_steps) else "steps",
            f"{math.degrees(r.max_yaw_rate_rad_s):.1f}",
        )
        for k, r in enumerate(s.segments, start=1)
    ]
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    left = {1, 2, 3}
    for row in (header, *rows):
        w("  ".join(c.ljust(widths[i]) if i in left else c.rjust(widths[i]) for i, c in enumerate(row)).rstrip() + "\n")
    w(f"\ntotal     {s.duration_s:.2f} s, {s.length_m:.2f} m of path ({len(s.segments)} segments)\n")
    lo, hi = s.min_ned_m, s.max_ned_m
    w(f"bounds    north [{lo[0]:.2f}, {hi[0]:.2f}]  east [{lo[1]:.2f}, {hi[1]:.2f}]  down [{lo[2]:.2f}, {hi[2]:.2f}] m (NED)\n")
    w(_wrapped(
        "peaks     ",
        f"speed {s.max_speed_m_s:.2f} m/s, acceleration {s.max_accel_m_s2:.2f} m/s^2"
        f"{' between the velocity steps' if s.velocity_steps else ''}, "
        f"yaw rate {math.degrees(s.max_yaw_rate_rad_s):.1f} deg/s (sampled every {dt_s * 1000:g} ms)"
    ))
    if s.velocity_steps:
        listed = ", ".join(f"t = {v.t_s:.2f} s {v.speed_change_m_s:.2f} m/s ({v.where})" for v in s.velocity_steps[:8])
        more = f" and {len(s.velocity_steps) - 8} more" if len(s.velocity_steps) > 8 else ""
        w(_wrapped("speed     ", f"the velocity reference steps (unbounded acceleration, not smoothed): {listed}{more}"))
    if s.jumps:
        w("jumps     the reference steps between segments (not smoothed):\n")
        for j in s.jumps:
            w(
                f"          t = {j.t_s:.2f} s  {j.from_segment} -> {j.to_segment}: "
                f"{j.position_m:.2f} m, yaw {math.degrees(j.yaw_rad):+.1f} deg\n"
            )
    else:
        w("jumps     none: the reference is continuous in position and yaw\n")
    w(_wrapped("phases    ", ", ".join(f"{p.name} [{p.start_s:.1f}, {p.end_s:.1f}) {p.kind}" for p in traj.phases())))


def _wrapped(label: str, text: str, width: int = 100) -> str:
    """A long report line, wrapped at ``width`` under its label."""
    import textwrap

    return textwrap.fill(text, width, initial_indent=label, subsequent_indent=" " * len(label), break_on_hyphens=False) + "\n"
