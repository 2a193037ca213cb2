"""Sweep files: a scenario and distributions or grids over what a flight depends on.

A sweep file (``missions/sweep-table2.toml`` is the paper's Table II as a distribution)::

    [sweep]
    name = "table2"
    scenario = "paper-sim1-rigid-body.toml"   # a scenario file (relative to this file): the base flight
    flights = 1000                            # how many flights (a multiple of the grid's size)
    seed = 2026                               # the sweep's seed: every flight's draws and noise derive from it
    # duration_s = 6.0                        # optional: fly the mission this long (default: the scenario's)
    # converged_m = 0.1                       # optional: "converged" = the 3D error first within this (m)

    [parameters.controller]                   # what the controller believes
    mass_kg = { uniform = [0.8, 1.4], relative = "truth" }   # x the flight's true mass (Table II: 1.2)
    [parameters.vehicle]                      # the true vehicle
    motor_time_constant_s = { grid = [0.01, 0.02, 0.04] }
    [parameters.wind]
    dryden_m_s = { uniform = [0, 6] }

A parameter is a number (fixed), or a table with one distribution: ``uniform = [LO, HI]``,
``normal = [MEAN, STD]``, ``lognormal = [MU, SIGMA]`` (of the log), ``choice = [V, ...]`` (drawn),
``grid = [V, ...]`` or ``linspace = [LO, HI, N]`` (every value, crossed with the other grids).
``relative = "base"`` multiplies the scenario's own value by the draw; ``relative = "truth"`` (the
controller's mass and inertia) multiplies the flight's true vehicle's value: a Table II-style
error. ``PARAMETERS`` lists every name; ``offboard sweep --list-parameters`` prints them.

Seeds (docs/sweeps.md): flight ``i``'s draw of parameter ``name`` comes from
``SeedSequence(seed, spawn_key=(i, 0, crc32(name)))`` and its sensor-noise and wind seed from
``SeedSequence(seed, spawn_key=(i, 1))``: a flight is the same whoever flies it, in any chunk, on
any number of workers, and adding a parameter leaves the others' draws as they were.
"""

from __future__ import annotations

import enum
import itertools
import math
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from offboard.errors import ParameterFileError
from offboard.inprocess import Scenario
from offboard.model.tomlfile import Fields, near_name, read_toml
from offboard.scenario import load_scenario
from sitl_plant.dynamics.sensors import sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec


class ParameterKind(enum.StrEnum):
    """What a swept parameter's values are: numbers (``number``) or whole sensor or wind spec
    strings (``spec``), which take only a value, a choice or a grid and are never relative."""

    NUMBER = "number"
    SPEC = "spec"


@dataclass(frozen=True)
class Parameter:
    """What a sweep may vary: its kind and the bounds a value must keep."""

    help: str
    kind: ParameterKind = ParameterKind.NUMBER
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    base: bool = True  # the scenario has a value of its own (so ``relative = "base"`` means something)
    truth: str | None = None  # the true vehicle's parameter this belief may be relative to


