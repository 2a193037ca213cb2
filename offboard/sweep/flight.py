"""One flight of a sweep on the one-vehicle path, and the row of figures every flight gives.

``fly_one`` flies a flight by ``offboard.inprocess.simulate`` (what ``offboard simulate`` runs:
the reference the batched engine is held to). ``row_of`` turns a flight's series (the true
position, the reference, the attitude and the thrust at each control sample) into the row a
sweep writes: the same function for both engines, so their rows compare column for column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from offboard.controller.paper import PaperController
from offboard.inprocess import simulate
from offboard.metrics import LOST_TRACK_M, LOST_TRACK_WINDOW_S, SETTLE_S, flown_end_s
from offboard.record import FlightStatus
from offboard.sweep.spec import FlightSpec, SweepSpec, scenario_of
from offboard.trajectory.base import Phase
from sitl_plant.dynamics.sensors import sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec

#: A flight's status in its row: flown to its end and on track, lost (diverged, a non-finite
#: command, or flown to its end more than ``metrics.LOST_TRACK_M`` off), or on the ground again
#: while its reference is in the air.
STATUSES = ("complete", "diverged", "crashed")
#: Crashed: back within this of the ground (m) after having risen above ``LIFTED_M`` while the
#: reference is higher than ``LIFTED_M``.
GROUND_M = 0.01
LIFTED_M = 0.2


@dataclass(frozen=True)
class Series:
    """What a flight's row is computed from: one entry per control sample flown."""

    t_s: np.ndarray  # (n,)
    pos_ned_m: np.ndarray  # (n, 3), the truth
    ref_pos_ned_m: np.ndarray  # (n, 3)
    euler_rad: np.ndarray  # (n, 3), the truth
    thrust_n: np.ndarray  # (n,)
    status: FlightStatus
    detail: str = ""


def flown_phases(phases: list[Phase], duration_s: float) -> list[Phase]:
    """The mission's phases a flight of ``duration_s`` flies: those that begin before its last
    sample (``offboard simulate``'s table lists the same; a phase that begins at the last sample,
    as the paper helix's hold after a 12 s scenario, is not flown)."""
    return [p for p in phases if p.start_s < duration_s - 1e-9]


def phase_columns(phases: list[Phase], duration_s: float) -> list[str]:
    """The per-phase columns of a row, in order (the same for every flight of a sweep): the
    whole flight, after 5 s and each phase flown in ``duration_s`` (``flown_phases``)."""
    names = ["whole", "after_5s", *(p.name for p in flown_phases(phases, duration_s))]
    return [f"{kind}_{name}_m" for name in names for kind in ("rms", "max")]


def row_of(series: Series, phases: list[Phase], duration_s: float, converged_m: float) -> dict[str, float | str]:
    """The figures of one flight (module docstring) of a scenario of ``duration_s`` over a mission
    of ``phases``: per-phase RMS and max of the 3D error (``phase_columns``), the final error,
    peak tilt and thrust, status and the time to converge (of a complete flight: the first sample
    within ``converged_m`` of the reference; NaN if none is). A last sample at the start of a
    phase not flown reads that phase's first reference, a step the flight never flew
    (``metrics.flown_end_s``): no span counts it and the final error is the sample's before."""
    t = series.t_s
    err = np.linalg.norm(series.ref_pos_ned_m - series.pos_ned_m, axis=1) if len(t) else np.zeros(0)
    row: dict[str, float | str] = {}
    end = flown_end_s(float(t[-1]), phases) if len(t) else 0.0
    spans = [("whole", 0.0, end), ("after_5s", SETTLE_S, end),
             *((p.name, p.start_s, p.end_s) for p in flown_phases(phases, duration_s))]  # fmt: skip
    for name, a, b in spans:
        mask = (t >= a) & (t < b) if math.isfinite(b) else t >= a
        e = err[mask]
        row[f"rms_{name}_m"] = float(np.sqrt(np.mean(e**2))) if len(e) else math.nan
        row[f"max_{name}_m"] = float(np.max(e)) if len(e) else math.nan
    flown = err[t < end]
    row["final_error_m"] = float(flown[-1]) if len(flown) else math.nan
    euler = series.euler_rad
    tilt = np.degrees(np.arccos(np.clip(np.cos(euler[:, 0]) * np.cos(euler[:, 1]), -1, 1))) if len(t) else np.zeros(0)
    row["peak_tilt_deg"] = float(np.max(tilt)) if len(tilt) else math.nan
    row["peak_thrust_n"] = float(np.max(series.thrust_n)) if len(t) else math.nan
    row["flown_s"] = float(t[-1]) if len(t) else 0.0
    status, detail = "complete", series.detail
    tail = err[t >= t[-1] - LOST_TRACK_WINDOW_S] if len(t) else err
    if series.status is not FlightStatus.COMPLETE:
        status = "diverged"
    elif len(tail) and float(np.min(tail)) > LOST_TRACK_M:  # metrics.check_tracking's LOST_TRACK
        status, detail = "diverged", f"flown to its end but {float(np.min(tail)):.1f} m from the reference"
    else:
        altitude, ref_altitude = -series.pos_ned_m[:, 2], -series.ref_pos_ned_m[:, 2]
        lifted = np.maximum.accumulate(altitude) > LIFTED_M
        down = lifted & (altitude <= GROUND_M) & (ref_altitude > LIFTED_M)
        if np.any(down):
            status, detail = "crashed", f"on the ground at t = {float(t[np.argmax(down)]):.2f} s with the reference in the air"
    row["status"] = status
    row["detail"] = detail
    converged = math.nan
    if status == "complete" and len(err):
        within = np.nonzero(err < converged_m)[0]
        if len(within):
            converged = float(t[within[0]])
    row["converge_s"] = converged
    return row


def series_of_record(record) -> Series:  # noqa: ANN001 - a FlightRecord
    """The ``Series`` (time, position, reference, attitude, thrust, status) of a flight's record."""
    return Series(record["t_s"], record["pos_ned_m"], record["ref_pos_ned_m"], record["euler_rad"], record["thrust_n"],
                  record.status, record.status_detail)  # fmt: skip


def fly_one(spec: SweepSpec, fl: FlightSpec, *, fast: bool = False) -> tuple[dict[str, float | str], object]:
    """Flight ``fl`` by ``simulate`` (the paper's controller, the scenario's drive and model):
    its row of figures and its ``FlightResult``."""
    setup = scenario_of(spec, fl)
    sc = setup.scenario
    controller = PaperController(sc.controller, vehicle_model=sc.model)
    result = simulate(
        sc.vehicle, controller, sc.trajectory, drive=sc.drive, model=sc.model, physics_dt_s=sc.physics_dt_s,
        duration_s=sc.flight_duration_s, sensors=sensors_from_spec(sc.sensors, sc.seed),
        wind=None if sc.wind == "none" else wind_from_spec(sc.wind, sc.seed), ground=sc.ground,
        initial_pos_ned_m=sc.initial_pos_ned_m, initial_yaw_rad=sc.initial_yaw_rad, latency_s=setup.latency_s,
        fast=fast and sc.model == "rigid-body",
    )  # fmt: skip
    return row_of(series_of_record(result.record), sc.trajectory.phases(), sc.flight_duration_s, spec.converged_m), result
