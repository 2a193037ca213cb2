"""A sweep's Parquet rows and report: schema, one row a flight, percentiles, sensitivity, plots."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from helpers.sweeps import write_sweep
from offboard import jsonout
from offboard.sweep.report import format_report, read_rows, spearman, summary, write_plots
from offboard.sweep.runner import ParquetRows, chunks, columns, fly_chunk, row_columns
from offboard.sweep.spec import load_sweep


def test_spearman_is_the_rank_correlation_with_ties_averaged():
    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    assert spearman(x, x**3) == pytest.approx(1.0)
    assert spearman(x, -x) == pytest.approx(-1.0)
    # ties: ranks (1.5, 1.5, 3, 4) against (1, 2, 3, 4): Pearson of the ranks
    assert spearman(np.array([0.0, 0.0, 1.0, 2.0]), np.array([1.0, 2.0, 3.0, 4.0])) == pytest.approx(0.9486833, abs=1e-6)
    assert math.isnan(spearman(np.ones(5), x)) and math.isnan(spearman(x[:2], x[:2]))


def test_chunks_cover_every_flight_once():
    assert list(chunks(7, 3)) == [(0, 3), (3, 6), (6, 7)]
    assert list(chunks(3, 5)) == [(0, 3)]


def test_rows_go_to_parquet_one_a_flight_and_make_a_report(tmp_path):
    body = ("[parameters.controller]\nmass_kg = { grid = [0.3, 0.5, 0.7] }\n"
            "[parameters.controller.gains]\nkx1 = { uniform = [0.7, 0.9] }\n"
            "[parameters]\nwind = { choice = [\"none\", \"constant:1,0,0\"] }\n")  # fmt: skip
    spec = load_sweep(write_sweep(tmp_path, body, flights=3, duration_s=0.3))
    names = [c for c, _ in columns(spec)]
    assert names[:5] == ["flight", "seed", "controller.mass_kg", "controller.gains.kx1", "wind"]
    assert {"rms_whole_m", "max_helix_m", "final_error_m", "peak_tilt_deg", "peak_thrust_n", "status", "converge_s"} <= set(names)
    out = ParquetRows(tmp_path / "flights.parquet", columns(spec))
    for start, stop in ((2, 3), (0, 2)):  # in any order: the report sorts by flight
        rows = fly_chunk(spec, start, stop)
        out.write(row_columns(rows, columns(spec)), len(rows))  # as a task hands them over
    out.close()
    rows = read_rows(tmp_path / "flights.parquet")
    assert rows["flight"].tolist() == [0, 1, 2] and rows["controller.mass_kg"].tolist() == [0.3, 0.5, 0.7]
    assert set(rows["wind"].tolist()) <= {"none", "constant:1,0,0"}
    s = summary(spec, rows)
    assert s["flights"] == 3 and sum(s["statuses"].values()) == 3
    assert s["success_rate"] == pytest.approx(s["statuses"].get("complete", 0) / 3)
    assert [r["parameter"] for r in s["sensitivity"]] and {r["parameter"] for r in s["sensitivity"]} == {
        "controller.mass_kg", "controller.gains.kx1"}
    p = s["percentiles"]["rms_whole_m"]
    assert p["p5"] <= p["p50"] <= p["p95"] <= p["p99"]
    json.loads(jsonout.dumps(s))  # strict JSON
    text = format_report(s)
    assert text.startswith("# sweep mini: 3 flights") and "| controller.mass_kg |" in text
    figures = write_plots(spec, rows, s, tmp_path)
    assert [f.name for f in figures] == ["rms-histogram.png", "rms-vs-parameters.png", "failure-map.png"]
    assert all(f.stat().st_size > 5000 for f in figures)


def test_a_believed_mass_far_too_low_ranks_first(tmp_path):
    # 0.3 of the truth: the law asks for a third of the weight and the vehicle never leaves the ground
    body = "[parameters.controller]\nmass_kg = { grid = [0.3, 1.0], relative = \"truth\" }\n"
    spec = load_sweep(write_sweep(tmp_path, body + "[parameters.vehicle]\nmass_kg = { uniform = [0.49, 0.51] }\n",
                                  flights=4, duration_s=0.6))  # fmt: skip
    rows_list = fly_chunk(spec, 0, 4)
    rows = {k: np.array([r[k] for r in rows_list]) for k in rows_list[0]}
    assert [r["status"] for r in rows_list][1::2] == ["complete", "complete"]
    s = summary(spec, rows)
    assert s["sensitivity"][0]["parameter"] == "controller.mass_kg"
