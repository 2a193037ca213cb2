"""`--json` and summary.json are strict JSON: null, never NaN or Infinity (docs/json.md)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from offboard import jsonout
from offboard.missions import MISSIONS_DIR

from helpers.logs import write_foreign_log


def strict_loads(text: str) -> object:
    """json.loads as JavaScript's JSON.parse reads it: NaN, Infinity, -Infinity are errors."""

    def refuse(word: str) -> None:
        raise ValueError(f"not JSON: {word}")

    return json.loads(text, parse_constant=refuse)


def test_strict_replaces_every_non_finite_number():
    value = {"a": math.nan, "b": [1.0, math.inf, (-math.inf, 2)], "c": np.float64("nan"), "d": np.array([1.0, np.nan]),
             "e": np.int64(3), "f": Path("x/y"), "g": True, "h": None}  # fmt: skip
    assert jsonout.strict(value) == {"a": None, "b": [1.0, None, [None, 2]], "c": None, "d": [1.0, None], "e": 3,
                                     "f": "x/y", "g": True, "h": None}  # fmt: skip
    assert strict_loads(jsonout.dumps(value)) == jsonout.strict(value)


def test_simulate_json_of_a_diverged_flight_is_strict(tmp_path):
    # the paper's Simulation 1 as stated diverges within a second: the "after 5 s" row has no sample
    proc = subprocess.run([sys.executable, "-m", "offboard.cli", "simulate", str(MISSIONS_DIR / "paper-sim1-as-stated.toml"),
                           "--json", "--no-plots", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 3, proc.stderr
    assert "NaN" not in proc.stdout  # what it printed before
    payload = strict_loads(proc.stdout)
    assert payload["status"] == "diverged"
    after = next(p for p in payload["phases"] if p["name"] == "after 5 s")
    assert after["samples"] == 0
    assert after["axes"]["3d"] == {"rms_m": None, "max_m": None, "mean_m": None}
    assert strict_loads((tmp_path / "run" / "summary.json").read_text()) == payload


def test_replay_json_without_commands_is_strict(tmp_path, capsys):
    from offboard.cli import main

    log = write_foreign_log(tmp_path / "gcs.tlog").path  # a ground station's log: no setpoints, so no thrust
    assert main(["replay", str(log), "--json", "--no-plots", "--run-dir", str(tmp_path / "r")]) == 0
    payload = strict_loads(capsys.readouterr().out)
    assert payload["commands"] == "none"
    assert payload["peak_thrust_n"] is None and payload["peak_torques_nm"] == [None, None, None]
    strict_loads((tmp_path / "r" / "summary.json").read_text())


@pytest.mark.parametrize("word", ["NaN", "Infinity", "-Infinity"])
def test_the_strict_reader_of_these_tests_refuses_what_python_writes(word):
    with pytest.raises(ValueError):
        strict_loads(f'{{"x": {word}}}')
