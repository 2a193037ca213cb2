"""``offboard tune --search``: the designs near the analytic one, flown on a sweep's flights.

The analytic design (``offboard.controller.design``) picks the fastest loop that keeps the stated
margins on a linear model. This search flies what the model leaves out: the sweep's flights
(its mission, its drawn beliefs, wind, sensors, start) of the tuned vehicle through PX4's
attitude loop (the ``px4`` drive, the loop the design models), once for each design of
``nearby_designs`` (every one keeps the margins), on the sweep engine (Dask; the same flights,
seeds included, for every design), and keeps the design whose median RMS error over the flights
is lowest among those that complete every flight.

The error is the 3D RMS after the first 5 s (``rms_after_5s_m``, the start's transient left
out), or over the whole flight when a flight is no longer than that.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from offboard.controller.design import Design
from offboard.controller.params import ControllerParams
from offboard.metrics import SETTLE_S
from offboard.inprocess import Drive
from offboard.model.vehicle import VehicleModel, VehicleParams
from offboard.sweep.runner import local_cluster, run_sweep
from offboard.sweep.spec import Distribution, DistributionKind, SweepSpec

#: What a sweep may not vary for a search: what the search itself chooses.
CHOSEN = ("controller.gains.", "controller.tilt_lead", "controller.velocity_integral", "controller.vertical_velocity_integral",
          "controller.integral_gain_per_s",
          "controller.sample_time_s", "controller.velocity_from_position_s")  # fmt: skip


@dataclass(frozen=True)
class Trial:
    """One design flown on the sweep's flights.

    Attributes
    ----------
    design : Design
    params : ControllerParams
        The controller file it writes.
    flights, complete : int
        Flights flown; those that completed (neither diverged nor crashed).
    median_rms_m, p90_rms_m : float
        Median and 90th percentile of the flights' RMS error (NaN when none completed).
    run_dir : Path
        Its flights.parquet.
    """

    design: Design
    params: ControllerParams
    flights: int
    complete: int
    median_rms_m: float
    p90_rms_m: float
    run_dir: Path

    @property
    def all_complete(self) -> bool:
        """Whether every flight of the trial completed."""
        return self.complete == self.flights


def check_sweep(spec: SweepSpec) -> None:
    """Raise ValueError naming a swept parameter the search chooses itself."""
    for d in spec.parameters:
        if d.name.startswith(CHOSEN):
            raise ValueError(f"{spec.source or spec.name}: sweeps {d.name}, which the search chooses")


def error_column(spec: SweepSpec) -> str:
    """The row column the search compares (module docstring)."""
    return "rms_after_5s_m" if spec.base.flight_duration_s > SETTLE_S else "rms_whole_m"


def search_spec(spec: SweepSpec, vehicle: VehicleParams, params: ControllerParams, latency_s: float) -> SweepSpec:
    """The sweep flown for one design: its scenario flying ``vehicle`` through PX4's attitude loop
    with ``params``, and the design's latency where the sweep does not draw one."""
    base = replace(spec.base, vehicle=vehicle, controller=params, drive=Drive.PX4, model=VehicleModel.RIGID_BODY)
    parameters = spec.parameters
    if latency_s > 0.0 and not any(d.name == "latency_s" for d in parameters):
        parameters = (*parameters, Distribution("latency_s", DistributionKind.FIXED, (latency_s,)))
    return replace(spec, base=base, parameters=parameters)


def search(
    designs: list[Design],
    params_of: Callable[[Design], ControllerParams],
    spec: SweepSpec,
    vehicle: VehicleParams,
    run_dir: Path,
    *,
    flights: int,
    latency_s: float = 0.0,
    scheduler: str | None = None,
    workers: int | None = None,
    say: Callable[[str], None] = lambda text: None,
) -> list[Trial]:
    """Fly ``flights`` of ``spec`` for every design (module docstring); the trials in order."""

    check_sweep(spec)
    flights = max(1, min(flights, spec.flights))
    column = error_column(spec)
    cluster = None
    if scheduler is None:
        cluster = local_cluster(workers)
        scheduler = cluster.scheduler_address
    trials: list[Trial] = []
    try:
        for k, design in enumerate(designs):
            params = params_of(design)
            folder = run_dir / f"design-{k}"
            folder.mkdir(parents=True, exist_ok=True)
            run = run_sweep(search_spec(spec, vehicle, params, latency_s), folder, scheduler=scheduler, limit=flights,
                            flights_per_task=max(1, math.ceil(flights / (2 * (workers or os.cpu_count() or 1)))))  # fmt: skip
            trial = _trial(design, params, run.parquet, column, folder)
            trials.append(trial)
            say(f"design {k}: {trial.complete} of {trial.flights} complete, median RMS {trial.median_rms_m:.4f} m, "
                f"p90 {trial.p90_rms_m:.4f} m")  # fmt: skip
    finally:
        if cluster is not None:
            cluster.close()
    return trials


def _trial(design: Design, params: ControllerParams, parquet: Path, column: str, folder: Path) -> Trial:
    import pyarrow.parquet as pq

    table = pq.read_table(parquet, columns=["status", column]).to_pydict()
    complete = [float(e) for s, e in zip(table["status"], table[column]) if s == "complete"]
    errors = np.array([e for e in complete if math.isfinite(e)])
    median = float(np.median(errors)) if len(errors) else math.nan
    p90 = float(np.percentile(errors, 90)) if len(errors) else math.nan
    return Trial(design, params, len(table["status"]), len(complete), median, p90, folder)


def best(trials: list[Trial]) -> Trial | None:
    """The trial with the lowest median error of those that completed every flight (None if none did)."""
    ok = [t for t in trials if t.all_complete and math.isfinite(t.median_rms_m)]
    return min(ok, key=lambda t: t.median_rms_m) if ok else None
