"""bench/px4_own.py's figures of a flight of PX4's own controller, on flights made here (the flight
itself needs a PX4: ``python bench/px4_own.py``; tests/e2e/test_px4_own.py flies one), and
bench/design.py's lines setting it beside the designed law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.design import MISSIONS, _own_lines
from bench.px4_own import OwnFlight, figures, main
from offboard.missions import load_mission

HELIX = load_mission(MISSIONS / "paper-helix.toml").trajectory


def _flight(offset_north_m: float, hold_roll_deg: float) -> OwnFlight:
    """The helix flown ``offset_north_m`` off its reference throughout, level except for a
    constant roll in the hold at 12 m (12-25 s)."""
    flight = OwnFlight()
    for n in range(int(round(HELIX.duration_s / 0.05)) + 1):
        t = n * 0.05
        ref = HELIX.reference(t)
        pos = ref.pos_ned_m + np.array([offset_north_m, 0.0, 0.0]) if t > 0 else np.zeros(3)  # starts on the ground
        flight.t_s.append(t)
        flight.ref_ned_m.append(tuple(ref.pos_ned_m))
        flight.pos_ned_m.append(tuple(pos))
        flight.roll_pitch_rad.append((math.radians(hold_roll_deg) if 12.0 <= t < 25.0 else 0.0, 0.0))
    return flight


def test_figures_read_the_helix_and_the_holds_second_half_as_the_law_s_flights_do():
    f = figures(_flight(0.2, 3.0), HELIX)
    assert f["status"] == "complete"
    assert f["moving_rms_m"] == pytest.approx(0.2)  # the helix's 5-11.9 s
    assert f["hold_rms_m"] == pytest.approx(0.2)  # the hold at 12 m, 18.5-25 s (the descent's is a landing)
    assert f["hold_tilt_max_deg"] == pytest.approx(3.0)
    assert f["duration_s"] == pytest.approx(40.0)


def test_a_flight_that_never_started_has_only_its_status():
    assert figures(OwnFlight(status="PX4 refused OFFBOARD"), HELIX) == {"status": "PX4 refused OFFBOARD"}


def test_own_lines_set_px4s_own_controller_beside_the_designed_law_on_the_same_mission():
    def row(controller, condition, moving, hold_rms, tilt):
        return {"vehicle": "real PX4", "mission": "paper-helix.toml", "controller": controller, "condition": condition,
                "moving_rms_m": moving, "hold_rms_m": hold_rms, "hold_tilt_max_deg": tilt}  # fmt: skip

    lines = _own_lines([row("designed", "real time", 0.097, 0.071, 5.2), row("px4-own", "real time", 1.03, 0.444, 2.4),
                        row("px4-own", "--speed 4, vehicle clock", 1.1, 0.17, 1.8)])  # no designed flight at --speed 4 here
    assert [x for x in lines if x.startswith("- ")] == [
        "- paper-helix.toml, real time: designed law moving RMS 0.097 m, hold RMS 0.071 m, hold tilt 5.2 deg; "
        "PX4's own moving RMS 1.030 m, hold RMS 0.444 m, hold tilt 2.4 deg"
    ]
    assert _own_lines([row("designed", "real time", 0.097, 0.071, 5.2)]) == []


def test_a_bad_mission_or_argument_is_one_line_before_any_px4_starts(tmp_path, capsys):
    (tmp_path / "bad.toml").write_text("x = [\n")
    assert main(["--mission", str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("px4_own: ") and "bad.toml" in err[0] and "TOML" in err[0]
    assert main(["--mission", str(tmp_path / "missing.toml")]) == 2
    assert "no such file" in capsys.readouterr().err
    for args in (["--repeat", "0"], ["--speed", "-1"], ["--speed", "nan"], ["--start-after", "-1"], ["--start-after", "inf"]):
        with pytest.raises(SystemExit) as exit_:
            main(args)
        assert exit_.value.code == 2 and args[0] in capsys.readouterr().err


def test_each_flight_starts_when_asked(monkeypatch, tmp_path, capsys):
    import bench.px4_own as px4_own

    flown = []
    monkeypatch.setattr(px4_own, "px4_launcher", lambda: "px4")
    monkeypatch.setattr(px4_own.tempfile, "mkdtemp", lambda prefix: str(tmp_path))
    monkeypatch.setattr(px4_own, "fly_px4_own", lambda mission, folder, speed, start_after_s: flown.append((speed, start_after_s)) or {"status": "complete"})
    assert main(["--speed", "4", "--repeat", "2", "--start-after", "33"]) == 0
    assert flown == [(4.0, 33.0)] * 2
