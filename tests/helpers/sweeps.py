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
