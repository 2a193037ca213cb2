"""Tracking: the paper's law against SE(3) and the PX4 cascade, same missions, limits, noise, wind.

Every controller flies the same rigid-body vehicle, from the same start, with the same sample
time (To = 50 ms), in two comparisons (``LOOPS``; ``bench.pilots``):

- ``px4-attitude``: the comparison a MAVLink user makes. Every controller, built as ``offboard
  fly --controller K`` builds it, hands an attitude target, thrust and yaw feed-forward to PX4's
  attitude and rate controllers every 50 ms (sitl-plant's px4 inner loop, in-process: the same
  flight as over MAVLink in lockstep to float32 rounding). The paper's law flies with Table I's
  gains and with the gains ``offboard fly`` designs for the vehicle (docs/controller-design.md);
- ``own``: each controller with its own inner loop at the physics rate (1 kHz), thrust range
  0-19.6 N and tilt limit 35 deg: the paper's eq. 16, Lee's attitude law, PX4's attitude loop.

Conditions:

- ``nominal``: the controllers know the vehicle;
- ``table-ii``: they believe the paper's Table II (m = 0.6 kg, I = 2.7/4.8/8.9e-3) while the
  vehicle has m = 0.5 kg, I = 3.8/3.8/7.1e-3;
- ``noise``: the paper's 5 % acceleration noise with integrated velocity and position
  (``paper:0.05``);
- ``wind``: Dryden turbulence with a 5 m/s mean wind and a 5 m/s 1-cosine gust from the east at
  t = 6 s, on the vehicle variant with linear drag (``bench/vehicles/paper-quad-drag.toml``).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
CONTROLLERS = ("paper", "se3", "px4", "paper+i")
#: The two comparisons (module docstring) and their controllers.
LOOPS = {"px4-attitude": ("paper-designed", "paper", "se3", "px4"), "own": CONTROLLERS}
LOOP_TITLES = {"px4-attitude": "through PX4's attitude loop", "own": "each controller's own inner loop"}
CONTROLLER_TITLES = {
    "paper": "paper's law",
    "paper-designed": "paper's law, designed gains",
    "se3": "SE(3) (Lee)",
    "px4": "PX4 cascade",
    "paper+i": "paper's law + integral",
}
INTEGRAL_GAIN_PER_S = 1.0  # missions/paper-sim2-integral.toml's
FINAL_WINDOW_S = 2.0
WIND_SPEC = "dryden:5+gust:t=6,amp=5,dur=2,dir=270"


@dataclass(frozen=True)
class Mission:
    key: str
    file: str
    duration_s: float | None
    note: str


MISSIONS = (
    Mission("helix", "paper-helix.toml", 11.95,
            "the helix phase (0-12 s) of the paper's Simulation 1; the vehicle starts hovering at the "
            "reference's start (2, 0, 2 m up) at rest, while the reference moves at 2.15 m/s"),
    Mission("square", "paper-square.toml", None,
            "Simulation 3's 5 m square at 5 m, 1 m/s, then a 5 s hold; starts hovering at the first corner"),
    Mission("figure-eight", "figure-eight.toml", None,
            "take-off to 3 m, two laps of an 8 m x 4 m eight (16 s a lap) facing along the path, land; "
            "starts on the ground"),
    Mission("waypoints", "px4-sitl-box.waypoints", None,
            "QGC WPL box around PX4 SITL's home: take-off to 10 m, four waypoints with loiters, land; "
            "starts on the ground"),
)  # fmt: skip
CONDITIONS = ("nominal", "table-ii", "noise", "wind")


def _job(args: tuple) -> dict:
    mission_key, condition, controller, quick_s, loop = args
    from bench.flight import fly
    from bench.pilots import NOMINAL, TABLE_II, contender, flown_controller
    from offboard.inprocess import Drive
    from offboard.missions import MISSIONS_DIR, load_mission
    from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

    mission = next(m for m in MISSIONS if m.key == mission_key)
    trajectory = load_mission(MISSIONS_DIR / mission.file).trajectory
    vehicle_file = BENCH_DIR / "vehicles" / "paper-quad-drag.toml" if condition == "wind" else PAPER_VEHICLE_FILE
    vehicle = load_vehicle(vehicle_file)
    belief = TABLE_II if condition == "table-ii" else NOMINAL
    if loop == "px4-attitude":
        law, drive = flown_controller(controller, belief, vehicle), Drive.PX4
    else:
        law, drive = contender(controller, belief, INTEGRAL_GAIN_PER_S)
    duration = mission.duration_s if mission.duration_s is not None else trajectory.duration_s
    if quick_s:
        duration = min(duration, quick_s)
    result = fly(
        law, drive, trajectory, vehicle, duration_s=duration,
        sensors="paper:0.05" if condition == "noise" else "clean",
        wind=WIND_SPEC if condition == "wind" else "none",
        seed=1,
    )  # fmt: skip
    err = result.error_m
    every = max(1, len(result.t_s) // 400)
    return {
        "loop": loop,
        "mission": mission_key,
        "condition": condition,
        "controller": controller,
        "rms_m": float(np.sqrt(np.mean(err**2))) if len(err) else math.nan,
        "max_m": float(np.max(err)) if len(err) else math.nan,
        # the steady state a model error leaves: mean error over the last FINAL_WINDOW_S
        "final_m": float(np.mean(err[result.t_s >= result.t_s[-1] - FINAL_WINDOW_S])) if len(err) else math.nan,
        "tilt_deg": float(np.degrees(np.max(result.tilt_rad))) if len(err) else math.nan,
        "thrust_n": float(np.max(result.thrust_n)) if len(err) else math.nan,
        "cost_us": float(np.median(result.cost_s) * 1e6) if len(err) else math.nan,
        "diverged_at_s": result.diverged_at_s,
        "flown_s": float(result.t_s[-1]) if len(err) else 0.0,
        "path": result.pos_ned_m[::every].tolist(),
        "ref": result.ref_ned_m[::every].tolist(),
    }


def run(*, workers: int = 2, quick_s: float | None = None, missions: tuple[str, ...] | None = None,
        loops: tuple[str, ...] = tuple(LOOPS)) -> list[dict]:  # fmt: skip
    """Fly the whole matrix (in ``workers`` processes); one dict per flight."""
    jobs = [
        (m.key, c, k, quick_s, loop)
        for loop in loops
        for m in MISSIONS
        if missions is None or m.key in missions
        for c in CONDITIONS
        for k in LOOPS[loop]
    ]
    jobs.sort(key=lambda j: j[2] in ("se3", "px4"), reverse=True)  # the slow ones first
    if workers <= 1:
        results = [_job(j) for j in jobs]
    else:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        env_path = str(BENCH_DIR.parent)
        os.environ["PYTHONPATH"] = env_path + os.pathsep + os.environ.get("PYTHONPATH", "")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            results = list(pool.map(_job, jobs))
    order = {(loop, m.key, c, k): i for i, (loop, m, c, k) in enumerate(
        (loop, m, c, k) for loop in LOOPS for m in MISSIONS for c in CONDITIONS for k in LOOPS[loop])}  # fmt: skip
    return sorted(results, key=lambda r: order[(r["loop"], r["mission"], r["condition"], r["controller"])])


def _cell(value: float, best: bool, fmt: str) -> str:
    text = format(value, fmt) if math.isfinite(value) else "-"
    return f"**{text}**" if best else text


def tables(results: list[dict], controllers: tuple[str, ...]) -> str:
    """One markdown table per mission: rows condition x metric, columns the controllers."""
    out = []
    metrics = (("rms_m", "RMS 3D error (m)", ".3f", True), ("max_m", "max 3D error (m)", ".2f", True),
               ("final_m", f"mean error, last {FINAL_WINDOW_S:g} s (m)", ".3f", True),
               ("tilt_deg", "peak tilt (deg)", ".0f", False), ("thrust_n", "peak thrust (N)", ".1f", False))  # fmt: skip
    for mission in MISSIONS:
        rows = [r for r in results if r["mission"] == mission.key]
        if not rows:
            continue
        out.append(f"#### {mission.key}\n\n{mission.note}.\n")
        out.append(f"![{mission.key}](tracking-{mission.key}.png)\n")
        out.append("| condition | metric | " + " | ".join(CONTROLLER_TITLES[c] for c in controllers) + " |")
        out.append("|---|---|" + "---:|" * len(controllers))
        for condition in CONDITIONS:
            cells = {r["controller"]: r for r in rows if r["condition"] == condition}
            if not cells:
                continue
            for key, title, fmt, lower_is_better in metrics:
                values = [cells[c][key] if c in cells else math.nan for c in controllers]
                finite = [v for v in values if math.isfinite(v)]
                best = min(finite) if (finite and lower_is_better) else None
                texts = []
                for c, v in zip(controllers, values):
                    text = _cell(v, best is not None and v == best, fmt)
                    if c in cells and cells[c]["diverged_at_s"] is not None and key == "rms_m":
                        text += f" (diverged at {cells[c]['diverged_at_s']:.2f} s)"
                    texts.append(text)
                out.append(f"| {condition} | {title} | " + " | ".join(texts) + " |")
        nominal = {r["controller"]: r for r in rows if r["condition"] == "nominal"}
        out.append("| all | controller step, median (µs) | "
                   + " | ".join(f"{nominal[c]['cost_us']:.0f}" if c in nominal else "-" for c in controllers) + " |")  # fmt: skip
        out.append("")
    return "\n".join(out)


def summary(results: list[dict], controllers: tuple[str, ...]) -> str:
    """RMS error of every flight in one table, and who wins where (``paper+i``, an option, is
    shown but not ranked); with the designed law, where it does not win and by how much."""
    lines = ["| mission | condition | " + " | ".join(CONTROLLER_TITLES[c] for c in controllers) + " | best |",
             "|---|---|" + "---:|" * len(controllers) + "---|"]  # fmt: skip
    wins = {c: 0 for c in controllers}
    base = [c for c in controllers if c != "paper+i"]
    losses: list[str] = []
    for mission in MISSIONS:
        for condition in CONDITIONS:
            cells = {r["controller"]: r for r in results if r["mission"] == mission.key and r["condition"] == condition}
            if not cells:
                continue
            rms = {c: cells[c]["rms_m"] if c in cells and cells[c]["diverged_at_s"] is None else math.inf for c in controllers}
            best = min(base, key=lambda c: rms[c])
            wins[best] += 1
            if "paper-designed" in base and best != "paper-designed" and math.isfinite(rms["paper-designed"]):
                losses.append(f"{mission.key}/{condition}: {CONTROLLER_TITLES[best]} {rms[best]:.3f} m against "
                              f"{rms['paper-designed']:.3f} m (+{100 * (rms['paper-designed'] / rms[best] - 1):.0f} %)")
            lines.append(f"| {mission.key} | {condition} | " + " | ".join(
                _cell(rms[c], c == best, ".3f") for c in controllers) + f" | {CONTROLLER_TITLES[best]} |")  # fmt: skip
    lines.append("")
    lines.append("Lowest RMS error: " + ", ".join(f"{CONTROLLER_TITLES[c]} {wins[c]}" for c in base) + " flights.")
    if "paper-designed" in base:
        lines.append("")
        lines.append("Where the designed law is not the lowest: " + ("; ".join(losses) if losses else "nowhere") + ".")
    return "\n".join(lines)


def plots(results: list[dict], out_dir: Path, controllers: tuple[str, ...]) -> list[Path]:
    """One PNG per mission (nominal condition): top view and height against sample, all paths."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    colours = {"paper": "tab:red", "paper-designed": "tab:orange", "se3": "tab:blue", "px4": "tab:green", "paper+i": "tab:purple"}
    written = []
    for mission in MISSIONS:
        rows = {r["controller"]: r for r in results if r["mission"] == mission.key and r["condition"] == "nominal"}
        if not rows:
            continue
        fig = Figure(figsize=(8.0, 3.6), dpi=80)
        FigureCanvasAgg(fig)
        top, side = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
        ref = np.array(next(iter(rows.values()))["ref"])
        top.plot(ref[:, 1], ref[:, 0], color="k", lw=1.0, ls="--", label="reference")
        side.plot(-ref[:, 2], color="k", lw=1.0, ls="--")
        for c in controllers:
            if c not in rows:
                continue
            path = np.array(rows[c]["path"])
            top.plot(path[:, 1], path[:, 0], color=colours[c], lw=1.0, label=CONTROLLER_TITLES[c])
            side.plot(-path[:, 2], color=colours[c], lw=1.0)
        top.set_xlabel("east (m)")
        top.set_ylabel("north (m)")
        top.set_aspect("equal", adjustable="datalim")
        top.legend(fontsize=7, loc="best")
        side.set_xlabel("sample")
        side.set_ylabel("height (m)")
        fig.suptitle(f"{mission.key}: nominal parameters", fontsize=9)
        fig.tight_layout()
        path = out_dir / f"tracking-{mission.key}.png"
        fig.savefig(path)
        written.append(path)
    return written
