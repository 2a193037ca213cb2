"""``bench/run.py``'s verdict on issue 16's one-vehicle target, from the figures of a run."""

from __future__ import annotations

from bench.run import ONE_VEHICLE_TARGET_X, one_vehicle_verdict


def test_one_vehicle_verdict_reads_the_compiled_closed_loop_against_500x():
    assert ONE_VEHICLE_TARGET_X == 500.0  # issue 16
    assert one_vehicle_verdict({"numba": True, "fast_x_realtime": 574.4}) == "Target ≥ 500× (issue 16): 574×, met."
    assert one_vehicle_verdict({"numba": True, "fast_x_realtime": 458.0}) == "Target ≥ 500× (issue 16): 458×, not met."
    # interpreted kernels are not the configuration the target is about: no verdict either way
    assert "not measured: numba is not installed" in one_vehicle_verdict({"numba": False, "fast_x_realtime": 9.6})