_AXES = ("xx", "yy", "zz")
PARAMETERS: dict[str, Parameter] = {
    "vehicle.mass_kg": Parameter("true mass (kg)", gt=0),
    **{f"vehicle.inertia_{a}_kg_m2": Parameter(f"true I{a} (kg m^2)", gt=0) for a in _AXES},
    "vehicle.motor_time_constant_s": Parameter("motor speed lag (s; rigid body)", ge=0),
    "vehicle.linear_drag_n_s_m": Parameter("linear drag on all three body axes (N s/m; rigid body)", ge=0),
    "vehicle.drag_to_thrust_m": Parameter("rotor drag torque per newton, c (m)", gt=0),
    "vehicle.arm_length_m": Parameter("arm length l (m)", gt=0),
    "controller.mass_kg": Parameter("the mass the controller believes (kg)", gt=0, truth="vehicle.mass_kg"),
    **{f"controller.inertia_{a}_kg_m2": Parameter(f"the I{a} the controller and the inner loop believe (kg m^2)",
                                                   gt=0, truth=f"vehicle.inertia_{a}_kg_m2") for a in _AXES},  # fmt: skip
    **{f"controller.gains.kx{k}": Parameter(f"Table I gain k_x{k}, in (0, 1)", gt=0, lt=1) for k in range(1, 13)},
    "controller.integral_gain_per_s": Parameter("integral action ki (1/s; 0 = the paper's law)", ge=0),
    "controller.velocity_integral_gain_per_s2": Parameter("velocity integral ki (1/s^2; 0 = the paper's law)", ge=0),
    "controller.vertical_velocity_integral_gain_per_s2": Parameter("the vertical axis's own velocity integral ki (1/s^2)",
                                                                   ge=0),
    "controller.tilt_lead": Parameter("lead on the attitude handed to an autopilot (px4 drive)", ge=0),
    "controller.velocity_integral_hold_s": Parameter("the velocity integral's hold after a reference step (s; 0 = "
                                                     "on the bounds only)", ge=0),
    "controller.velocity_from_position_s": Parameter("T of the filter making the velocity read consistent with the "
                                                     "position (s; 0 = as measured, the paper's law)", ge=0),
    "controller.sample_time_s": Parameter("To (s): a whole number of physics steps", gt=0),
    "wind.north_m_s": Parameter("steady wind towards north (m/s)", base=False),
    "wind.east_m_s": Parameter("steady wind towards east (m/s)", base=False),
    "wind.dryden_m_s": Parameter("Dryden turbulence, mean wind at 6 m (m/s)", ge=0, base=False),
    "wind.dryden_dir_deg": Parameter("heading the Dryden mean wind blows towards (deg)", base=False),
    "wind.gust_m_s": Parameter("a 1-cosine gust's amplitude (m/s), towards wind.gust_dir_deg", ge=0, base=False),
    "wind.gust_t_s": Parameter("the gust's start (s; default 4)", ge=0, base=False),
    "wind.gust_dir_deg": Parameter("heading the gust blows towards (deg)", base=False),
    "sensors.paper_fraction": Parameter("the paper's accelerometer noise, a fraction of the value", ge=0, base=False),
    "initial.north_m": Parameter("start offset north (m)", base=False),
    "initial.east_m": Parameter("start offset east (m)", base=False),
    "initial.down_m": Parameter("start offset down (m; < 0 starts in the air)", base=False),
    "initial.yaw_deg": Parameter("start yaw (deg)", base=False),
    "latency_s": Parameter("link latency (s): a command reaches the vehicle this long after its sample", ge=0, base=False),
    "wind": Parameter("a whole wind spec (none | constant:N,E,D | dryden:SPEED | gust:...)", kind=ParameterKind.SPEC, base=False),
    "sensors": Parameter("a whole sensor spec (clean | paper:F | imu:...)", kind=ParameterKind.SPEC, base=False),
}
DISTRIBUTIONS = ("uniform", "normal", "lognormal", "choice", "grid", "linspace")
GUST_DURATION_S = 1.0


class DistributionKind(enum.StrEnum):
    """How a swept parameter's value comes per flight: one value for all (``fixed``: a file's plain
    number or ``value``), drawn (``uniform`` [LO, HI], ``normal`` [MEAN, STD], ``lognormal`` [MU,
    SIGMA] of the log, ``choice`` among the values) or every value of a ``grid`` (a file's ``grid``
    or ``linspace``), crossed with the other grids."""

    FIXED = "fixed"
    UNIFORM = "uniform"
    NORMAL = "normal"
    LOGNORMAL = "lognormal"
    CHOICE = "choice"
    GRID = "grid"


class Relative(enum.StrEnum):
    """What a drawn value multiplies: nothing (``""``, the value itself), the scenario's own value
    (``base``) or the flight's true vehicle's (``truth``: the controller's mass and inertia)."""

    NONE = ""
    BASE = "base"
    TRUTH = "truth"


