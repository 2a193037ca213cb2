"""Sweep files: validation (one line naming the file and the field), expansion, per-flight seeds."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from helpers.sweeps import MISSIONS, MIXED, write_sweep
from offboard.errors import ParameterFileError
from offboard.sweep.spec import flight, flights, load_sweep, scenario_of

BUNDLED = sorted(MISSIONS.glob("sweep-*.toml"))


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.name)
def test_bundled_sweep_files_load_and_expand(path):
    spec = load_sweep(path)
    assert spec.flights >= 100 and spec.swept
    first = scenario_of(spec, flight(spec, 0)).scenario
    assert first.model == "rigid-body" and first.drive == "inner-loop"


def test_table2_covers_the_papers_point():
    spec = load_sweep(MISSIONS / "sweep-table2.toml")
    box = {d.name: d.args for d in spec.parameters}
    for name, factor in (("controller.mass_kg", 0.6 / 0.5), ("controller.inertia_xx_kg_m2", 2.7 / 3.8),
                         ("controller.inertia_yy_kg_m2", 4.8 / 3.8), ("controller.inertia_zz_kg_m2", 8.9 / 7.1)):  # fmt: skip
        lo, hi = box[name]
        assert lo <= factor <= hi, name


@pytest.mark.parametrize(
    "body, expected",
    [
        ("[parameters.controller]\nmas_kg = 0.6\n", "parameters.controller.mas_kg: unknown parameter; did you mean controller.mass_kg?"),
        ("[parameters.vehicle]\nmass_kg = { uniform = [0.6] }\n", "parameters.vehicle.mass_kg.uniform: expected 2 numbers"),
        ("[parameters.vehicle]\nmass_kg = { uniform = [0.6, 0.4] }\n", "parameters.vehicle.mass_kg.uniform: expected [LO, HI] with LO <= HI"),
        ("[parameters.vehicle]\nmass_kg = { uniform = [-1, 0.4] }\n", "parameters.vehicle.mass_kg.uniform[0]: must be > 0"),
        ("[parameters.vehicle]\nmass_kg = { unifrom = [0.4, 0.6] }\n", "parameters.vehicle.mass_kg: unknown key 'unifrom'; did you mean uniform?"),
        ("[parameters.vehicle]\nmass_kg = { uniform = [0.4, 0.6], grid = [1] }\n", "parameters.vehicle.mass_kg: expected one distribution"),
        ("[parameters.vehicle]\nmass_kg = { normal = [0.5, -1] }\n", "parameters.vehicle.mass_kg.normal: the spread must be >= 0"),
        ("[parameters.controller.gains]\nkx1 = { grid = [0.5, 1.5] }\n", "parameters.controller.gains.kx1.grid[1]: must be < 1"),
        ("[parameters.wind]\ndryden_m_s = { uniform = [0, 5], relative = \"base\" }\n",
         "parameters.wind.dryden_m_s.relative: the scenario has no value of its own"),
        ("[parameters.vehicle]\nmass_kg = { uniform = [0.9, 1.1], relative = \"truth\" }\n",
         "parameters.vehicle.mass_kg.relative: only the controller's mass and inertia are relative to the truth"),
        ("[parameters]\nwind = { grid = [\"dryden:fast\"] }\n", "parameters.wind.grid[0]: wind spec"),
        ("[parameters]\nsensors = { uniform = [0, 1] }\n", "parameters.sensors: a spec string takes value, choice or grid"),
        ("[parameters.vehicle]\nmotor_time_constant_s = { grid = [0.01, 0.02, 0.03, 0.04] }\n",
         "sweep.flights: 6 is not a multiple of the grid's 4 points"),
        ("[parameters.vehicle]\nmass_kg = { linspace = [0.4, 0.6, 2.5] }\n", "parameters.vehicle.mass_kg.linspace: the count must be a whole number"),
        ("[parameters.controller]\nsample_time_s = 0.0505\n", "parameters: "),
        ("[parameters]\nlatency_s = 0.06\n", "latency_s = 0.06 in flight 0: must be below the sample time"),
        ("[parameters.controller]\nmass_kg = { normal = [0.5, 1.0] }\n", ""),  # loads: draws are checked per flight
        ("[sweep2]\n", "sweep2: unknown field"),
    ],
)
def test_spec_errors_are_one_line_naming_file_and_field(tmp_path, body, expected):
    path = write_sweep(tmp_path, body)
    if not expected:
        load_sweep(path)
        return
    with pytest.raises(ParameterFileError) as err:
        load_sweep(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("mini.toml: "), message
    assert expected in message, message


def test_header_errors(tmp_path):
    for text, expected in (('[sweep]\nscenario = "nope.toml"\nflights = 3\n', "mini.toml: sweep.scenario: no such file 'nope.toml'"),
                           (f'[sweep]\nscenario = "{MISSIONS / "paper-sim1.toml"}"\nflights = 2.5\n', "sweep.flights: expected a whole number"),
                           ('[scenario]\nname = "x"\n', "a scenario file ([scenario]), not a sweep")):  # fmt: skip
        path = tmp_path / "mini.toml"
        path.write_text(text)
        with pytest.raises(ParameterFileError, match="^mini.toml: ") as err:
            load_sweep(path)
        assert expected in str(err.value)


def test_per_flight_draws_depend_on_the_seed_and_index_only(tmp_path):
    spec = load_sweep(write_sweep(tmp_path, MIXED, flights=20))
    whole = flights(spec)
    chunked = [f for a, b in ((0, 3), (3, 4), (4, 13), (13, 20)) for f in flights(spec, a, b)]
    assert whole == chunked
    assert [flight(spec, i) for i in reversed(range(20))] == list(reversed(whole))
    # the flights differ, and another seed gives other flights
    assert len({f.seed for f in whole}) == 20
    assert len({f.values["controller.mass_kg"] for f in whole}) == 20
    other = load_sweep(write_sweep(tmp_path, MIXED, flights=20, seed=4))
    assert flight(other, 0).values["controller.mass_kg"] != whole[0].values["controller.mass_kg"]


def test_adding_a_parameter_leaves_the_others_draws(tmp_path):
    spec = load_sweep(write_sweep(tmp_path, MIXED, flights=10))
    more = load_sweep(write_sweep(tmp_path, MIXED + "\"controller.gains.kx1\" = { uniform = [0.6, 0.9] }\n", flights=10))
    for a, b in zip(flights(spec), flights(more)):
        assert {k: b.values[k] for k in a.values} == a.values and a.seed == b.seed


def test_grid_is_crossed_and_truth_relative_beliefs_follow_the_flights_truth(tmp_path):
    body = ("[parameters.vehicle]\nmass_kg = { grid = [0.4, 0.6] }\nmotor_time_constant_s = { linspace = [0.01, 0.03, 3] }\n"
            "[parameters.controller]\nmass_kg = { uniform = [1.2, 1.2], relative = \"truth\" }\n")  # fmt: skip
    spec = load_sweep(write_sweep(tmp_path, body, flights=12))
    points = [(f.values["vehicle.mass_kg"], f.values["vehicle.motor_time_constant_s"]) for f in flights(spec)]
    assert sorted(set(points)) == [(m, t) for m in (0.4, 0.6) for t in np.linspace(0.01, 0.03, 3)]
    assert points[:6] == points[6:]
    for f in flights(spec):
        sc = scenario_of(spec, f).scenario
        assert sc.vehicle.mass_kg == f.values["vehicle.mass_kg"]
        assert sc.controller.mass_kg == pytest.approx(1.2 * sc.vehicle.mass_kg, rel=1e-15)
        assert sc.seed == f.seed


def test_flight_values_reach_the_scenario(tmp_path):
    spec = load_sweep(write_sweep(tmp_path, MIXED + "\"initial.yaw_deg\" = 90\n"))
    f = flight(spec, 1)
    setup = scenario_of(spec, f)
    sc = setup.scenario
    assert setup.latency_s == f.values["latency_s"]
    assert sc.vehicle.motor_time_constant_s == f.values["vehicle.motor_time_constant_s"]
    assert sc.controller.inertia_kg_m2[0] == pytest.approx(f.values["controller.inertia_xx_kg_m2"] * sc.vehicle.inertia_kg_m2[0])
    assert sc.wind.startswith("dryden:") and sc.sensors == f"paper:{f.values['sensors.paper_fraction']!r}"
    assert sc.initial_pos_ned_m[2] == f.values["initial.down_m"]
    assert sc.initial_yaw_rad == pytest.approx(math.pi / 2)
    assert replace(spec.base, name=sc.name, vehicle=sc.vehicle, controller=sc.controller, sensors=sc.sensors, wind=sc.wind,
                   seed=sc.seed, initial_pos_ned_m=sc.initial_pos_ned_m, initial_yaw_rad=sc.initial_yaw_rad) == sc  # fmt: skip


def test_a_drawn_value_out_of_bounds_names_the_parameter_and_flight(tmp_path):
    spec = load_sweep(write_sweep(tmp_path, "[parameters.vehicle]\nmass_kg = { normal = [0.5, 0.3] }\n", flights=100))
    bad = [f for f in flights(spec) if f.values["vehicle.mass_kg"] <= 0]
    assert bad
    with pytest.raises(ValueError, match=f"vehicle.mass_kg = .* in flight {bad[0].index}: must be > 0"):
        scenario_of(spec, bad[0])
    assert np.isfinite([f.values["vehicle.mass_kg"] for f in flights(spec)]).all()
