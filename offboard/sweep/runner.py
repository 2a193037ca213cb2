"""Running a sweep's flights on Dask, rows streamed to Parquet.

Flights are cut into chunks of consecutive indices (``flights_per_task``, by default sized to
about 0.8 s of work: Dask's own guidance is ~1 ms of overhead a task, so tasks of 0.1-1 s
keep it under 1 %); each chunk is one task, flown by ``fly_chunk`` on a worker, which returns its
rows as Parquet columns. The client writes each chunk as a row group of ``flights.parquet`` as it arrives,
and keeps no more than a few tasks per worker in flight, so the memory stays flat in the number
of flights. A flight depends only on the sweep and its index (``spec.flight``), so the rows are
the same on one worker or fifty and in any chunking; they arrive in completion order (the
``flight`` column says which is which).

The cluster: by default a ``distributed.LocalCluster`` of the machine's cores (one process a
core, one thread each: the kernels hold the GIL); ``scheduler="tcp://HOST:8786"`` joins any
running Dask scheduler (``dask scheduler`` / ``dask worker``, dask-jobqueue, Kubernetes), whose
workers must have this project installed, at the same version.
"""

from __future__ import annotations

import enum
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from offboard.sweep.flight import phase_columns
from offboard.sweep.spec import PARAMETERS, ParameterKind, SweepSpec, flights


class SweepEngine(enum.StrEnum):
    """How a task flies its flights: ``batch`` (stepped together, ``offboard.sweep.batch``) or
    ``one`` (``offboard.inprocess.simulate`` per flight, the reference)."""

    BATCH = "batch"
    ONE = "one"


ENGINES = tuple(e.value for e in SweepEngine)
#: The work a task aims at (s): inside Dask's 0.1-1 s guidance.
TASK_TARGET_S = 0.8
#: At most this share of a batched task goes to its fixed part (the law's numpy calls per sample).
FIXED_SHARE = 0.25
#: Tasks kept in flight per worker (the rest wait in the client, not in memory on the cluster).
TASKS_PER_WORKER = 3
METRIC_COLUMNS_TAIL = ("final_error_m", "peak_tilt_deg", "peak_thrust_n", "flown_s", "status", "detail", "converge_s")


def columns(spec: SweepSpec) -> list[tuple[str, str]]:
    """The Parquet columns (name, ``float``/``string``/``int``) of a sweep's rows, in order."""
    cols = [("flight", "int"), ("seed", "int")]
    cols += [(d.name, "string" if PARAMETERS[d.name].kind is ParameterKind.SPEC else "float") for d in spec.parameters]
    cols += [(c, "float") for c in phase_columns(spec.base.trajectory.phases(), spec.base.flight_duration_s)]
    cols += [(c, "string" if c in ("status", "detail") else "float") for c in METRIC_COLUMNS_TAIL]
    return cols


def fly_chunk(spec: SweepSpec, start: int, stop: int, engine: SweepEngine | str = SweepEngine.BATCH) -> list[dict]:
    """Flights ``start`` to ``stop`` of ``spec``: one row each (what a Dask task runs)."""
    fls = flights(spec, start, stop)
    _one_thread_per_worker()
    if SweepEngine(engine) is SweepEngine.BATCH:
        from offboard.sweep.batch import fly_batch

        rows = fly_batch(spec, fls)
    else:
        from offboard.sweep.flight import fly_one

        rows = [fly_one(spec, fl)[0] for fl in fls]
    for fl, row in zip(fls, rows):
        row.update({"flight": fl.index, "seed": fl.seed, **fl.values})
    return rows


def _one_thread_per_worker() -> None:
    """In a Dask worker, numba's kernels use the worker's threads only: the cluster already runs
    a worker per core, and numba's own pool on top would oversubscribe them."""
    try:
        from distributed import get_worker

        threads = get_worker().state.nthreads
    except (ImportError, ValueError, AttributeError):
        return
    from sitl_plant.dynamics.batch import NUMBA

    if NUMBA:
        import numba

        numba.set_num_threads(max(1, min(threads, int(getattr(numba.config, "NUMBA_NUM_THREADS")))))  # set at import