@dataclass(frozen=True)
class Distribution:
    """One swept parameter: how its value is drawn (or gridded) per flight."""

    name: str
    kind: DistributionKind
    args: tuple = ()
    relative: Relative = Relative.NONE

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", DistributionKind(self.kind))  # a caller's word: its enum
        object.__setattr__(self, "relative", Relative(self.relative))

    @property
    def grid_size(self) -> int:
        """How many values the distribution takes on the grid (1 unless it is a grid)."""
        return len(self.args) if self.kind is DistributionKind.GRID else 1

    def draw(self, rng: np.random.Generator, grid_index: int) -> float | str:
        """One value: fixed, the grid's ``grid_index``-th, or drawn from ``rng``."""
        k, a = self.kind, self.args
        if k is DistributionKind.FIXED:
            return a[0]
        if k is DistributionKind.GRID:
            return a[grid_index]
        if k is DistributionKind.CHOICE:
            return a[int(rng.integers(len(a)))]
        if k is DistributionKind.UNIFORM:
            return float(rng.uniform(a[0], a[1]))
        if k is DistributionKind.NORMAL:
            return float(rng.normal(a[0], a[1]))
        return float(rng.lognormal(a[0], a[1]))


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep file (module docstring)."""

    name: str
    base: Scenario
    flights: int
    seed: int
    parameters: tuple[Distribution, ...]
    source: str = ""
    description: str = ""
    converged_m: float = 0.1

    @property
    def grid(self) -> tuple[Distribution, ...]:
        """The parameters swept on a grid."""
        return tuple(d for d in self.parameters if d.kind is DistributionKind.GRID)

    @property
    def grid_size(self) -> int:
        """How many points the grids make together (their product)."""
        return math.prod(d.grid_size for d in self.grid)

    @property
    def swept(self) -> tuple[str, ...]:
        """The names of the parameters that vary from flight to flight."""
        return tuple(d.name for d in self.parameters
                     if d.kind is not DistributionKind.FIXED and not (d.kind is DistributionKind.GRID and d.grid_size == 1))


@dataclass(frozen=True)
class FlightSpec:
    """One flight of a sweep: its index, its parameter values and its noise/wind seed."""

    index: int
    values: dict[str, float | str] = field(default_factory=dict)
    seed: int = 0


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested ``[parameters.*]`` tables to dotted names; a table holding a distribution key is a
    parameter, not a namespace."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        known = name in PARAMETERS and PARAMETERS[name].kind is ParameterKind.NUMBER  # "wind" is also the wind.* namespace
        if isinstance(value, Mapping) and not known and not (set(value) & {*DISTRIBUTIONS, "relative", "value"}):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def _distribution(name: str, value: Any, source: str) -> Distribution:
    where = f"{source}: parameters.{name}"
    if name not in PARAMETERS:
        near = near_name(name, PARAMETERS)
        raise ParameterFileError(f"{where}: unknown parameter" + (f"; did you mean {near}?" if near else
                                                                   " (offboard sweep --list-parameters lists them)"))
    par = PARAMETERS[name]
    if not isinstance(value, Mapping):
        value = {"value": value}
    keys = [k for k in value if k != "relative"]
    unknown = [k for k in keys if k not in (*DISTRIBUTIONS, "value")]
    if unknown:
        near = near_name(unknown[0], DISTRIBUTIONS)
        raise ParameterFileError(f"{where}: unknown key {unknown[0]!r}" + (f"; did you mean {near}?" if near else
                                                                          f" (expected one of {', '.join(DISTRIBUTIONS)})"))
    if len(keys) != 1:
        raise ParameterFileError(f"{where}: expected one distribution ({', '.join(DISTRIBUTIONS)}), got "
                                 f"{', '.join(keys) or 'none'}")  # fmt: skip
    kind, args = keys[0], value[keys[0]]  # a file's key: a DistributionKind's name, or value or linspace
    raw_relative = value.get("relative", "")
    if raw_relative not in tuple(Relative):
        raise ParameterFileError(f"{where}.relative: expected \"base\" or \"truth\", got {raw_relative!r}")
    relative = Relative(raw_relative)
    if relative is not Relative.NONE and par.kind is not ParameterKind.NUMBER:
        raise ParameterFileError(f"{where}.relative: a spec string cannot be relative")
    if relative is Relative.BASE and not par.base:
        raise ParameterFileError(f"{where}.relative: the scenario has no value of its own to be relative to")
    if relative is Relative.TRUTH and par.truth is None:
        raise ParameterFileError(f"{where}.relative: only the controller's mass and inertia are relative to the truth")

    def numbers(n: int | None) -> tuple[float, ...]:
        if not isinstance(args, list) or (n is not None and len(args) != n) or not args:
            want = f"{n} numbers" if n is not None else "a list of numbers"
            raise ParameterFileError(f"{where}.{kind}: expected {want}, got {args!r}")
        for v in args:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ParameterFileError(f"{where}.{kind}: expected finite numbers, got {v!r}")
        return tuple(float(v) for v in args)

    def check_value(v: float | str, label: str) -> None:
        if par.kind is ParameterKind.SPEC:
            if not isinstance(v, str):
                raise ParameterFileError(f"{where}.{label}: expected a spec string, got {v!r}")
            _check_spec(name, v, f"{where}.{label}")
            return
        if isinstance(v, str):
            raise ParameterFileError(f"{where}.{label}: expected a number, got {v!r}")
        if relative is not Relative.NONE:  # a factor: positive, the product is checked per flight
            if not v > 0:
                raise ParameterFileError(f"{where}.{label}: a relative factor must be > 0, got {v:g}")
            return
        for bound, ok, text in ((par.gt, lambda b: v > b, ">"), (par.ge, lambda b: v >= b, ">="),
                                (par.lt, lambda b: v < b, "<")):  # fmt: skip
            if bound is not None and not ok(bound):
                raise ParameterFileError(f"{where}.{label}: must be {text} {bound:g}, got {v:g}")

    if par.kind is ParameterKind.SPEC and kind not in ("value", "choice", "grid"):
        raise ParameterFileError(f"{where}: a spec string takes value, choice or grid, not {kind}")
    if kind == "value":
        v = args if par.kind is ParameterKind.SPEC else _number(args, f"{where}.value" if isinstance(value, Mapping) and "value" in value else where)
        check_value(v, "value")
        return Distribution(name, DistributionKind.FIXED, (v,), relative)
    if kind in ("choice", "grid"):
        if par.kind is ParameterKind.SPEC:
            if not isinstance(args, list) or not args:
                raise ParameterFileError(f"{where}.{kind}: expected a list of spec strings, got {args!r}")
            values: tuple = tuple(args)
        else:
            values = numbers(None)
        for j, v in enumerate(values):
            check_value(v, f"{kind}[{j}]")
        return Distribution(name, DistributionKind(kind), values, relative)
    if kind == "linspace":
        lo, hi, n = numbers(3)
        if n < 1 or n != int(n):
            raise ParameterFileError(f"{where}.linspace: the count must be a whole number >= 1, got {n:g}")
        values = tuple(float(v) for v in np.linspace(lo, hi, int(n)))
        for j, v in enumerate(values):
            check_value(v, f"linspace[{j}]")
        return Distribution(name, DistributionKind.GRID, values, relative)
    a, b = numbers(2)
    if kind == "uniform":
        if not a <= b:
            raise ParameterFileError(f"{where}.uniform: expected [LO, HI] with LO <= HI, got [{a:g}, {b:g}]")
        check_value(a, "uniform[0]")
        check_value(b, "uniform[1]")
    elif not b >= 0:
        raise ParameterFileError(f"{where}.{kind}: the spread must be >= 0, got {b:g}")
    return Distribution(name, DistributionKind(kind), (a, b), relative)


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ParameterFileError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _check_spec(name: str, spec: str, where: str) -> None:

    try:
        if name == "wind":
            if spec != "none":
                wind_from_spec(spec, 0)
        else:
            sensors_from_spec(spec, 0)
    except ValueError as exc:
        raise ParameterFileError(f"{where}: {exc}") from None


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file; every error is one line naming the file and the field."""
    path = Path(path)
    source = path.name
    top = Fields(read_toml(path), source)
    if not top.has("sweep") and top.has("scenario"):
        raise ParameterFileError(f"{source}: a scenario file ([scenario]), not a sweep ([sweep]): fly it with "
                                 f"`offboard simulate {path}`, or name it in a sweep's [sweep] scenario")  # fmt: skip
    s = top.sub("sweep")
    scenario_name = s.string("scenario")
    scenario_path = (path.resolve().parent / scenario_name).resolve()
    if not scenario_path.is_file():
        raise s.error("scenario", f"no such file {scenario_name!r} (relative to {path.resolve().parent})")
    base = load_scenario(scenario_path)
    spec_name = s.string("name", path.stem)
    flights = s.number("flights", ge=1)
    if flights != int(flights):
        raise s.error("flights", f"expected a whole number, got {flights:g}")
    seed = s.number("seed", 0, ge=0)
    if seed != int(seed):
        raise s.error("seed", f"expected a whole number, got {seed:g}")
    description = s.string("description", "")
    converged_m = s.number("converged_m", 0.1, gt=0)
    if s.has("duration_s"):  # fly the scenario's mission for this long instead
        base = replace(base, duration_s=s.number("duration_s", gt=0))
    s.reject_unknown()
    params_table = top.raw("parameters", {})
    if not isinstance(params_table, Mapping):
        raise top.error("parameters", f"expected a table, got {type(params_table).__name__}")
    top.reject_unknown()
    distributions = tuple(_distribution(name, value, source) for name, value in _flatten(params_table).items())
    spec = SweepSpec(spec_name, base, int(flights), int(seed), distributions, str(path), description, converged_m)
    if spec.grid_size > 1 and spec.flights % spec.grid_size:
        raise s.error("flights", f"{spec.flights} is not a multiple of the grid's {spec.grid_size} points "
                                 f"({' x '.join(str(d.grid_size) for d in spec.grid)})")  # fmt: skip
    try:  # the first flight of every grid point must make a valid scenario (catches e.g. To off the physics step)
        for i in range(min(spec.grid_size, 64)):
            scenario_of(spec, flight(spec, i))
    except ValueError as exc:
        raise ParameterFileError(f"{source}: parameters: {exc}") from None
    return spec


