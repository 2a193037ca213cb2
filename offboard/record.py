"""A flight as aligned time series, whatever produced it (in-process run, MAVLink flight, replay).

Metrics (``offboard.metrics``) and figures (``offboard.plots``) take a ``FlightRecord``, so the
same table and the same plots describe a simulation, a live flight and a replayed log.
"""

from __future__ import annotations

import csv
import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from offboard.trajectory.base import Phase, Reference

if TYPE_CHECKING:
    from offboard.controller.law import ControlOutput


class FlightStatus(enum.Enum):
    """How a flight ended (exit codes of ``offboard fly``/``simulate`` follow ``exit_code``)."""

    COMPLETE = "complete"
    DIVERGED = "diverged"  # state non-finite or tilt past 90 degrees
    NAN_COMMAND = "nan_command"  # the controller produced a NaN/inf action; never sent
    LINK_LOST = "link_lost"
    FAILSAFE = "failsafe"  # the vehicle left OFFBOARD on its own
    MODE_CHANGED = "mode_changed"  # someone else took the vehicle out of OFFBOARD
    REJECTED = "rejected"  # a command was refused
    INTERRUPTED = "interrupted"  # Ctrl-C: landed and disarmed on request

    @property
    def exit_code(self) -> int:
        return {
            FlightStatus.COMPLETE: 0,
            FlightStatus.DIVERGED: 3,
            FlightStatus.NAN_COMMAND: 4,
            FlightStatus.LINK_LOST: 5,
            FlightStatus.FAILSAFE: 6,
            FlightStatus.MODE_CHANGED: 7,
            FlightStatus.REJECTED: 8,
            FlightStatus.INTERRUPTED: 130,
        }[self]


#: Columns of a record: name -> number of components (1 = scalar per sample).
COLUMNS: dict[str, int] = {
    "t_s": 1,
    "pos_ned_m": 3,
    "vel_ned_m_s": 3,
    "euler_rad": 3,  # roll, pitch, yaw as measured/flown
    "ref_pos_ned_m": 3,
    "ref_yaw_rad": 1,
    "ref_euler_rad": 3,  # x7ez, x9ez, x11d(n+1): the attitude the law asked for
    "thrust_n": 1,  # u
    "torques_nm": 3,  # eq. 16 real torques
    "tau_tilde": 3,  # eq. 40-42
}


class StateSample(Protocol):
    """What a record row takes of a vehicle state: ``offboard.codec.MeasuredState`` (a MAVLink
    flight, a re-run) or the simulator's truth (``run_scenario``)."""

    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    euler_rad: np.ndarray


def control_row(t_s: float, state: StateSample, ref: Reference, out: ControlOutput) -> dict[str, object]:
    """One record row (``COLUMNS``) of a control sample: the state, the reference at n and the
    law's output for it.

    The one place a sample becomes a row, for the in-process run, the MAVLink flight and the
    re-run of a log alike, so their records compare column for column.

    Parameters
    ----------
    t_s : float
        Mission time of sample n (s).
    state : StateSample
        The vehicle's position and velocity (NED, m, m/s) and ZYX Euler angles (rad).
    ref : Reference
        The mission's reference at n (NED).
    out : ControlOutput
        The controller's output for sample n: u, the angle references x7ez, x9ez, x11d(n+1),
        the eq. 16 torques and tau_tilde (eq. 40-42).
    """
    law = out.law
    return {
        "t_s": t_s,
        "pos_ned_m": state.pos_ned_m,
        "vel_ned_m_s": state.vel_ned_m_s,
        "euler_rad": state.euler_rad,
        "ref_pos_ned_m": ref.pos_ned_m,
        "ref_yaw_rad": ref.yaw_rad,
        "ref_euler_rad": (law.roll_ref_rad, law.pitch_ref_rad, law.yaw_ref_rad),
        "thrust_n": law.thrust_n,
        "torques_nm": out.torques_nm,
        "tau_tilde": law.tau_tilde,
    }


@dataclass
class FlightRecord:
    """Columns of equal length, one row per control sample; see ``COLUMNS``."""

    columns: dict[str, np.ndarray]
    phases: list[Phase] = field(default_factory=list)
    status: FlightStatus = FlightStatus.COMPLETE
    status_detail: str = ""
    meta: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        lengths = {name: len(values) for name, values in self.columns.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"columns of unequal length: {lengths}")

    def __len__(self) -> int:
        return len(self.columns["t_s"]) if "t_s" in self.columns else 0

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    @property
    def error_ned_m(self) -> np.ndarray:
        """Position error, reference minus actual (the paper's e = x_d - x), NED."""
        return self["ref_pos_ned_m"] - self["pos_ned_m"]

    def write_csv(self, path: str | Path) -> None:
        """One row per sample; vector columns become name_0, name_1, name_2."""
        names: list[str] = []
        arrays: list[np.ndarray] = []
        for name, values in self.columns.items():
            values = np.asarray(values, dtype=float)
            if values.ndim == 1:
                names.append(name)
                arrays.append(values[:, None])
            else:
                names.extend(f"{name}_{i}" for i in range(values.shape[1]))
                arrays.append(values)
        table = np.hstack(arrays) if arrays else np.zeros((0, 0))
        with open(path, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(names)
            writer.writerows(table.tolist())


class RecordBuilder:
    """Collects rows sample by sample, then freezes them into a ``FlightRecord``."""

    def __init__(self, columns: dict[str, int] | None = None) -> None:
        self._spec = dict(COLUMNS if columns is None else columns)
        self._rows: dict[str, list] = {name: [] for name in self._spec}

    def append(self, **values: object) -> None:
        missing = self._spec.keys() - values.keys()
        if missing:
            raise KeyError(f"missing columns: {sorted(missing)}")
        for name, value in values.items():
            self._rows[name].append(value)

    def __len__(self) -> int:
        return len(self._rows["t_s"])

    def build(self, **kwargs: object) -> FlightRecord:
        columns = {}
        for name, width in self._spec.items():
            data = np.asarray(self._rows[name], dtype=float)
            columns[name] = data.reshape(-1, width) if width > 1 else data.reshape(-1)
        return FlightRecord(columns=columns, **kwargs)  # type: ignore[arg-type]
