"""The sweep benchmark (issue 15): Table II flights of the paper helix, batched on Dask, against
``offboard simulate``'s loop in the same run.

- **one at a time**: ``simulate()`` per flight (what ``offboard simulate`` runs; ``fly_one``),
  a few flights of the same sweep, as flights per second;
- **the sweep**: ``run_sweep`` with the batched engine on a local cluster of 2 workers, 10 000
  flights of 12 s (rigid body, 1 kHz RK4, 20 Hz law): wall time, flights per second, the ratio to
  one at a time, the workers' time not spent flying per flight (scheduler overhead), the client's
  memory (RSS) when 2 000 flights are done and when all are, and the growth between (flat: rows
  are streamed to Parquet), and its peak;
- **scaling**: the same spec, in the same tasks, on 1 worker against the sweep's 2 (issue 15's
  target compares the two on the same spec; a smaller spec would mostly time the start-up);
- **the machine's ceiling**: the same flights flown by plain processes with no Dask, one alone,
  then two at once (one numba thread each, as the workers): what two independent processes gain
  on this machine's cores, against which the 2-worker figure can be read. On a machine whose two
  cores do not run two processes at twice the rate of one, no scheduler can.

    python bench/sweep.py [--flights 10000] [--quick]
    python bench/sweep.py --chunk START STOP [--flight-s S]   (one ceiling process; prints its seconds)
"""

from __future__ import annotations

import math
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from offboard import jsonout  # noqa: E402

SPEC = ROOT / "missions" / "sweep-table2.toml"
# (full, quick)
SIZES = {"flights": (10_000, 8), "one_at_a_time": (3, 1), "duration_s": (12.0, 0.3),
         "workers": (2, 1), "flights_per_task": (None, 4), "rss_mark": (2_000, 4)}


def _size(key: str, quick: bool):  # noqa: ANN202
    return SIZES[key][1 if quick else 0]


def _rss_mib() -> float:
    """This process's resident memory now (MiB)."""
    import psutil  # a dependency of distributed

    return psutil.Process().memory_info().rss / 2**20


def _spec(duration_s: float, flights: int):  # noqa: ANN202
    from offboard.sweep.spec import load_sweep

    spec = load_sweep(SPEC)
    return replace(spec, base=replace(spec.base, duration_s=duration_s), flights=max(flights, spec.flights))


def fly_chunk_timed(start: int, stop: int, duration_s: float) -> float:
    """In a ceiling process: flights ``start`` to ``stop`` flown as one Dask task flies them (the
    batched engine, one numba thread), after a warm-up that loads the kernels; their seconds."""
    from offboard.sweep.runner import fly_chunk
    from sitl_plant.dynamics.batch import NUMBA

    if NUMBA:
        import numba

        numba.set_num_threads(1)  # as _one_thread_per_worker does on a 1-thread worker
    spec = _spec(duration_s, stop)
    fly_chunk(replace(spec, base=replace(spec.base, duration_s=0.1)), 0, 1)
    started = time.perf_counter()
    fly_chunk(spec, start, stop)
    return time.perf_counter() - started


def ceiling(flights: int, duration_s: float, repeats: int = 2) -> dict:
    """What two plain processes gain over one on this machine: ``flights`` flown by one process
    alone, then the same number by each of two processes started together (each its own flights),
    ``repeats`` times, the best of each kept. Throughput ratio = 2 x (alone s) / (the slower of the
    pair's s)."""

    def start(first: int) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--chunk", str(first), str(first + flights),
                                 "--flight-s", repr(duration_s)], stdout=subprocess.PIPE, text=True)  # fmt: skip

    def seconds(process: subprocess.Popen) -> float:
        out, _ = process.communicate(timeout=1800)
        if process.returncode != 0:
            raise RuntimeError(f"a ceiling process exited {process.returncode}")
        return float(out.split()[-1])

    alone, both = math.inf, [math.inf, math.inf]
    for k in range(repeats):  # the best of each: the machine's ceiling, not its noise
        alone = min(alone, seconds(start(0)))
        pair = [start((2 * k + 1) * flights), start((2 * k + 2) * flights)]
        this = [seconds(p) for p in pair]
        if max(this) < max(both):
            both = this
    return {"flights": flights, "repeats": repeats, "alone_s": alone, "pair_s": both, "speedup": 2 * alone / max(both)}