def _stream(seed: int, *key: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed, spawn_key=key)


def flight(spec: SweepSpec, index: int) -> FlightSpec:
    """Flight ``index`` of the sweep: its values and seed, from the sweep's seed alone (module docstring)."""
    if not 0 <= index < spec.flights:
        raise IndexError(f"flight {index} of a sweep of {spec.flights}")
    grid_index = index % spec.grid_size if spec.grid_size > 1 else 0
    # mixed radix over the grid parameters, the first one slowest
    digits: dict[str, int] = {}
    rest = grid_index
    for d in reversed(spec.grid):
        rest, digits[d.name] = divmod(rest, d.grid_size)
    values: dict[str, float | str] = {}
    for d in spec.parameters:
        rng = np.random.default_rng(_stream(spec.seed, index, 0, zlib.crc32(d.name.encode())))
        values[d.name] = d.draw(rng, digits.get(d.name, 0))
    seed = int(_stream(spec.seed, index, 1).generate_state(1, np.uint32)[0])
    return FlightSpec(index, values, seed)


def flights(spec: SweepSpec, start: int = 0, stop: int | None = None) -> list[FlightSpec]:
    """Flights ``start`` to ``stop`` (exclusive) of the sweep."""
    stop = spec.flights if stop is None else min(stop, spec.flights)
    return [flight(spec, i) for i in range(start, stop)]