def local_cluster(workers: int | None):  # noqa: ANN201  (distributed's LocalCluster, imported late)
    """A Dask cluster of ``workers`` processes (default: one per core) of one thread each, on
    loopback, its dashboard on a free port."""
    from distributed import LocalCluster

    return LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                        dashboard_address=":0", host="127.0.0.1")  # fmt: skip


def _warm_up(spec: SweepSpec, engine: SweepEngine) -> None:
    """On a worker: one flight of 0.1 s, so that its imports and compiled kernels
    are loaded (a second or more) before its first task."""
    from dataclasses import replace

    fly_chunk(replace(spec, base=replace(spec.base, duration_s=0.1)), 0, 1, engine)


def row_columns(rows: list[dict], cols: list[tuple[str, str]]) -> dict[str, list | np.ndarray]:
    """``rows`` as the columns of ``cols`` (``columns``): floats as one float64 array each (a
    missing value NaN), integers and strings as lists."""
    out: dict[str, list | np.ndarray] = {}
    for name, kind in cols:
        values = [r.get(name) for r in rows]
        out[name] = np.array([math.nan if v is None else float(v) for v in values]) if kind == "float" else values
    return out


def _task(spec: SweepSpec, start: int, stop: int, engine: SweepEngine) -> tuple[dict[str, list | np.ndarray], int, float]:
    """A Dask task: ``fly_chunk``'s rows as Parquet columns, their number, and the seconds it took
    on the worker. The worker builds the columns: the client, which shares a machine's cores
    with the workers of a local cluster, only writes them (and a task's pickle is a few arrays,
    not a dict per flight)."""
    started = time.perf_counter()
    rows = fly_chunk(spec, start, stop, engine)
    return row_columns(rows, columns(spec)), len(rows), time.perf_counter() - started


def chunks(total: int, size: int) -> Iterator[tuple[int, int]]:
    """(start, end) of consecutive slices of ``range(total)``, ``size`` long (the last one shorter)."""
    for start in range(0, total, size):
        yield start, min(start + size, total)


def estimate_flights_per_task(spec: SweepSpec, engine: SweepEngine) -> int:
    """Flights a task of ``TASK_TARGET_S`` holds, from timing a few short flights here (which also
    loads the compiled kernels before the workers need them).

    A batch costs a fixed part per sample (the law's numpy calls) and a part per flight (the
    physics): both are measured, on 8 and on 128 flights of half a second, and scaled to the
    flight's duration. Where the fixed part alone nears the target (long flights), the task
    holds enough flights for the fixed part to stay within ``FIXED_SHARE`` of it."""
    if engine is SweepEngine.ONE:
        return 1  # a one-vehicle flight is seconds of work already
    from dataclasses import replace

    duration = spec.base.flight_duration_s
    probe_s = min(0.5, duration)
    probe = replace(spec, base=replace(spec.base, duration_s=probe_s))
    small, large = min(spec.flights, 8), min(spec.flights, 128)
    fly_chunk(probe, 0, 1, engine)  # warm-up: imports, kernels
    timings = []
    for n in (small, large):
        started = time.perf_counter()
        fly_chunk(probe, 0, n, engine)
        timings.append((time.perf_counter() - started) * duration / probe_s)
    per_flight = (timings[1] - timings[0]) / (large - small) if large > small else timings[0] / small
    fixed = max(0.0, timings[0] - small * per_flight)
    if per_flight <= 0:
        return spec.flights
    # fill the task to TASK_TARGET_S, but give the flights at least FIXED_SHARE of it beside the
    # fixed part (a long flight's fixed part alone can be near the target: then the task is longer)
    fill = max((TASK_TARGET_S - fixed) / per_flight, fixed * (1 - FIXED_SHARE) / FIXED_SHARE / per_flight)
    return max(1, min(spec.flights, int(fill)))


@dataclass
class SweepRun:
    """What a sweep run did (its rows are in ``parquet``)."""

    parquet: Path
    flights: int
    tasks: int
    flights_per_task: int
    workers: int
    wall_s: float
    scheduler: str
    compute_s: float = 0.0  # the tasks' own time on the workers, summed
    startup_s: float = 0.0  # of wall_s: sizing the tasks, starting the cluster, loading every worker's kernels

    @property
    def flying_s(self) -> float:
        """Wall time from the first task to the last row written (``wall_s`` less ``startup_s``)."""
        return self.wall_s - self.startup_s

    @property
    def overhead_per_flight_s(self) -> float:
        """Worker time not spent flying, per flight: cluster start, scheduling, transfers, Parquet."""
        return max(0.0, self.wall_s * self.workers - self.compute_s) / self.flights if self.flights else math.nan


