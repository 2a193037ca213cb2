"""``make bench``: every benchmark of docs/benchmarks.md in one run, written to ``bench/RESULTS.md``.

Speed figures stand next to their floor or peer measured in the same run (the pseudo-inverse
law, RotorPy's ``Multirotor``, the numpy batch, a bare pymavlink ping-pong); tracking flies
the paper's law, SE(3) and the PX4 cascade through the same missions and conditions. Raw
numbers go to ``results.json`` beside the output, the tracking plots to ``img/``.

    python bench/run.py [--output bench/RESULTS.md] [--quick] [--workers 2] [--only speed,loop,tracking,design,sweep,faults]

``--quick`` shrinks every measurement (about a minute in all: 54 s wall on a shared 2-core machine):
for the smoke test, not for figures.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # `python bench/run.py` from anywhere
    sys.path.insert(0, str(ROOT))

from offboard import jsonout  # noqa: E402

PARTS = ("speed", "loop", "tracking", "design", "sweep", "faults")

# sizes of every measurement: (full, quick)
SIZES = {
    "controller_calls": (5000, 200),
    "controller_repeats": (9, 3),
    "flight_s": (12.0, 0.5),  # the paper helix's helix phase, fast simulator
    "reference_flight_s": (2.0, 0.2),  # VehicleSim (interpreted), the same flight's start
    "rotorpy_flight_s": (2.0, 0.1),
    "batch_sizes": ([1, 10, 100, 1000, 10_000, 100_000], [1, 10]),
    "batch_steps": (200, 5),
    "numpy_max": (10_000, 10),
    "tracking_quick_s": (None, 0.5),
}


def _size(key: str, quick: bool):  # noqa: ANN202
    return SIZES[key][1 if quick else 0]


def _say(text: str) -> None:
    print(f"[bench {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


# --- the machine ---------------------------------------------------------------------------------


def machine() -> dict:
    """What the figures were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gib = math.nan
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem_gib = int(line.split()[1]) / 2**20
    except OSError:
        pass
    versions = {}
    for dist in ("numpy", "pymavlink", "numba", "rotorpy", "scipy", "py-spy"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    # dirty: changes other than this report's own outputs (a previous run's RESULTS.md, plots)
    changed = subprocess.run(["git", "status", "--porcelain", "--", ".", ":!bench/RESULTS.md", ":!bench/img"],
                             cwd=ROOT, capture_output=True, text=True).stdout.strip()  # fmt: skip
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "memory_gib": round(mem_gib, 1),
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
        "os": f"{platform.system()} {platform.release()}",
        "python": f"{platform.python_implementation()} {platform.python_version()}",
        "versions": versions,
        "commit": (commit.stdout.strip() + ("-dirty" if changed else "")) or None,
        "date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }


# --- measuring -------------------------------------------------------------------------------------


def measure_speed(quick: bool) -> dict:
    from bench import speed

    _say("controller step (closed form vs pseudo-inverse)")
    out = {"controller": speed.controller_step(_size("controller_calls", quick), _size("controller_repeats", quick))}
    _say("physics, one vehicle (compiled, VehicleSim, interpreted kernels, RotorPy)")
    out["physics"] = speed.physics_one_vehicle(
        _size("flight_s", quick), _size("reference_flight_s", quick), _size("rotorpy_flight_s", quick)
    )
    _say("physics, many vehicles")
    out["batch"] = speed.physics_batch(_size("batch_sizes", quick), _size("batch_steps", quick), _size("numpy_max", quick))
    out["numba_compile_s"] = None if quick else speed.numba_compile_s()
    return out


def measure_loop(quick: bool) -> dict:
    from bench import loop

    _say("MAVLink lockstep loop vs ping-pong floor, real-time jitter, memory")
    return loop.measure(quick=quick)


def measure_tracking(quick: bool, workers: int, img_dir: Path) -> dict:
    from bench import tracking

    missions = ("helix",) if quick else None
    _say(f"tracking: {'1 mission' if quick else f'{len(tracking.MISSIONS)} missions'} x {len(tracking.CONDITIONS)} "
         f"conditions x {' + '.join(str(len(c)) for c in tracking.LOOPS.values())} controllers "
         f"({' / '.join(tracking.LOOPS)}), {workers} processes")  # fmt: skip
    results = tracking.run(workers=workers, quick_s=_size("tracking_quick_s", quick), missions=missions)
    img_dir.mkdir(parents=True, exist_ok=True)
    primary = [r for r in results if r["loop"] == "px4-attitude"]
    plots = tracking.plots(primary, img_dir, tracking.LOOPS["px4-attitude"])
    return {"flights": results, "plots": [p.name for p in plots]}


def measure_design(quick: bool) -> dict:
    from bench import design

    _say("design: the law over MAVLink through the attitude loop, Table I against the designed gains")
    return design.run(quick=quick, say=_say)


def measure_faults(quick: bool) -> dict:
    from bench import faults

    _say("faults: a lossy link, a killed offboard (real time)")
    return faults.measure(quick=quick)


def measure_sweep(quick: bool) -> dict:
    from bench import sweep

    return sweep.measure(quick=quick, say=_say)


# --- writing ---------------------------------------------------------------------------------------


def _f(value, fmt: str = ".3g", none: str = "n/a") -> str:  # noqa: ANN001
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return none
    return format(value, fmt)


def _ratio(a, b) -> str:  # noqa: ANN001
    if a is None or b is None or not b:
        return "n/a"
    return f"{a / b:.3g}×"


#: Issue 16: one vehicle in process, closed loop (the paper helix, 1 kHz RK4, the 20 Hz law, eq. 16,
#: the mixer and the sensor model), in simulated seconds per wall second.
ONE_VEHICLE_TARGET_X = 500.0


def one_vehicle_verdict(p: dict) -> str:
    """Whether the compiled one-vehicle closed loop met ``ONE_VEHICLE_TARGET_X`` in this run."""
    rate = p.get("fast_x_realtime")
    if not p.get("numba"):
        return f"Target ≥ {ONE_VEHICLE_TARGET_X:g}× (issue 16): not measured: numba is not installed, the kernels ran interpreted."
    verdict = "met" if rate is not None and rate >= ONE_VEHICLE_TARGET_X else "not met"
    return f"Target ≥ {ONE_VEHICLE_TARGET_X:g}× (issue 16): {_f(rate, '.0f')}×, {verdict}."


def speed_markdown(s: dict) -> str:
    c, p = s["controller"], s["physics"]
    lines = [
        "### Controller step",
        "",
        "Median time of one sample of the paper's law (eq. 28-42) in CPython, against the same law solved",
        "with numpy's pseudo-inverse `w = A⁺b` (eq. 35). Target: under 10 µs.",
        "",
        "| implementation | µs per sample | pinv / this |",
        "|---|---:|---:|",
        f"| `law_step`, closed form (eq. 39-42), the paper's law | {c['law_step_us']:.2f} | {_ratio(c['pinv_us'], c['law_step_us'])} |",
        f"| `law_step`, yaw-aware, thrust and tilt limits | {c['law_step_yaw_aware_limits_us']:.2f} | {_ratio(c['pinv_us'], c['law_step_yaw_aware_limits_us'])} |",
        f"| `RosalesController.step` (+ eq. 16 torques, rotor forces, numpy arrays) | {c['controller_step_us']:.2f} | {_ratio(c['pinv_us'], c['controller_step_us'])} |",
        f"| pseudo-inverse (eq. 35, `numpy.linalg.pinv`), the floor | {c['pinv_us']:.2f} | 1× |",
        "",
        f"Largest difference between the two solutions of (u, τ̃): {c['pinv_max_difference']:.1e}.",
        "",
        "### Physics: one vehicle",
        "",
        f"The paper helix's helix phase ({_f(p['flight_s'], 'g')} s simulated; RotorPy and the interpreted",
        "reference fly its start): the paper's law at 20 Hz, eq. 16 and the mixer at every 1 kHz physics",
        "step, RK4. Simulated seconds per wall second (× real time); \"closed loop\" includes the controller,",
        "the sensor model and the reference, \"physics only\" the stepping. Target (issue 16): the",
        f"compiled closed loop ≥ {ONE_VEHICLE_TARGET_X:g}× real time, in the configuration `make demo` installs (numba in the base install).",
        "",
        "| simulator | closed loop (× real time) | physics only (× real time) | vs RotorPy (closed loop) |",
        "|---|---:|---:|---:|",
        f"| `FastRigidBodySim` ({'numba' if p['numba'] else 'numba NOT installed: interpreted'}) | {_f(p['fast_x_realtime'], '.1f')} | {_f(p['fast_physics_only_x_realtime'], '.1f')} | {_ratio(p['fast_x_realtime'], p.get('rotorpy_x_realtime'))} |",
        f"| `VehicleSim` (the reference: `rigid_body.derivative` + `integrate.rk4_step`) | {_f(p['vehicle_sim_x_realtime'], '.2f')} | {_f(p['vehicle_sim_physics_only_x_realtime'], '.2f')} | {_ratio(p['vehicle_sim_x_realtime'], p.get('rotorpy_x_realtime'))} |",
        f"| `FastRigidBodySim`, kernels interpreted (`SITL_PLANT_NO_NUMBA=1`) | {_f(p.get('no_numba_x_realtime'), '.2f')} | | {_ratio(p.get('no_numba_x_realtime'), p.get('rotorpy_x_realtime'))} |",
        f"| RotorPy `Multirotor.step` ({_f(p.get('rotorpy'), 's', 'not installed')}, `solve_ivp`) | {_f(p.get('rotorpy_x_realtime'), '.3f')} | {_f(p.get('rotorpy_physics_only_x_realtime'), '.3f')} | 1× |",
        "",
        f"Compiled and reference trajectories agree to {p['max_position_difference_m']:.1e} m over the reference's flight.",
        "",
        one_vehicle_verdict(p),
        "",
        "### Physics: many vehicles",
        "",
        "`step_many`: an (N, 17) batch of rigid bodies, RK4 at 1 kHz with held rotor commands and",
        "wind (numba, parallel over the cores), against `step_many_numpy` (the same step vectorised",
        "with numpy over the batch). Target: ≥ 10 million vehicle-steps per second.",
        "",
        "| vehicles | compiled (vehicle-steps/s) | numpy (vehicle-steps/s) | compiled / numpy |",
        "|---:|---:|---:|---:|",
    ]
    for row in s["batch"]:
        lines.append(f"| {row['vehicles']:,} | {row['compiled_per_s']:,.0f} | {_f(row['numpy_per_s'], ',.0f', '-')} | "
                     f"{_ratio(row['compiled_per_s'], row['numpy_per_s']) if row['numpy_per_s'] else '-'} |")  # fmt: skip
    if s.get("numba_compile_s") is not None:
        lines += ["", f"A fresh process imports the kernels and runs each once in {_f(s['numba_compile_s'], '.1f')} s "
                      "(numba's on-disk cache warm; the first run ever compiles for longer)."]  # fmt: skip
    return "\n".join(lines)


def tracking_markdown(t: dict) -> str:
    from bench import tracking

    flights = t["flights"]
    diverged = [f for f in flights if f["diverged_at_s"] is not None]
    by_loop = {loop: [f for f in flights if f.get("loop", "own") == loop] for loop in tracking.LOOPS}
    lines = [
        "Same rigid-body vehicle, missions, sample time (50 ms), noise and wind for every controller; see",
        "`bench/tracking.py` for the conditions. Bold: the lowest. Two comparisons: every controller's",
        "attitude target flown by PX4's attitude loop (what `offboard fly --controller K` flies over MAVLink;",
        "the law with Table I's gains and with the gains `offboard fly` designs), and each controller with",
        "its own inner loop at 1 kHz (0-19.6 N, 35° tilt; the paper's law + integral is",
        f"`integral_gain_per_s = {tracking.INTEGRAL_GAIN_PER_S:g}`, off by default for the reproduction).",
        "",
    ]
    for loop, controllers in tracking.LOOPS.items():
        if by_loop[loop]:
            lines += [f"### RMS 3D error of every flight (m), {tracking.LOOP_TITLES[loop]}", "",
                      tracking.summary(by_loop[loop], controllers), ""]  # fmt: skip
    if diverged:
        lines += ["Flights that diverged: " + ", ".join(
            f"{f.get('loop', 'own')}/{f['mission']}/{f['condition']}/{f['controller']} at {f['diverged_at_s']:.2f} s"
            for f in diverged) + ".", ""]  # fmt: skip
    primary = "px4-attitude" if by_loop["px4-attitude"] else "own"
    lines += [f"### Per mission, {tracking.LOOP_TITLES[primary]}", "",
              tracking.tables(by_loop[primary], tracking.LOOPS[primary]).replace("](tracking-", "](img/tracking-")]  # fmt: skip
    return "\n".join(lines)


def write(results: dict, output: Path, command: str) -> None:
    m = results["machine"]
    v = m["versions"]
    head = [
        "# Benchmarks",
        "",
        f"Written by `{command}` on {m['date_utc']} at commit `{m['commit']}`, in {results['wall_s'] / 60:.1f} min.",
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_gib']} GiB, {m['os']}, {m['python']}; "
        f"load average at start {', '.join(f'{x:.2f}' for x in m['load_average']) if m['load_average'] else 'n/a'}.",
        "Packages: " + ", ".join(f"{k} {v[k] or 'not installed'}" for k in v) + ".",
        "Shared, noisy machines: compare the figures within this file (each stands beside its baseline,",
        "measured in the same run), not across runs. How to read them: `docs/benchmarks.md`.",
        "",
    ]
    body = []
    if "speed" in results:
        body += ["## Speed", "", speed_markdown(results["speed"]), ""]
    if "loop" in results:
        from bench import loop

        body += [loop.markdown(results["loop"]), ""]
    if "tracking" in results:
        body += ["## Tracking", "", tracking_markdown(results["tracking"]), ""]
    if "design" in results:
        from bench import design

        body += [design.markdown(results["design"]), ""]
    if "sweep" in results:
        from bench import sweep

        body += [sweep.markdown(results["sweep"]), ""]
    if "faults" in results:
        from bench import faults

        body += [faults.markdown(results["faults"]), ""]
    output.write_text("\n".join(head + body).rstrip() + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench/run.py", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    parser.add_argument("--output", type=Path, default=ROOT / "bench" / "RESULTS.md", help="markdown report")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: checks the harness, not the speed")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="processes for the tracking flights")
    parser.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts among {', '.join(PARTS)}")
    args = parser.parse_args(argv)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        parser.error(f"--only: unknown part {unknown[0]!r}; expected some of {', '.join(PARTS)}")
    if args.workers < 1:
        parser.error(f"--workers must be at least 1, got {args.workers}")
    output = args.output.resolve()
    output.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    results: dict = {"machine": machine(), "quick": args.quick}
    if "speed" in parts:
        results["speed"] = measure_speed(args.quick)
    if "loop" in parts:
        results["loop"] = measure_loop(args.quick)
    if "tracking" in parts:
        results["tracking"] = measure_tracking(args.quick, args.workers, output.parent / "img")
    if "design" in parts:
        results["design"] = measure_design(args.quick)
    if "sweep" in parts:
        results["sweep"] = measure_sweep(args.quick)
    if "faults" in parts:
        results["faults"] = measure_faults(args.quick)
    results["wall_s"] = time.perf_counter() - start
    command = "make bench" if output == (ROOT / "bench" / "RESULTS.md") and not args.quick and len(parts) == len(PARTS) \
        else "python bench/run.py " + " ".join(argv if argv is not None else sys.argv[1:])  # fmt: skip
    (output.parent / "results.json").write_text(jsonout.dumps(results, indent=1, default=str))  # strict: no NaN
    write(results, output, command)
    _say(f"wrote {output} ({results['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
