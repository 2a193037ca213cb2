"""The paper's figures (Fig. 2-6) of any ``FlightRecord``, as PNG files, headless.

One figure per question the paper's Section 4 answers:

=================  =========================================================================
``path3d.png``     3D path flown and its reference (Fig. 2); north, east, up (= -down), metres
``position.png``   x north, y east, z up against time, with their references (Fig. 3)
``attitude.png``   roll, pitch, yaw against time with the law's x7ez, x9ez and the yaw
                   reference, degrees (Fig. 4)
``errors.png``     position errors per axis (reference - flown, z up) and the wrapped yaw
                   error, against time (Fig. 5)
``actions.png``    u and the real torques of eq. 16, tau_phi, tau_theta, tau_psi (Fig. 6)
=================  =========================================================================

Phase boundaries are light vertical lines. Columns that a record does not hold (NaN, as in a
replayed log without commands) leave their lines empty rather than failing; a one-sample
record draws markers instead of lines.

The figures are built on ``matplotlib.figure.Figure`` with the Agg canvas, never through
``pyplot``: nothing opens a window, nothing needs a display, no global backend is switched
under a caller (a notebook keeps its own), and each figure is freed when its last reference
goes, so a long batch of runs does not accumulate open figures.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from offboard.record import FlightRecord, FlightStatus
from offboard.model.rotations import wrap_pi

if TYPE_CHECKING:  # only the annotation: the design's modules load with offboard tune --plot
    from offboard.controller.design import Design

#: File stems of the figures ``write_figures`` writes, in order.
FIGURE_NAMES = ("path3d", "position", "attitude", "errors", "actions")

FLOWN = {"color": "tab:blue", "linewidth": 1.3}
REFERENCE = {"color": "tab:red", "linewidth": 1.0, "linestyle": "--", "zorder": 3}  # on top: visible where tracking is good
PHASE_LINE = {"color": "0.75", "linewidth": 0.8, "zorder": 0}
DPI = 100
LAYOUT = None  # "constrained" looks a little tidier but doubles the drawing time


def _new_figure(rows: int, title: str, what: str) -> tuple[Figure, list]:
    height_in = 1.9 * rows + 0.8
    fig = Figure(figsize=(8.0, height_in), dpi=DPI, layout=LAYOUT)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.11, right=0.97, top=1.0 - 0.55 / height_in, bottom=0.5 / height_in, hspace=0.18)
    axes = list(fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0])
    fig.suptitle(f"{title} - {what}" if title else what)
    axes[-1].set_xlabel("t [s]")
    return fig, axes


def _style(n: int) -> dict:
    """A one-sample record has no line to draw: show its point."""
    return {"marker": "o", "markersize": 4} if n == 1 else {}


def _phase_lines(record: FlightRecord, axes: list) -> None:
    for phase in record.phases:
        if phase.start_s <= 0.0:
            continue
        for ax in axes:
            ax.axvline(phase.start_s, **PHASE_LINE)
    if record.phases:
        top = axes[0]
        for phase in record.phases:
            top.annotate(
                phase.name, xy=(max(phase.start_s, 0.0), 1.0), xycoords=("data", "axes fraction"),
                xytext=(2, -2), textcoords="offset points", fontsize=7, color="0.45", va="top",
            )


def _end_mark(record: FlightRecord, axes: list) -> None:
    """Where a flight that did not complete ended (diverged, NaN command, link lost ...): a red
    dotted line at its last sample, with the status."""
    if record.status is FlightStatus.COMPLETE or not len(record):
        return
    t_end = float(record["t_s"][-1])
    for ax in axes:
        ax.axvline(t_end, color="tab:red", linewidth=0.9, linestyle=":", zorder=4)
    axes[0].annotate(f"{record.status.value} at {t_end:.2f} s", xy=(t_end, 0.0), xycoords=("data", "axes fraction"),
                     xytext=(-3, 3), textcoords="offset points", fontsize=7, color="tab:red", ha="right", va="bottom")


def _no_data(ax, values: np.ndarray, why: str) -> None:
    """A panel with nothing to draw says why instead of staying blank."""
    if not np.any(np.isfinite(np.asarray(values, dtype=float))):
        ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center", fontsize=8, color="0.4")


def _up(ned: np.ndarray) -> np.ndarray:
    """North, east, down -> north, east, up (the paper's x, y, z)."""
    out = np.array(ned, dtype=float, copy=True).reshape(-1, 3)
    out[:, 2] = -out[:, 2]
    return out


def _finish(ax, ylabel: str) -> None:
    ax.set_ylabel(ylabel)
    ax.grid(True, linewidth=0.4, alpha=0.5)


def path3d_figure(record: FlightRecord, title: str = "") -> Figure:
    """Fig. 2: the path flown and the reference in 3D, north/east/up in metres."""
    fig = Figure(figsize=(7.0, 6.0), dpi=DPI, layout=LAYOUT)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    style = _style(len(record))
    ref = _up(record["ref_pos_ned_m"])
    pos = _up(record["pos_ned_m"])
    ax.plot(ref[:, 0], ref[:, 1], ref[:, 2], label="reference", **REFERENCE, **style)
    ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], label="flown", **FLOWN, **style)
    finite = pos[np.all(np.isfinite(pos), axis=1)]
    if len(finite):
        ax.scatter(*finite[0], color="tab:green", s=18, label="start")
        ax.scatter(*finite[-1], color="black", s=18, marker="x", label="end")
    ax.set_xlabel("x north [m]")
    ax.set_ylabel("y east [m]")
    ax.set_zlabel("z up [m] (= -down)")
    ax.legend(loc="upper left", fontsize=8)
    what = "3D path (local NED shown north, east, up)"
    fig.suptitle(f"{title} - {what}" if title else what)
    return fig


