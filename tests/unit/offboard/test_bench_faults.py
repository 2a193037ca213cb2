"""bench/faults.py's report: every figure it measured, no NaN, one row per flight kind."""

from __future__ import annotations

import pytest

from bench.faults import main, markdown


def result(**lossy):
    return {
        "lossy": {"link": "loss=20,delay=50,jitter=20", "command": "python -m sitl_plant.cli --link ...", "clean_status": "complete",
                  "clean_helix_rms_m": 0.1, "complete": 19, "trials": 20, "rms_ratio_median": 1.5, "rms_ratio_max": 3.0,
                  **lossy},
        "kill": {"trials": 20, "fired": 20, "within_bound": 20, "bound_s": 1.05, "min_s": 1.0, "max_s": 1.02},
    }  # fmt: skip


def test_the_report_says_what_was_measured():
    text = markdown(result())
    assert "| loss=20,delay=50,jitter=20 | 19 of 20 seeds | 0.150 m (median) | 1.50, 3.00 |" in text
    assert "failsafe fired in 20, within COM_OF_LOSS_T + one control period (1.05 s) of the last setpoint in 20" in text
    assert "nan" not in text.lower()


def test_a_run_without_ratios_says_n_a():
    text = markdown(result(rms_ratio_median=None, rms_ratio_max=None))
    assert "| 19 of 20 seeds | n/a | n/a |" in text


def test_quick_says_what_it_runs(capsys):
    """The help said "two kills" while --quick ran one: the smoke test (tests/e2e/test_bench_smoke.py)
    checks what it runs, this what it says."""
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "--quick     one lossy seed of a 1 s hover and one kill (the smoke test)" in capsys.readouterr().out
