"""Small sweep files for the sweep tests: short flights of the bundled rigid-body helix."""

from __future__ import annotations

from pathlib import Path

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
SCENARIO = MISSIONS / "paper-sim1-rigid-body.toml"


def write_sweep(folder: Path, body: str = "", *, flights: int = 6, seed: int = 3, duration_s: float = 0.5,
                name: str = "mini", scenario: Path = SCENARIO) -> Path:  # fmt: skip
    """A sweep file in ``folder`` over ``scenario`` with ``body`` (its [parameters] tables)."""
    path = folder / f"{name}.toml"
    path.write_text(f'[sweep]\nname = "{name}"\nscenario = "{scenario}"\nflights = {flights}\nseed = {seed}\n'
                    f"duration_s = {duration_s}\n{body}")  # fmt: skip
    return path


#: Table II-style beliefs, a gridded motor lag, wind, latency, start offsets and the paper's noise: every kind of
#: parameter the batch flies.
MIXED = """
[parameters.controller]
mass_kg = { uniform = [0.8, 1.2], relative = "truth" }
inertia_xx_kg_m2 = { uniform = [0.7, 1.3], relative = "truth" }
[parameters.vehicle]
motor_time_constant_s = { grid = [0.01, 0.03] }
mass_kg = { normal = [0.5, 0.02] }
[parameters.wind]
dryden_m_s = { uniform = [0, 5] }
[parameters]
latency_s = { choice = [0.0, 0.01] }
"initial.down_m" = { uniform = [-0.5, 0.0] }
"sensors.paper_fraction" = { choice = [0.0, 0.05] }
"""


def full_helix_errors(indices: list[int]) -> list[dict]:
    """Flights ``indices`` of the bundled Table II sweep over the helix's full 12 s, batched
    together and by ``simulate``: for each, the batch's largest position difference from
    ``simulate`` (m), the spread of ``simulate`` itself under a rounding-level change (the true
    mass times 1 + 4.4e-16, two ulps: how much this flight amplifies rounding), the samples each
    flew and their statuses. Imports here, so that a subprocess with SITL_PLANT_NO_NUMBA=1 can
    run it on the interpreted kernels."""
    from dataclasses import replace

    import numpy as np

    from offboard.controller.paper import PaperController
    from offboard.inprocess import simulate
    from offboard.sweep.batch import fly_group
    from offboard.sweep.spec import flight, load_sweep, scenario_of

    spec = load_sweep(MISSIONS / "sweep-table2.toml")
    setups = [scenario_of(spec, flight(spec, i)) for i in indices]
    out = []
    for setup, series in zip(setups, fly_group(setups)):
        sc = setup.scenario

        def fly(vehicle):  # noqa: ANN001, ANN202 - simulate() as fly_one calls it
            return simulate(vehicle, PaperController(sc.controller, vehicle_model=sc.model), sc.trajectory, drive=sc.drive,
                            model=sc.model, physics_dt_s=sc.physics_dt_s, duration_s=sc.flight_duration_s, ground=sc.ground,
                            initial_pos_ned_m=sc.initial_pos_ned_m, initial_yaw_rad=sc.initial_yaw_rad,
                            latency_s=setup.latency_s).record  # fmt: skip

        ref = fly(sc.vehicle)
        nudged = fly(replace(sc.vehicle, mass_kg=sc.vehicle.mass_kg * (1 + 4.4e-16)))
        n = min(len(ref), len(series.t_s))
        out.append({"duration_s": sc.flight_duration_s, "batch_samples": len(series.t_s), "samples": len(ref),
                    "batch_status": series.status.name, "status": ref.status.name,
                    "error_m": float(np.max(np.abs(series.pos_ned_m[:n] - ref["pos_ned_m"][:n]))),
                    "spread_m": float(np.max(np.abs(nudged["pos_ned_m"] - ref["pos_ned_m"])))})  # fmt: skip
    return out
