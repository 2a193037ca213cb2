"""offboard.record.RecordBuilder spools its rows to a file: a long flight's memory stays flat, and
the record it builds is the rows appended, bit for bit (also when the spool cannot be written)."""

from __future__ import annotations

import csv
import errno
import io
import math
import tracemalloc

import numpy as np
import pytest

import offboard.record as record_module
from offboard.flight import LoopStats
from offboard.record import COLUMNS, RecordBuilder

#: The MAVLink flight's columns (offboard.flight.FLIGHT_COLUMNS): 29 values a row.
SPEC = {**COLUMNS, "time_boot_ms": 1, "sample_wall_s": 1}


def row(n: int) -> dict[str, object]:
    """Row n as the flight appends it: numpy arrays, tuples, Python floats and an int stamp."""
    t = 0.05 * n
    return {
        "t_s": t,
        "pos_ned_m": np.array([math.sin(t), math.cos(t), -t]),
        "vel_ned_m_s": np.array([n, -n, 0.5 * n], dtype=float),
        "euler_rad": np.array([1e-3 * n, -2e-3 * n, math.pi / (n + 1)]),
        "ref_pos_ned_m": np.array([1.0, 2.0, -3.0 - t]),
        "ref_yaw_rad": 0.1 * n,
        "ref_euler_rad": (t / 3.0, -t / 7.0, 0.3),
        "thrust_n": 4.9 + 1e-6 * n,
        "torques_nm": np.array([1e-9 * n, 2.0, -1.0 / (n + 3)]),
        "tau_tilde": (float(n % 17), -0.5, 1.0 / (n + 2)),
        "time_boot_ms": 1000 + 50 * n,
        "sample_wall_s": t * 1.0001,
    }


def expected(count: int) -> dict[str, np.ndarray]:
    """What numpy.asarray(rows, dtype=float) made of the rows (the builder's record before spooling)."""
    rows = [row(n) for n in range(count)]
    return {name: np.asarray([r[name] for r in rows], dtype=float).reshape(-1, w) if w > 1 else
            np.asarray([r[name] for r in rows], dtype=float) for name, w in SPEC.items()}  # fmt: skip


def assert_record_equals(record, want: dict[str, np.ndarray]) -> None:
    assert list(record.columns) == list(want)
    for name, values in want.items():
        assert record[name].shape == values.shape, name
        np.testing.assert_array_equal(record[name], values, err_msg=name)  # bit for bit (NaN-free)


@pytest.mark.slow
def test_100k_rows_hold_bounded_memory_and_build_the_rows():
    rows = 100_000  # 83 min of a 20 Hz flight; as Python lists these rows held ~100 MB
    builder = RecordBuilder(SPEC)
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        for n in range(rows):
            builder.append(**row(n))
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # one block of 1024 rows x 29 float64 (232 kB) and the spool file's buffer; 100k rows are 23 MB packed
    assert held - base < 1_000_000, f"{(held - base) / 1e6:.1f} MB held after {rows} rows"
    assert peak - base < 1_500_000, f"{(peak - base) / 1e6:.1f} MB peak while appending {rows} rows"
    assert len(builder) == rows and builder.spool_error is None
    assert_record_equals(builder.build(), expected(rows))


@pytest.mark.parametrize("block_rows", [1, 7, 1024])
def test_build_any_time_and_append_after(block_rows):
    builder = RecordBuilder(SPEC, block_rows=block_rows)
    assert_record_equals(builder.build(), expected(0))  # empty: (0,) and (0, 3) columns
    for n in range(30):
        builder.append(**row(n))
    first = builder.build()
    for n in range(30, 61):
        builder.append(**row(n))
    assert_record_equals(first, expected(30))
    assert_record_equals(builder.build(), expected(61))
    builder.close()


def test_a_spool_that_cannot_be_written_keeps_the_rows_in_memory(monkeypatch):
    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(record_module.tempfile, "TemporaryFile", no_space)
    builder = RecordBuilder(SPEC, block_rows=8)
    for n in range(50):
        builder.append(**row(n))
    assert builder.spool_error is not None and "No space left on device" in builder.spool_error
    assert_record_equals(builder.build(), expected(50))


def test_a_write_failing_midway_loses_no_row(monkeypatch):
    class FullAfterOneBlock(io.BytesIO):
        def write(self, data):
            if self.tell():
                raise OSError(errno.ENOSPC, "No space left on device")
            return super().write(data)

    monkeypatch.setattr(record_module.tempfile, "TemporaryFile", lambda **kwargs: FullAfterOneBlock())
    builder = RecordBuilder(SPEC, block_rows=4)
    for n in range(23):
        builder.append(**row(n))
    assert builder.spool_error is not None
    assert_record_equals(builder.build(), expected(23))


def test_bad_rows_are_one_clear_error_and_leave_the_record_as_it_was():
    builder = RecordBuilder(SPEC, block_rows=4)
    builder.append(**row(0))
    with pytest.raises(ValueError, match="'pos_ned_m' takes 3 numbers a row"):
        builder.append(**{**row(1), "pos_ned_m": (1.0, 2.0)})
    with pytest.raises(ValueError, match="'thrust_n' takes 1 number a row"):
        builder.append(**{**row(1), "thrust_n": "lots"})
    with pytest.raises(KeyError, match="missing columns: \\['time_boot_ms'\\]"):
        builder.append(**{k: v for k, v in row(1).items() if k != "time_boot_ms"})
    with pytest.raises(KeyError, match="unknown columns: \\['extra'\\]"):
        builder.append(**row(1), extra=1.0)
    builder.append(**row(1))
    assert_record_equals(builder.build(), expected(2))


def test_write_csv_in_blocks_writes_the_whole_table_as_before(tmp_path, monkeypatch):
    builder = RecordBuilder(SPEC, block_rows=16)
    for n in range(45):
        builder.append(**row(n))
    record = builder.build()
    # before: the whole table through csv.writer at once
    names, arrays = [], []
    for name, values in record.columns.items():
        names += [name] if values.ndim == 1 else [f"{name}_{i}" for i in range(values.shape[1])]
        arrays.append(values[:, None] if values.ndim == 1 else values)
    whole = io.StringIO(newline="")
    writer = csv.writer(whole)
    writer.writerow(names)
    writer.writerows(np.hstack(arrays).tolist())
    monkeypatch.setattr(record_module, "CSV_BLOCK_ROWS", 7)  # 45 rows: 6 full blocks and 3 rows
    record.write_csv(tmp_path / "series.csv")
    assert (tmp_path / "series.csv").read_bytes() == whole.getvalue().encode()


def test_loop_periods_are_spooled_and_their_statistics_exact(monkeypatch):
    monkeypatch.setattr(record_module, "SPOOL_BLOCK_ROWS", 8)
    stats = LoopStats()
    periods = [0.05 + 1e-4 * math.sin(k) + (0.02 if k == 17 else 0.0) for k in range(100)]
    for p in periods:
        stats.add_period(p)
    assert stats.periods._spooled == 96  # in the file, not in memory
    np.testing.assert_array_equal(stats.periods_s, periods)
    jitter = np.abs(np.asarray(periods) - 0.05)
    d = stats.to_dict(0.05)
    assert d["jitter_p50_ms"] == float(np.percentile(jitter, 50) * 1e3)
    assert d["jitter_p99_ms"] == float(np.percentile(jitter, 99) * 1e3)
    assert d["jitter_max_ms"] == float(np.max(jitter) * 1e3)
    assert d["period_mean_s"] == float(np.mean(periods))