def measure(quick: bool = False, flights: int | None = None, say=lambda text: None) -> dict:  # noqa: ANN001
    from offboard.sweep.flight import fly_one
    from offboard.sweep.runner import run_sweep
    from offboard.sweep.spec import flight
    from sitl_plant.dynamics.batch import NUMBA

    duration = _size("duration_s", quick)
    n = flights or _size("flights", quick)
    spec = _spec(duration, n)
    out: dict = {"spec": SPEC.name, "flight_s": duration, "numba": NUMBA}

    k = _size("one_at_a_time", quick)
    say(f"sweep: {k} flights one at a time (simulate)")
    started = time.perf_counter()
    for i in range(k):
        fly_one(spec, flight(spec, i))
    one_s = (time.perf_counter() - started) / k
    out["one_at_a_time"] = {"flights": k, "s_per_flight": one_s, "flights_per_s": 1.0 / one_s}

    def sweep(count: int, workers: int, size: int | None = None, rss: dict | None = None) -> dict:
        def progress(done: int, total: int, elapsed_s: float) -> None:  # the client's RSS as flights come in
            if rss is not None:
                for mark in rss:
                    if rss[mark] is None and done >= mark:
                        rss[mark] = _rss_mib()

        with tempfile.TemporaryDirectory() as tmp:
            run = run_sweep(spec, Path(tmp), workers=workers, limit=count, flights_per_task=size or _size("flights_per_task", quick),
                            progress=progress)  # fmt: skip
        return {"flights": run.flights, "workers": run.workers, "tasks": run.tasks, "flights_per_task": run.flights_per_task,
                "wall_s": run.wall_s, "flights_per_s": run.flights / run.wall_s, "compute_s": run.compute_s,
                "overhead_per_flight_s": run.overhead_per_flight_s, "startup_s": run.startup_s,
                "flying_flights_per_s": run.flights / run.flying_s}  # fmt: skip

    workers = _size("workers", quick)
    say(f"sweep: {n} flights of {duration:g} s, batched, on a local cluster of {workers} workers")
    marks: dict = {min(_size("rss_mark", quick), n): None, n: None}
    out["sweep"] = sweep(n, workers, rss=marks)
    (early, early_mib), (late, late_mib) = sorted(marks.items())
    out["client_rss_mib"] = {"at_flights": [early, late], "mib": [early_mib, late_mib], "growth_mib": late_mib - early_mib}
    out["sweep"]["speedup_vs_one_at_a_time"] = out["sweep"]["flights_per_s"] / out["one_at_a_time"]["flights_per_s"]
    out["client_peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if workers > 1:  # the same flights in the same tasks on one worker: only the workers differ
        size = out["sweep"]["flights_per_task"]
        say(f"sweep: the same {n} flights on 1 worker, in tasks of {size}")
        one, two = sweep(n, 1, size), out["sweep"]
        out["scaling"] = {"one_worker": one, "two_workers": two, "speedup": two["flights_per_s"] / one["flights_per_s"],
                          "flying_speedup": two["flying_flights_per_s"] / one["flying_flights_per_s"]}  # fmt: skip
    count = 8 * out["sweep"]["flights_per_task"]  # a few tasks' worth: long enough to time, short beside the sweep
    say(f"sweep: the machine's ceiling, {count} flights in one process alone, then in each of two at once")
    out["ceiling"] = ceiling(count, duration, repeats=1 if quick else 2)
    return out


def markdown(r: dict) -> str:
    one, s = r["one_at_a_time"], r["sweep"]
    lines = [
        "## Sweep (issue 15)",
        "",
        f"`{r['spec']}`: Table II-style beliefs, flights of {r['flight_s']:g} s of the paper helix (rigid body, 1 kHz RK4, "
        f"20 Hz law); batched engine {'compiled (numba)' if r['numba'] else 'interpreted (no numba)'}.",
        "",
        "| run | flights | workers | tasks x flights | wall s | flights/s | vs one at a time | overhead ms/flight |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        f"| `simulate()` one at a time | {one['flights']} | 1 | - | {one['s_per_flight'] * one['flights']:.1f} | "
        f"{one['flights_per_s']:.3g} | 1× | - |",
        f"| sweep, batched, local cluster | {s['flights']} | {s['workers']} | {s['tasks']} x {s['flights_per_task']} | "
        f"{s['wall_s']:.1f} | {s['flights_per_s']:.3g} | {s['speedup_vs_one_at_a_time']:.3g}× | "
        f"{1e3 * s['overhead_per_flight_s']:.2f} |",
    ]
    tail = [f"The sweep's wall time includes {s['startup_s']:.1f} s of start-up (tasks sized, cluster started, kernels loaded)."]
    sc = r.get("scaling")
    if sc:
        for label, run in (("the same sweep on 1 worker", sc["one_worker"]),):
            lines.append(f"| {label} | {run['flights']} | {run['workers']} | {run['tasks']} x {run['flights_per_task']} | "
                         f"{run['wall_s']:.1f} | {run['flights_per_s']:.3g} | - | {1e3 * run['overhead_per_flight_s']:.2f} |")  # fmt: skip
        lines += ["", f"2 workers against 1: {sc['speedup']:.2f}× in wall time; {sc['flying_speedup']:.2f}× from the first task "
                  f"to the last row (start-up, the cluster and every worker's kernels loaded: "
                  f"{sc['one_worker']['startup_s']:.1f} s on 1 worker, {sc['two_workers']['startup_s']:.1f} s on 2)."]  # fmt: skip
    c = r.get("ceiling")
    if c:
        lines += ["", f"The machine's ceiling: {c['flights']} of the same flights in plain processes (no Dask, one numba "
                  f"thread each) took {c['alone_s']:.2f} s alone and {c['pair_s'][0]:.2f} s / {c['pair_s'][1]:.2f} s for "
                  f"two at once (the best of {c['repeats']} runs each): two processes fly {c['speedup']:.2f}× one on this machine's cores."]  # fmt: skip
        if sc:
            lines[-1] += (f" The 2-worker sweep's {sc['flying_speedup']:.2f}× is {sc['flying_speedup'] / c['speedup']:.0%} "
                          "of that; issue 15's 1.8× target is out of reach of any scheduler where the ceiling is below it.")
    m = r["client_rss_mib"]
    lines += ["", *tail]
    lines += ["", f"Client memory (RSS) at {m['at_flights'][0]} flights done: {m['mib'][0]:.0f} MiB; at {m['at_flights'][1]}: "
              f"{m['mib'][1]:.0f} MiB; growth {m['growth_mib']:+.1f} MiB (rows go to Parquet as they arrive). Peak through "
              f"the sweep: {r['client_peak_rss_mib']:.0f} MiB."]  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(prog="bench/sweep.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", type=int, default=None)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--chunk", type=int, nargs=2, metavar=("START", "STOP"), help="fly these flights, print the seconds")
    parser.add_argument("--flight-s", type=float, default=12.0)
    args = parser.parse_args()
    if args.chunk:
        print(f"{fly_chunk_timed(args.chunk[0], args.chunk[1], args.flight_s):.6f}")
        sys.exit(0)
    result = measure(args.quick, args.flights, say=lambda text: print(text, file=sys.stderr, flush=True))
    print(jsonout.dumps(result, indent=1))
    print(markdown(result))
