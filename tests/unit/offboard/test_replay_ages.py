"""What ``offboard replay --rerun`` reads of a flight's latency prediction beside its log:
summary.json's latency and observer, series.csv's telemetry ages."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from offboard.commands.replay import ReplayArgumentError, _observed_as_flown, _observer_memory_as_flown, _predicted_latency_as_flown


def _series(folder, rows):
    (folder / "series.csv").write_text("t_s,time_boot_ms,telemetry_age_s\n" + "".join(f"{t},{s},{a}\n" for t, s, a in rows))
    return folder / "flight.tlog"


def test_two_samples_of_one_telemetry_stamp_each_keep_their_own_age(tmp_path):
    """A sample that read the telemetry the one before it read shares its stamp (a real-time
    flight under load: 1.8 s and 1.85 s, both 2844 ms); the record has a sample for each command,
    and each gets its own age, in order (a dict by stamp gave both the second's, 0.1 ms against
    7 ms, and the re-run differed from there). A log that holds only the first command of the
    stamp gives it the first's."""
    log = _series(tmp_path, [(1.75, 2792, 0.009), (1.8, 2844, 0.007), (1.85, 2844, 0.0001), (1.9, 2944, 0.0071)])
    record = SimpleNamespace(meta={"time_boot_ms": np.array([2792, 2844, 2844, 2944, 3044])})
    latency, ages, note = _predicted_latency_as_flown(log, {"predicted_latency_s": 0.01}, record)
    assert latency == 0.01
    assert ages[:4].tolist() == [0.009, 0.007, 0.0001, 0.0071] and math.isnan(ages[4])
    assert "telemetry's ages from series.csv" in note and "observed" not in note
    first_only = SimpleNamespace(meta={"time_boot_ms": np.array([2792, 2844, 2944])})
    assert _predicted_latency_as_flown(log, {"predicted_latency_s": 0.01}, first_only)[1].tolist() == [0.009, 0.007, 0.0071]


def test_the_observer_is_restored_as_flown_and_a_bad_value_is_one_line(tmp_path):
    log = _series(tmp_path, [(0.0, 100, 0.005)])
    record = SimpleNamespace(meta={"time_boot_ms": np.array([100])})
    assert _observed_as_flown({"observed_rate_loop": True}) is True
    assert _observed_as_flown({"observed_rate_loop": None}) is False
    assert _observed_as_flown({}) is False  # a summary from before the observer: at hover, as it flew
    _, _, note = _predicted_latency_as_flown(log, {"predicted_latency_s": 0.1, "observed_rate_loop": True, "observer_memory_s": 1.0}, record)
    assert "state predicted over 100 ms, the rate loop observed (1 s of memory)" in note
    with pytest.raises(ReplayArgumentError, match="observed_rate_loop 'yes' is not true, false or null"):
        _observed_as_flown({"observed_rate_loop": "yes"})


def test_the_observers_memory_is_restored_as_flown_and_a_bad_value_is_one_line(tmp_path):
    """summary.json's ``observer_memory_s``: the memory flown; absent in the flights that
    observed before it (deadbeat, memory 0), which re-run so and say so."""
    log = _series(tmp_path, [(0.0, 100, 0.005)])
    record = SimpleNamespace(meta={"time_boot_ms": np.array([100])})
    assert _observer_memory_as_flown({"observer_memory_s": 1.0}) == 1.0
    assert _observer_memory_as_flown({"observed_rate_loop": True}) == 0.0
    _, _, note = _predicted_latency_as_flown(log, {"predicted_latency_s": 0.1, "observed_rate_loop": True}, record)
    assert "the rate loop observed (deadbeat)" in note
    for bad in ("1", -0.5, float("inf"), True):
        with pytest.raises(ReplayArgumentError, match=r"observer_memory_s .* is not a time \(s, >= 0\)"):
            _observer_memory_as_flown({"observer_memory_s": bad})