class ParquetRows:
    """Rows appended as row groups of one Parquet file, with a schema fixed up front."""

    def __init__(self, path: Path, cols: list[tuple[str, str]]) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        types = {"int": pa.int64(), "float": pa.float64(), "string": pa.string()}
        self._pa = pa
        self.cols = cols
        self.schema = pa.schema([(name, types[kind]) for name, kind in cols])
        self.writer = pq.ParquetWriter(path, self.schema)
        self.rows = 0

    def write(self, columns: dict[str, list | np.ndarray], count: int) -> None:
        """``count`` rows given as columns (``row_columns``), as one row group."""
        self.writer.write_table(self._pa.Table.from_pydict(columns, schema=self.schema))
        self.rows += count

    def close(self) -> None:
        """Close the Parquet file (its footer written)."""
        self.writer.close()


def run_sweep(
    spec: SweepSpec,
    run_dir: Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    engine: SweepEngine | str = SweepEngine.BATCH,
    flights_per_task: int | None = None,
    limit: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> SweepRun:
    """Fly the sweep's flights on Dask into ``run_dir/flights.parquet`` (module docstring).

    Parameters
    ----------
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a running Dask scheduler; None starts a local cluster.
    workers : int, optional
        The local cluster's worker processes (default: the machine's cores).
    engine : SweepEngine or str
        ``batch`` (N flights stepped together, ``offboard.sweep.batch``) or ``one``
        (``simulate`` per flight, the reference).
    flights_per_task : int, optional
        Chunk size; by default about ``TASK_TARGET_S`` of work (``estimate_flights_per_task``).
    limit : int, optional
        Fly only the first ``limit`` flights.
    progress : callable, optional
        Called with (flights done, flights in all, seconds since the start) after each task.
    """
    from distributed import Client, as_completed

    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    engine = SweepEngine(engine)
    total = spec.flights if limit is None else max(0, min(limit, spec.flights))
    started = time.perf_counter()
    if flights_per_task is None:
        size = estimate_flights_per_task(spec, engine)  # which compiles or loads the kernels here too
    else:
        size = flights_per_task
        _warm_up(spec, engine)  # compiled here once, into numba's cache: a local cluster's workers load them, not each compile them
    if flights_per_task is None and scheduler is None:  # at least TASKS_PER_WORKER + 1 tasks a worker: no worker idles
        size = max(1, min(size, -(-total // ((TASKS_PER_WORKER + 1) * (workers or os.cpu_count() or 1)))))
    cluster = None
    if scheduler is None:
        cluster = local_cluster(workers)
    out = ParquetRows(run_dir / "flights.parquet", columns(spec))
    tasks = 0
    try:
        with Client(cluster if cluster is not None else scheduler) as client:
            n_workers = max(1, len(client.scheduler_info().get("workers", {})))
            spec_future = client.scatter(spec, broadcast=True)
            client.run(_warm_up, spec, engine)  # every worker loads its kernels before the clock of the flights starts
            ready = time.perf_counter()
            pending = chunks(total, size)
            window = as_completed()
            for start, stop in pending:
                window.add(client.submit(_task, spec_future, start, stop, engine, pure=False))
                tasks += 1
                if window.count() >= TASKS_PER_WORKER * n_workers:
                    break
            done = 0
            compute_s = 0.0
            for future in window:
                cols, count, seconds = future.result()
                compute_s += seconds
                future.release()
                out.write(cols, count)
                done += count
                if progress is not None:
                    progress(done, total, time.perf_counter() - started)
                nxt = next(pending, None)
                if nxt is not None:
                    window.add(client.submit(_task, spec_future, nxt[0], nxt[1], engine, pure=False))
                    tasks += 1
            address = client.scheduler.address
    finally:
        out.close()
        if cluster is not None:
            cluster.close()
    return SweepRun(run_dir / "flights.parquet", out.rows, tasks, size, n_workers, time.perf_counter() - started,
                    "local" if cluster is not None else str(address), compute_s, ready - started)  # fmt: skip
