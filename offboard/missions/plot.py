"""A picture of a mission's path: 3D view and top view, one colour per segment (PNG, headless).

Drawn with matplotlib's Agg canvas directly (no pyplot, no display, no global backend state).
Axes are east/north/up, the way a map is read; jumps between segments are dotted.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from offboard.trajectory.base import Trajectory
from offboard.trajectory.sampling import DEFAULT_DT_S, sample
from offboard.trajectory.sequence import Sequence


def plot_path(
    trajectory: Trajectory,
    path: str | Path,
    title: str = "",
    start_ned_m: tuple[float, float, float] | None = None,
    dt_s: float = DEFAULT_DT_S,
) -> Path:
    """Write a PNG of the path of ``trajectory`` to ``path`` and return it.

    Parameters
    ----------
    trajectory : Trajectory
        NED; each segment of a ``Sequence`` gets its own colour and legend entry.
    path : str or Path
        Output file (PNG).
    title : str
        Figure title.
    start_ned_m : tuple of 3 floats, optional
        The vehicle's start, marked with a square.
    dt_s : float
        Sampling step (s).
    """
    path = Path(path)
    fig = Figure(figsize=(14, 5.5), dpi=100)
    FigureCanvasAgg(fig)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    if isinstance(trajectory, Sequence):
        parts = list(zip(trajectory.starts_s, trajectory.segments))
    else:
        parts = [(0.0, trajectory)]
    if len(parts) <= 10:
        colours: list[str | tuple[float, float, float, float]] = [f"C{k}" for k in range(len(parts))]
    else:  # distinct colours for up to 20 segments, then they repeat
        palette = matplotlib.colormaps["tab20"]
        colours = [palette(k % 20) for k in range(len(parts))]
    prev_end: np.ndarray | None = None
    for (t0, seg), colour in zip(parts, colours):
        s = sample(seg, dt_s)
        north, east, up = s.pos_ned_m[:, 0], s.pos_ned_m[:, 1], -s.pos_ned_m[:, 2]
        label = f"{getattr(seg, 'name', type(seg).__name__)} ({t0:.1f} s)"
        ax3.plot(east, north, up, color=colour, label=label)
        ax2.plot(east, north, color=colour, label=label)
        if prev_end is not None and np.linalg.norm(s.pos_ned_m[0] - prev_end) > 1e-3:
            ax3.plot([prev_end[1], east[0]], [prev_end[0], north[0]], [-prev_end[2], up[0]], ":", color="0.4")
            ax2.plot([prev_end[1], east[0]], [prev_end[0], north[0]], ":", color="0.4")
        prev_end = s.pos_ned_m[-1]
    if start_ned_m is not None:
        n0, e0, d0 = start_ned_m
        ax3.scatter([e0], [n0], [-d0], marker="s", color="k")
        ax2.plot([e0], [n0], "ks", label="vehicle start")
    ax3.set_xlabel("east (m)")
    ax3.set_ylabel("north (m)")
    ax3.set_zlabel("up (m)")
    ax3.set_title("3D")
    ax2.set_xlabel("east (m)")
    ax2.set_ylabel("north (m)")
    ax2.set_title("top view")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)  # into an existing folder: the rule of every output file (offboard/model/paths.py)
    return path