def position_figure(record: FlightRecord, title: str = "") -> Figure:
    """Fig. 3: x north, y east, z up against time, with the references."""
    fig, axes = _new_figure(3, title, "position")
    t = record["t_s"]
    style = _style(len(record))
    pos, ref = _up(record["pos_ned_m"]), _up(record["ref_pos_ned_m"])
    for i, (ax, label) in enumerate(zip(axes, ("x north [m]", "y east [m]", "z up [m]"))):
        ax.plot(t, ref[:, i], label="reference", **REFERENCE, **style)
        ax.plot(t, pos[:, i], label="flown", **FLOWN, **style)
        _finish(ax, label)
    axes[0].legend(loc="upper right", fontsize=8)
    _phase_lines(record, axes)
    _end_mark(record, axes)
    return fig


def attitude_figure(record: FlightRecord, title: str = "") -> Figure:
    """Fig. 4: roll, pitch, yaw with the law's x7ez, x9ez and the yaw reference, degrees."""
    fig, axes = _new_figure(3, title, "attitude")
    t = record["t_s"]
    style = _style(len(record))
    euler = np.degrees(np.asarray(record["euler_rad"], dtype=float).reshape(-1, 3))
    ref_euler = np.degrees(np.asarray(record["ref_euler_rad"], dtype=float).reshape(-1, 3))
    refs = (ref_euler[:, 0], ref_euler[:, 1], np.degrees(np.asarray(record["ref_yaw_rad"], dtype=float)))
    names = ("x7ez (roll ref.)", "x9ez (pitch ref.)", "yaw ref.")
    labels = ("roll phi [deg]", "pitch theta [deg]", "yaw psi [deg]")
    for i, ax in enumerate(axes):
        ax.plot(t, refs[i], label=names[i], **REFERENCE, **style)
        ax.plot(t, euler[:, i], label="flown", **FLOWN, **style)
        ax.legend(loc="upper right", fontsize=8)
        _finish(ax, labels[i])
    _phase_lines(record, axes)
    return fig