def _base_value(base: Scenario, name: str) -> float:
    v, c = base.vehicle, base.controller
    group, _, key = name.partition(".")
    obj: Any = v if group == "vehicle" else c
    if key.startswith("inertia_"):
        return float(obj.inertia_kg_m2[_AXES.index(key.split("_")[1])])
    if key == "linear_drag_n_s_m":
        return float(v.linear_drag_n_s_m[0])
    if key.startswith("gains."):
        return float(getattr(c.gains, key.split(".")[1]))
    return float(getattr(obj, key))


@dataclass(frozen=True)
class FlightSetup:
    """A flight's scenario (the base with the flight's values) and what a scenario does not hold."""

    scenario: Scenario
    latency_s: float = 0.0


def scenario_of(spec: SweepSpec, fl: FlightSpec) -> FlightSetup:
    """The scenario flight ``fl`` flies (raises ValueError naming the parameter when a value is not
    valid for it, e.g. a drawn mass <= 0)."""
    base = spec.base
    dist = {d.name: d for d in spec.parameters}
    values: dict[str, float | str] = {}
    # the truth first, so that a belief relative to the truth sees the flight's own truth
    for name in sorted(fl.values, key=lambda n: not n.startswith("vehicle.")):
        raw = fl.values[name]
        rel = dist[name].relative if name in dist else Relative.NONE
        if rel is Relative.BASE:
            raw = float(raw) * _base_value(base, name)
        elif rel is Relative.TRUTH:
            truth = PARAMETERS[name].truth
            assert truth is not None
            raw = float(raw) * float(values.get(truth, _base_value(base, truth)))
        values[name] = raw
    vehicle_changes: dict[str, Any] = {}
    controller_changes: dict[str, Any] = {}
    gains: dict[str, float] = {}
    v_inertia, c_inertia = list(base.vehicle.inertia_kg_m2), list(base.controller.inertia_kg_m2)
    wind_parts: list[str] = [] if base.wind == "none" else [base.wind]
    sensors, wind_spec = base.sensors, None
    pos, yaw, latency = list(base.initial_pos_ned_m), base.initial_yaw_rad, 0.0
    for name, raw in values.items():
        par = PARAMETERS[name]
        value = float(raw) if par.kind is ParameterKind.NUMBER else math.nan  # a spec's string is ``raw``
        if par.kind is ParameterKind.NUMBER:
            for bound, ok, text in ((par.gt, lambda b: value > b, ">"), (par.ge, lambda b: value >= b, ">="),
                                    (par.lt, lambda b: value < b, "<")):  # fmt: skip
                if bound is not None and not ok(bound):
                    raise ValueError(f"{name} = {value:g} in flight {fl.index}: must be {text} {bound:g}")
        group, _, key = name.partition(".")
        if group == "vehicle":
            if key.startswith("inertia_"):
                v_inertia[_AXES.index(key.split("_")[1])] = value
            elif key == "linear_drag_n_s_m":
                vehicle_changes[key] = (value, value, value)
            else:
                vehicle_changes[key] = value
        elif group == "controller":
            if key.startswith("inertia_"):
                c_inertia[_AXES.index(key.split("_")[1])] = value
            elif key.startswith("gains."):
                gains[key.split(".")[1]] = value
            else:
                controller_changes[key] = value
        elif name == "wind":
            wind_spec = str(raw)
        elif name == "sensors":
            sensors = str(raw)
        elif name == "sensors.paper_fraction":
            sensors = f"paper:{value!r}"
        elif group == "initial":
            if key == "yaw_deg":
                yaw = math.radians(value)
            else:
                pos[("north_m", "east_m", "down_m").index(key)] = value
        elif name == "latency_s":
            latency = value
    if "wind.north_m_s" in values or "wind.east_m_s" in values:
        wind_parts.append(f"constant:{float(values.get('wind.north_m_s', 0.0))!r},{float(values.get('wind.east_m_s', 0.0))!r},0")
    if "wind.dryden_m_s" in values and float(values["wind.dryden_m_s"]) > 0:
        wind_parts.append(f"dryden:{float(values['wind.dryden_m_s'])!r},dir={float(values.get('wind.dryden_dir_deg', 0.0))!r}")
    if "wind.gust_m_s" in values and float(values["wind.gust_m_s"]) > 0:
        wind_parts.append(f"gust:t={float(values.get('wind.gust_t_s', 4.0))!r},amp={float(values['wind.gust_m_s'])!r},"
                          f"dur={GUST_DURATION_S!r},dir={float(values.get('wind.gust_dir_deg', 0.0))!r}")  # fmt: skip
    if wind_spec is not None:
        wind_parts = [] if wind_spec == "none" else [wind_spec, *wind_parts[1 if base.wind != "none" else 0:]]
    vehicle = replace(base.vehicle, inertia_kg_m2=(v_inertia[0], v_inertia[1], v_inertia[2]), **vehicle_changes)
    controller = base.controller
    if gains:
        controller = replace(controller, gains=replace(controller.gains, **gains))
    controller = replace(controller, inertia_kg_m2=(c_inertia[0], c_inertia[1], c_inertia[2]), **controller_changes)
    scenario = replace(base, name=f"{base.name}#{fl.index}", vehicle=vehicle, controller=controller, sensors=sensors,
                       wind="+".join(wind_parts) or "none", seed=fl.seed, initial_pos_ned_m=(pos[0], pos[1], pos[2]),
                       initial_yaw_rad=yaw)  # fmt: skip
    n_physics = round(scenario.controller.sample_time_s / scenario.physics_dt_s)
    if latency and not latency < n_physics * scenario.physics_dt_s:
        raise ValueError(f"latency_s = {latency:g} in flight {fl.index}: must be below the sample time "
                         f"{scenario.controller.sample_time_s:g} s")  # fmt: skip
    return FlightSetup(scenario, latency)


def grid_points(spec: SweepSpec) -> list[dict[str, float | str]]:
    """Every point of the sweep's grid (for the report)."""
    return [dict(zip((d.name for d in spec.grid), combo)) for combo in itertools.product(*(d.args for d in spec.grid))]
