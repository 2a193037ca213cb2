"""The figures docs/reproduction.md quotes are what the scenario files fly (`offboard simulate`).

Each entry finds a number in the page by the words around it and recomputes it from the run of
its scenario; a doc that drifts from the code (the issue found 0.078 m quoted where the command
printed 0.058 m) fails here. A figure quoted to d decimals must be the run's value rounded to d.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from offboard.metrics import end_error_m
from helpers import REPO
from helpers.scenarios import flown

PAGE = (REPO / "docs" / "reproduction.md").read_text()


def rms_3d(name: str, phase: str) -> float:
    return flown(name)[1].phase(phase).axes["3d"].rms_m


def mean_error(name: str, axis: int, t0: float, t1: float, up: bool = False) -> float:
    record = flown(name)[0]
    t = record["t_s"]
    value = float(np.mean(record.error_ned_m[(t > t0) & (t < t1), axis]))
    return -value if up else value


# (pattern with one group: the number as the page writes it, scenario, how the run gives it)
FIGURES = [
    (r"helix \(0–12 s\), incl\. the 2\.8 m initial step \| ([0-9.]+) m", lambda: rms_3d("paper-sim1.toml", "helix")),
    (r"ψ = −π/2 \(12–25 s\) \| ([0-9.]+) m \(the switch\)", lambda: rms_3d("paper-sim1.toml", "hold-12m")),
    (r"ψ = 0 \(25–40 s\) \| ([0-9.]+) m \(the 12 m step\)", lambda: rms_3d("paper-sim1.toml", "descent")),
    (r"u between −([0-9]+) N", lambda: -flown("paper-sim1.toml")[1].min_thrust_n),
    (r"and \+([0-9]+) N \(hover is 4\.9 N\)", lambda: flown("paper-sim1.toml")[1].peak_thrust_n),
    (r"tilt up to ([0-9]+)°\. The 12 m descent", lambda: flown("paper-sim1.toml")[1].peak_tilt_deg),
    (r"flies\s+([0-9.]+) m high over t = 9–12 s", lambda: -mean_error("paper-sim2-noise-free.toml", 2, 9.0, 12.0, up=True)),
    (r"mean z error of ([0-9.]+) m over\s+t = 5–12 s", lambda: abs(mean_error("paper-sim2-integral.toml", 2, 5.0, 12.0))),
    (r"the true z error grows to about ([0-9.]+) m by t = 12 s", lambda: abs(float(flown("paper-sim2.toml")[0].error_ned_m[-1, 2]))),
    (r"`paper-sim3\.toml` converges \(3D RMS ([0-9.]+) m after 5 s\)", lambda: rms_3d("paper-sim3.toml", "after 5 s")),
    (r"corners are taken with tilts up to ([0-9]+)°", lambda: flown("paper-sim3.toml")[1].peak_tilt_deg),
    (r"u up to ([0-9]+) N\), because", lambda: flown("paper-sim3.toml")[1].peak_thrust_n),
    (r"tilt to 35°:\s+3D RMS ([0-9.]+) m after 5 s", lambda: rms_3d("paper-sim1-rigid-body.toml", "after 5 s")),
    (r"flown to its end but ([0-9.]+) m from the\s+reference", lambda: end_error_m(flown("paper-sim1-rigid-body-plain.toml")[0])),
]


@pytest.mark.parametrize("pattern, value", FIGURES, ids=[f[0][:40] for f in FIGURES])
def test_the_page_quotes_what_the_scenario_flies(pattern, value):
    found = re.search(pattern, PAGE)
    assert found, f"docs/reproduction.md no longer says: {pattern}"
    text = found.group(1)
    decimals = len(text.split(".")[1]) if "." in text else 0
    actual = value()
    assert math.isfinite(actual)
    assert f"{actual:.{decimals}f}" == text, f"the page says {text}, the run gives {actual:.4f}"