def errors_figure(record: FlightRecord, title: str = "") -> Figure:
    """Fig. 5: e = reference - flown per axis (x north, y east, z up) and the yaw error."""
    fig, axes = _new_figure(4, title, "tracking errors (reference - flown)")
    t = record["t_s"]
    style = _style(len(record))
    err = _up(record.error_ned_m)
    yaw_err = np.degrees(wrap_pi(np.asarray(record["ref_yaw_rad"], dtype=float) - record["euler_rad"][:, 2]))
    series = (err[:, 0], err[:, 1], err[:, 2], yaw_err)
    labels = ("e_x north [m]", "e_y east [m]", "e_z up [m]", "e_psi [deg]")
    for ax, values, label in zip(axes, series, labels):
        ax.axhline(0.0, color="0.6", linewidth=0.6)
        ax.plot(t, values, label=label, **FLOWN, **style)
        _no_data(ax, values, "no references: replay it with --mission FILE")
        _finish(ax, label)
    _phase_lines(record, axes)
    _end_mark(record, axes)
    return fig


def actions_figure(record: FlightRecord, title: str = "") -> Figure:
    """Fig. 6: thrust u [N] and the real torques of eq. 16 [N m]."""
    fig, axes = _new_figure(4, title, "control actions (eq. 9, 11, 16)")
    t = record["t_s"]
    style = _style(len(record))
    torques = np.asarray(record["torques_nm"], dtype=float).reshape(-1, 3)
    series = (record["thrust_n"], torques[:, 0], torques[:, 1], torques[:, 2])
    labels = ("u [N]", "tau_phi [N m]", "tau_theta [N m]", "tau_psi [N m]")
    for ax, values, label in zip(axes, series, labels):
        ax.plot(t, values, label=label, **FLOWN, **style)
        _no_data(ax, values, "not in the log (attitude setpoints carry no torques): replay --rerun recomputes them"
                 if label.startswith("tau") else "no thrust in the log")
        _finish(ax, label)
    _phase_lines(record, axes)
    _end_mark(record, axes)
    return fig


FIGURES: dict[str, Callable[[FlightRecord, str], Figure]] = {
    "path3d": path3d_figure,
    "position": position_figure,
    "attitude": attitude_figure,
    "errors": errors_figure,
    "actions": actions_figure,
}


def make_figures(record: FlightRecord, title: str = "") -> dict[str, Figure]:
    """All figures of ``record``, not yet saved, keyed by ``FIGURE_NAMES``."""
    return {name: FIGURES[name](record, title) for name in FIGURE_NAMES}


def save_figure(fig: Figure, path: Path) -> Path:
    """Write one figure as PNG (the figure is freed with its last reference; no pyplot registry)."""
    fig.savefig(path, format="png", dpi=DPI)
    return path


