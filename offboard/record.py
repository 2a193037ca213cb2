"""A flight as aligned time series, whatever produced it (in-process run, MAVLink flight, replay).

Metrics (``offboard.metrics``) and figures (``offboard.plots``) take a ``FlightRecord``, so the
same table and the same plots describe a simulation, a live flight and a replayed log.
"""

from __future__ import annotations

import csv
import enum
import io
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from offboard.trajectory.base import Phase, Reference

if TYPE_CHECKING:
    from offboard.controller.command import Command, StateEstimate


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
    LOST_TRACK = "lost_track"  # far off the reference and not closing in flight, or at the end (metrics.LOST_TRACK_M)
    ESTIMATE_LOST = "estimate_lost"  # the vehicle's estimator stopped vouching for what the law reads (flight.guards)
    INCOMPLETE = "incomplete"  # replay: the log ends before the mission does (cut short, stopped early)

    @property
    def exit_code(self) -> int:
        """The process exit code of this status (0 complete; docs/offboard.md lists them)."""
        return {
            FlightStatus.COMPLETE: 0,
            FlightStatus.DIVERGED: 3,
            FlightStatus.NAN_COMMAND: 4,
            FlightStatus.LINK_LOST: 5,
            FlightStatus.FAILSAFE: 6,
            FlightStatus.MODE_CHANGED: 7,
            FlightStatus.REJECTED: 8,
            FlightStatus.LOST_TRACK: 9,
            FlightStatus.INCOMPLETE: 10,
            FlightStatus.ESTIMATE_LOST: 11,
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


_NAN3 = (float("nan"),) * 3


def control_row(t_s: float, state: StateEstimate, ref: Reference, command: Command) -> dict[str, object]:
    """One record row (``COLUMNS``) of a control sample: the state, the reference at n and the
    controller's command for it.

    The one place a sample becomes a row, for the in-process run, the MAVLink flight and the
    re-run of a log alike, so their records compare column for column.

    Parameters
    ----------
    t_s : float
        Mission time of sample n (s).
    state : StateEstimate
        The vehicle's position and velocity (NED, m, m/s) and ZYX Euler angles (rad).
    ref : Reference
        The mission's reference at n (NED).
    command : Command
        The controller's command for sample n: u, the attitude asked for (the paper's x7ez,
        x9ez, x11d(n+1)), the torques (the paper's eq. 16 torques; another controller's torque
        command, NaN if it gives none) and tau_tilde (eq. 40-42; NaN for other controllers).
    """
    torques = command.generalized_torque_nm if command.generalized_torque_nm is not None else command.torque_nm
    return {
        "t_s": t_s,
        "pos_ned_m": state.pos_ned_m,
        "vel_ned_m_s": state.vel_ned_m_s,
        "euler_rad": state.euler_rad,
        "ref_pos_ned_m": ref.pos_ned_m,
        "ref_yaw_rad": ref.yaw_rad,
        "ref_euler_rad": command.attitude_ref_euler_rad,
        "thrust_n": command.thrust_n,
        "torques_nm": _NAN3 if torques is None else torques,
        "tau_tilde": _NAN3 if command.euler_accel_rad_s2 is None else command.euler_accel_rad_s2,
    }


#: Rows ``FlightRecord.write_csv`` formats at a time.
CSV_BLOCK_ROWS = 4096


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
        """One row per sample; vector columns become name_0, name_1, name_2 (``repr`` of each float)."""
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
        rows = len(arrays[0]) if arrays else 0
        with open(path, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(names)
            # a block of rows at a time: an hour's table as Python floats would be ~70 MB at once
            for start in range(0, rows, CSV_BLOCK_ROWS):
                writer.writerows(np.hstack([a[start : start + CSV_BLOCK_ROWS] for a in arrays]).tolist())


#: Rows a ``RecordBuilder`` packs in memory before it appends them to its spool file (1024 rows
#: of the flight's 29 values: 232 kB, 51 s of a 20 Hz flight).
SPOOL_BLOCK_ROWS = 1024


class RecordBuilder:
    """Collects rows sample by sample, then freezes them into a ``FlightRecord``.

    A flight's memory stays flat however long it lasts: each row is packed as float64 into a
    block of ``block_rows`` rows, and each full block is appended to an anonymous temporary file
    (the spool; ``tempfile``'s folder, ``TMPDIR``), as PX4's logger streams to its card instead of
    keeping the flight in RAM. ``build()`` reads the spool back into the record's columns, the
    same values bit for bit as the rows appended (every value goes through float64, as
    ``numpy.asarray(rows, dtype=float)`` would take it). A flight of fewer than ``block_rows``
    samples never touches the disk.

    If the spool cannot be created or written (no temporary folder, disk full), the blocks stay
    in memory (still packed: 8 bytes a value) and ``spool_error`` says why: a record is never
    lost to its spool.

    Parameters
    ----------
    columns : dict of str to int, optional
        Column name -> values per row (``COLUMNS`` by default).
    block_rows : int, optional
        Rows held in memory before a block goes to the spool (``SPOOL_BLOCK_ROWS``).
    """

    def __init__(self, columns: dict[str, int] | None = None, *, block_rows: int | None = None) -> None:
        self._spec = dict(COLUMNS if columns is None else columns)
        if any(not isinstance(w, int) or w < 1 for w in self._spec.values()):
            raise ValueError(f"column widths must be positive integers: {self._spec}")
        block_rows = SPOOL_BLOCK_ROWS if block_rows is None else block_rows
        if block_rows < 1:
            raise ValueError(f"block_rows must be positive, got {block_rows}")
        self._slots: list[tuple[str, int | slice]] = []
        offset = 0
        for name, width in self._spec.items():
            self._slots.append((name, offset if width == 1 else slice(offset, offset + width)))
            offset += width
        self._width = offset
        self._block_rows = block_rows
        self._block: np.ndarray | None = None  # allocated at the first row
        self._filled = 0  # rows in the block
        self._spool: io.RawIOBase | None = None  # unbuffered (buffering=0): a FileIO
        self._spooled = 0  # rows in the spool file
        self._kept: list[np.ndarray] = []  # full blocks kept in memory when the spool failed
        self.spool_error: str | None = None

    def append(self, **values: object) -> None:
        """One row: every column by name, a float (width 1) or a sequence of ``width`` floats.

        Raises
        ------
        KeyError
            A column is missing or unknown.
        ValueError
            A value does not have its column's width or is not a number.
        """
        if len(values) != len(self._spec) or values.keys() != self._spec.keys():
            missing, unknown = self._spec.keys() - values.keys(), values.keys() - self._spec.keys()
            raise KeyError(f"missing columns: {sorted(missing)}" if missing else f"unknown columns: {sorted(unknown)}")
        block = self._block
        if block is None:
            block = self._block = np.empty((self._block_rows, self._width), dtype=np.float64)
        row = block[self._filled]
        for name, slot in self._slots:
            try:
                row[slot] = values[name]
            except (ValueError, TypeError) as exc:
                width = self._spec[name]
                raise ValueError(f"record column {name!r} takes {width} number{'s' if width > 1 else ''} a row, "
                                 f"got {values[name]!r}") from exc  # fmt: skip
        self._filled += 1
        if self._filled == self._block_rows:
            self._flush_block()

    def __len__(self) -> int:
        return self._spooled + self._block_rows * len(self._kept) + self._filled

    def _flush_block(self) -> None:
        """The full block to the spool file (or kept in memory if the spool fails)."""
        assert self._block is not None
        if self.spool_error is None:
            try:
                if self._spool is None:
                    self._spool = cast(io.RawIOBase, tempfile.TemporaryFile(prefix="offboard-record-", buffering=0))
                data = self._block.data.cast("B")
                while data:  # unbuffered: a write may take part of the block
                    data = data[self._spool.write(data) :]
                self._spooled += self._block_rows
                self._filled = 0
                return
            except OSError as exc:
                # the rows already spooled stay readable; a block half written is never read back
                self.spool_error = f"record spool: {exc.strerror or exc}: rows kept in memory from row {self._spooled}"
        self._kept.append(self._block)
        self._block = np.empty_like(self._block)
        self._filled = 0

    def _close_spool(self) -> None:
        if self._spool is not None:
            try:
                self._spool.close()
            except OSError:
                pass
        self._spool = None

    def _tables(self) -> Iterator[np.ndarray]:
        """Every row in order, a block at a time (spool, kept blocks, the block being filled)."""
        if self._spooled:
            assert self._spool is not None
            chunk = np.empty((self._block_rows, self._width), dtype=np.float64)
            self._spool.seek(0)
            left = self._spooled
            while left:
                rows = min(left, self._block_rows)
                view = chunk[:rows]
                data = view.data.cast("B")
                while data:  # unbuffered: a read may return part of the block
                    got = self._spool.readinto(data)
                    if not got:
                        raise OSError(f"record spool: {data.nbytes} bytes missing at row {self._spooled - left}")
                    data = data[got:]
                yield view
                left -= rows
            self._spool.seek(0, 2)  # appending may go on after a build
        yield from self._kept
        if self._filled:
            assert self._block is not None
            yield self._block[: self._filled]

    def build(self, **kwargs: object) -> FlightRecord:
        """The rows so far as a ``FlightRecord`` (``kwargs``: its phases, status, detail, meta).

        The builder stays usable: more rows may follow and a later ``build()`` has them all.
        """
        n = len(self)
        columns = {name: np.empty((n, width) if width > 1 else n, dtype=np.float64) for name, width in self._spec.items()}
        start = 0
        for table in self._tables():
            stop = start + len(table)
            for name, slot in self._slots:
                columns[name][start:stop] = table[:, slot]
            start = stop
        return FlightRecord(columns=columns, **kwargs)  # type: ignore[arg-type]

    def close(self) -> None:
        """Remove the spool file now (it goes anyway when the builder is collected)."""
        self._close_spool()
