"""Scenario files: mission + vehicle + controller + sensors + wind, for ``offboard simulate``.

A scenario is one TOML file (the paper's three simulations are ``missions/paper-sim*.toml``)::

    [scenario]
    name = "paper-sim1"
    mission = "paper-helix.toml"    # a mission file (relative to this file, or bundled), or a [scenario.mission] table
    model = "paper"                 # paper | rigid-body
    drive = "inner-loop"            # inner-loop | held-torque
    physics_dt_s = 0.001
    sensors = "clean"               # clean | paper:0.05 | imu[:...]
    wind = "none"                   # none | constant:N,E,D | dryden:SPEED | gust:...
    seed = 1

    [vehicle]      # the true vehicle, the schema of sitl_plant/vehicles/paper-quad.toml
    [controller]   # the controller, the schema of offboard/controller/paper.toml

Each table may instead be a path: ``vehicle = "../sitl_plant/vehicles/paper-quad.toml"``.
"""

from __future__ import annotations

import math
from pathlib import Path

from offboard.controller.params import controller_from_table, load_controller
from offboard.errors import ParameterFileError
from offboard.inprocess import SCENARIO_DRIVES, Scenario
from offboard.missions import resolve_mission
from offboard.model.tomlfile import Fields, read_toml
from offboard.model.vehicle import VEHICLE_MODELS, load_vehicle, vehicle_from_table
from sitl_plant.dynamics.sensors import sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec


def _table_or_file(top: Fields, key: str, base_dir: Path, from_table, from_file):
    value = top.raw(key)
    if isinstance(value, str):
        path = (base_dir / value).resolve()
        if not path.is_file():
            raise top.error(key, f"no such file {value!r} (relative to {base_dir})")
        return from_file(path)
    return from_table(top.sub(key))


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario file; every error names the file and field."""
    path = Path(path)
    source = path.name
    top = Fields(read_toml(path), source)
    base_dir = path.resolve().parent
    if not top.has("scenario") and top.has("mission"):
        raise ParameterFileError(f"{source}: a mission file ([mission]), not a scenario ([scenario]): fly it with "
                                 f"`offboard fly {path}`, or name it in a scenario, as missions/paper-sim1.toml names "
                                 "paper-helix.toml")  # fmt: skip
    s = top.sub("scenario")
    mission = resolve_mission(s.raw("mission"), f"{source}: scenario", base_dir)
    vehicle = _table_or_file(top, "vehicle", base_dir, vehicle_from_table, load_vehicle)
    controller = _table_or_file(top, "controller", base_dir, controller_from_table, load_controller)
    duration = s.raw("duration_s", None)
    initial_yaw_deg = s.number("initial_yaw_deg", 0.0)
    fields = dict(
        name=s.string("name", path.stem),
        model=s.string("model", "paper", choices=tuple(sorted(VEHICLE_MODELS))),
        drive=s.string("drive", "inner-loop", choices=SCENARIO_DRIVES),
        physics_dt_s=s.number("physics_dt_s", 1e-3, gt=0),
        duration_s=None if duration is None else s.number("duration_s", gt=0),
        sensors=s.string("sensors", "clean"),
        wind=s.string("wind", "none"),
        seed=int(s.number("seed", 0, ge=0)),
        initial_pos_ned_m=s.vector("initial_pos_ned_m", 3, (0.0, 0.0, 0.0)),
        initial_yaw_rad=math.radians(initial_yaw_deg),
        ground=s.boolean("ground", True),
    )
    try:
        scenario = Scenario(trajectory=mission.trajectory, vehicle=vehicle, controller=controller, source=str(path),
                            **fields)  # type: ignore[arg-type]
    except ValueError as exc:  # cross-field checks (e.g. To not a multiple of the physics step)
        raise ParameterFileError(f"{source}: scenario: {exc}") from None
    s.string("description", "")
    s.reject_unknown()
    top.reject_unknown()
    _check_specs(scenario, s)
    return scenario


def _check_specs(scenario: Scenario, s: Fields) -> None:
    """Parse the sensor and wind specs now, so a typo fails before the flight, naming the field."""

    try:
        sensors_from_spec(scenario.sensors, scenario.seed)
    except ValueError as exc:
        raise s.error("sensors", str(exc)) from None
    if scenario.wind != "none":
        try:
            wind_from_spec(scenario.wind, scenario.seed)
        except ValueError as exc:
            raise s.error("wind", str(exc)) from None