def write_figures(record: FlightRecord, run_dir: Path, title: str = "") -> list[Path]:
    """Write the five figures of ``record`` into ``run_dir`` (created if needed).

    Parameters
    ----------
    record : FlightRecord
        Any flight: in-process, MAVLink, or replayed (NaN columns allowed).
    run_dir : Path
        Folder for ``path3d.png``, ``position.png``, ``attitude.png``, ``errors.png``,
        ``actions.png``.
    title : str
        Prefix of every figure title (scenario or log name).

    Returns
    -------
    list of Path
        The files written, in ``FIGURE_NAMES`` order.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in FIGURE_NAMES:
        paths.append(save_figure(FIGURES[name](record, title), run_dir / f"{name}.png"))
    return paths


#: One panel of a comparison: y label, then the two series (shape (n,) or (n, k)) and the
#: names of their k components.
ComparisonPanel = tuple[str, np.ndarray, np.ndarray, tuple[str, ...]]


def comparison_figure(
    t_s: np.ndarray, panels: list[ComparisonPanel], title: str = "", labels: tuple[str, str] = ("logged", "re-run")
) -> Figure:
    """Two runs side by side, one panel per quantity: the first solid, the second dashed.

    Used by ``offboard replay --rerun`` to show what a changed controller would have commanded
    beside what was flown.
    """
    fig, axes = _new_figure(len(panels), title, f"{labels[0]} (solid) vs {labels[1]} (dashed)")
    style = {"marker": "o", "markersize": 3} if len(t_s) == 1 else {}
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
    for ax, (ylabel, first, second, names) in zip(axes, panels):
        a = np.asarray(first, dtype=float).reshape(len(t_s), -1)
        b = np.asarray(second, dtype=float).reshape(len(t_s), -1)
        for i in range(a.shape[1]):
            name = names[i] if i < len(names) else ylabel
            color = colors[i % len(colors)]
            ax.plot(t_s, a[:, i], color=color, linewidth=1.3, label=f"{name} {labels[0]}", **style)
            ax.plot(t_s, b[:, i], color=color, linewidth=1.0, linestyle="--", label=f"{name} {labels[1]}", **style)
        if a.shape[1] > 1:
            ax.legend(loc="upper right", fontsize=7, ncol=a.shape[1])
        _finish(ax, ylabel)
    return fig


def design_figure(design: Design, path: Path) -> Path:
    """``offboard tune --plot``: the north axis's loop gain, phase and closed-loop poles, designed
    gains against Table I's (docs/controller-design.md)."""
    from offboard.controller.design import AxisGains, analyse_axis, axis_plants, loop_response
    from offboard.controller.params import ControllerGains

    table1 = ControllerGains()
    to = design.sample_time_s
    north, _, _ = axis_plants(design.model, to)
    fig = Figure(figsize=(10.0, 4.2), dpi=DPI, layout=LAYOUT)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.13, top=0.88, wspace=0.3, hspace=0.08)
    grid = fig.add_gridspec(2, 2, width_ratios=(1.6, 1.0))
    ax_mag, ax_ph, ax_z = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[:, 1])
    cases = (("Table I", AxisGains(table1.kx1, table1.kx2), "tab:red"), ("designed", design.horizontal, "tab:blue"))
    for name, gains, color in cases:
        w, loop = loop_response(north, gains, to)
        a = analyse_axis(north, gains, to)
        label = (f"{name}: kx1 {float(gains.k_pos):.3g}, kx2 {float(gains.k_vel):.3g}, lead {float(gains.lead):g}, ki "
                 f"{float(gains.integral_per_s):.2g} (GM {a.gain_margin:.2f}, PM {a.phase_margin_deg:.0f} deg)")
        ax_mag.loglog(w, np.abs(loop), color=color, label=label)
        ax_ph.semilogx(w, np.degrees(np.unwrap(np.angle(loop))), color=color)
        ax_z.plot(a.poles.real, a.poles.imag, "x", color=color, label=f"{name}: |pole| max {a.spectral_radius:.3f}")
    ax_mag.axhline(1.0, color="0.6", linewidth=0.8)
    ax_ph.axhline(-180.0, color="0.6", linewidth=0.8)
    ax_mag.set_ylabel("|L|")
    ax_ph.set_ylabel("arg L [deg]")
    ax_ph.set_xlabel("w [rad/s]")
    ax_mag.legend(fontsize=7, loc="lower left")
    ax_mag.tick_params(labelbottom=False)
    theta = np.linspace(0, 2 * np.pi, 200)
    ax_z.plot(np.cos(theta), np.sin(theta), color="0.6", linewidth=0.8)
    ax_z.set_aspect("equal")
    ax_z.set_xlabel("Re z")
    ax_z.set_ylabel("Im z")
    ax_z.legend(fontsize=7, loc="lower left")
    fig.suptitle(f"north axis loop broken at the tilt setpoint, To {to:g} s, latency {design.model.latency_s * 1000:.0f} ms")
    return save_figure(fig, path)
