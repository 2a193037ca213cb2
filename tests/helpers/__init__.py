"""What the tests share (fixtures in ``tests/conftest.py``; flights of real processes in
``helpers.flights``): where things are, and a clock a test moves by hand."""

from __future__ import annotations

import json
from pathlib import Path

#: The repository's root, and the folder beside it that CI provides (the paper, a real PX4 SITL).
REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
#: The parameters the PX4 SITL there publishes (its README), as a vehicle publishes them.
PX4_PARAMS_JSON = SHARED / "px4-sitl" / "params.json"


def sih_params() -> dict[str, float]:
    """PX4 SIH's published values: ``PX4_PARAMS_JSON``'s, or without it those its README gives."""
    if PX4_PARAMS_JSON.is_file():
        return {k: float(v["value"]) for k, v in json.loads(PX4_PARAMS_JSON.read_text()).items()}
    return {"SIH_MASS": 1.0, "SIH_T_MAX": 5.0, "SIH_IXX": 0.025, "SIH_IYY": 0.025, "SIH_IZZ": 0.03, "SIH_L_ROLL": 0.2,
            "SIH_L_PITCH": 0.2, "SIH_T_TAU": 0.05, "MC_ROLL_P": 6.5, "MC_PITCH_P": 6.5}  # fmt: skip


class FakeClock:
    """A monotonic clock in seconds that only moves when a test sets ``now``."""

    def __init__(self, start_s: float = 100.0) -> None:
        self.now = start_s

    def __call__(self) -> float:
        return self.now
