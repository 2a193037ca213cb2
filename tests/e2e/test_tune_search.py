"""`offboard tune --search`: the designs near the analytic one, each keeping its margins, flown on
a sweep's flights on a real local Dask cluster; the one with the lowest median error is written."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest

from offboard.cli import main
from offboard.controller import load_controller
from offboard.controller.design import nearby_designs
from offboard.controller.tuning import design_for_vehicle, vehicle_values
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from offboard.sweep.spec import Distribution, load_sweep
from offboard.sweep.tune import check_sweep, search_spec
from sitl_plant.params import plant_params
from helpers import REPO

pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def _design(latency_s: float = 0.0):
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    return design_for_vehicle(vehicle_values({n: table[n] for n in table}), sample_time_s=0.05, latency_s=latency_s)


def test_the_designs_near_the_analytic_one_all_keep_its_margins():
    design = _design()
    near = nearby_designs(design, limit=8)
    assert near[0] is design and 1 < len(near) <= 8
    keys = {(float(d.horizontal.k_pos), float(d.horizontal.k_vel), float(d.horizontal.lead),
             float(d.horizontal.velocity_integral_per_s2)) for d in near}  # fmt: skip
    assert len(keys) == len(near)  # no design twice
    for d in near:
        assert all(a.meets(design.spec) for a in (d.north, d.east, d.up))
        assert d.up.gains == design.up.gains  # the vertical axis keeps its gains and its own integral
        assert 0.0 < float(d.horizontal.k_pos) < 1.0 and 0.0 < float(d.horizontal.k_vel) < 1.0


def test_a_sweep_that_draws_the_gains_cannot_be_searched():
    with pytest.raises(ValueError, match="sweeps controller.integral_gain_per_s, which the search chooses"):
        check_sweep(load_sweep(REPO / "missions" / "sweep-gains.toml"))
    table2 = load_sweep(REPO / "missions" / "sweep-table2.toml")
    check_sweep(table2)  # beliefs, not gains: searched
    for name in ("controller.gains.kx4", "controller.tilt_lead", "controller.velocity_integral_gain_per_s2"):
        with pytest.raises(ValueError, match=f"sweeps {name}, which the search chooses"):
            check_sweep(replace(table2, parameters=(*table2.parameters, Distribution(name, "fixed", (0.5,)))))


def test_the_search_flies_the_tuned_vehicle_through_px4s_loop_at_the_designed_latency():
    spec = load_sweep(REPO / "missions" / "sweep-table2.toml")
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    flown = search_spec(spec, vehicle, spec.base.controller, latency_s=0.02)
    assert flown.base.drive == "px4" and flown.base.vehicle == vehicle and flown.base.model == "rigid-body"
    assert [d.args for d in flown.parameters if d.name == "latency_s"] == [(0.02,)]
    assert flown.parameters[:-1] == spec.parameters  # the sweep's own distributions, unchanged


def test_tune_search_writes_the_design_with_the_lowest_median_error(tmp_path, capsys):
    out, run_dir = tmp_path / "searched.toml", tmp_path / "search"
    code = main(["tune", "--vehicle", str(PAPER_VEHICLE_FILE), "--search", str(REPO / "missions" / "sweep-table2.toml"),
                 "--search-flights", "2", "--search-designs", "3", "--workers", "1", "--run-dir", str(run_dir),
                 "--output", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    summary = json.loads((run_dir / "search.json").read_text())
    designs = summary["designs"]
    assert len(designs) == 3 and summary["flights_per_design"] == 2
    for k, d in enumerate(designs):
        assert (run_dir / f"design-{k}" / "flights.parquet").is_file()
        assert d["flights"] == 2 and 0.0 < d["median_rms_m"] < 1.0 and d["p90_rms_m"] >= d["median_rms_m"]
    complete = [d for d in designs if d["complete"] == d["flights"]]
    chosen = designs[summary["chosen"]]
    assert chosen["median_rms_m"] == min(d["median_rms_m"] for d in complete)
    params = load_controller(out)
    assert (params.gains.kx1, params.gains.kx2, params.tilt_lead, params.velocity_integral_gain_per_s2) == \
        (chosen["k_pos"], chosen["k_vel"], chosen["tilt_lead"], chosen["velocity_integral_per_s2"])  # fmt: skip
    text = out.read_text()
    assert "# Searched (offboard tune --search" in text and "<- kept" in text
    assert "<- kept" in err and math.isfinite(chosen["median_rms_m"])


@pytest.mark.parametrize("extra, message", [
    (("--params", "PARAMS"), "--search flies the vehicle in process: give it as --vehicle FILE"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--search-flights", "0"), "--search-flights must be at least 1, got 0"),
    (("--vehicle", str(PAPER_VEHICLE_FILE), "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"), "--workers sizes the local cluster"),
])  # fmt: skip
def test_bad_search_options_are_one_line(extra, message, tmp_path, capsys):
    params = tmp_path / "p.json"
    table = plant_params(load_vehicle(PAPER_VEHICLE_FILE))
    params.write_text(json.dumps({n: table[n] for n in table}))
    args = [str(params) if a == "PARAMS" else a for a in extra]
    code = main(["tune", *args, "--search", str(REPO / "missions" / "sweep-table2.toml")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_a_gains_sweep_given_to_search_is_one_line(capsys):
    code = main(["tune", "--vehicle", str(PAPER_VEHICLE_FILE), "--search", str(REPO / "missions" / "sweep-gains.toml")])
    err = capsys.readouterr().err
    assert code == 2 and "sweeps controller.integral_gain_per_s, which the search chooses" in err and len(err.strip().splitlines()) == 1, err
