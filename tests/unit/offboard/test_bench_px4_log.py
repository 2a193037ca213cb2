"""bench/px4_log.py: pairing the offboard's setpoints with PX4's log of them (the flights' own
logs are read by tests/e2e/test_px4_flight.py against a real PX4)."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from bench.px4_log import WINDOW_MS, latency_figures, main, pair_setpoints, px4_ulog, sent_setpoints
from offboard.model.tlog import TlogWriter


def quats(*angles: float) -> np.ndarray:
    """Distinct unit quaternions (a roll of each angle), float32 as MAVLink carries them."""
    return np.array([(np.cos(a / 2), np.sin(a / 2), 0.0, 0.0) for a in angles], dtype=np.float32)


def test_each_setpoint_pairs_with_its_own_record_in_order_and_the_latency_is_the_vehicles_clock():
    sent = quats(0.1, 0.2, 0.3, 0.4)
    stamps = np.array([1000.0, 1050.0, 1100.0, 1150.0])
    # PX4's log: another module's setpoint first, then ours 4, 12, 8 ms after their stamps; the
    # fourth was not kept by PX4's logger
    logged_q = np.vstack([quats(0.9), sent[:3]])
    logged_us = np.array([990_000.0, 1_004_000.0, 1_062_000.0, 1_108_000.0])
    lat = pair_setpoints(stamps, sent, logged_us, logged_q)
    np.testing.assert_allclose(lat[:3], [4.0, 12.0, 8.0])
    assert np.isnan(lat[3])
    assert latency_figures(lat) == {"sent": 4, "paired": 3, "p50_ms": 8.0, "p90_ms": 11.2, "max_ms": 12.0}


def test_a_repeated_attitude_is_left_out_and_a_record_is_never_paired_twice_or_before_its_stamp():
    a, b = quats(0.1, 0.2)
    sent = np.array([a, a, b, a])  # the second a cannot be told from the first; the last a is new again
    stamps = np.array([0.0, 50.0, 100.0, 150.0])
    logged_q = np.array([a, a, b, a])
    logged_us = np.array([4_000.0, 54_000.0, 104_000.0, 140_000.0])  # the last a logged before its stamp
    lat = pair_setpoints(stamps, sent, logged_us, logged_q)
    assert lat[0] == 4.0 and np.isnan(lat[1]) and lat[2] == 4.0
    assert np.isnan(lat[3])  # 140 ms < its stamp 150 ms: not its record (nor a's first, already paired)
    # beyond the window: not paired
    late = pair_setpoints(np.array([0.0]), quats(0.1), np.array([(WINDOW_MS + 1) * 1000.0]), quats(0.1))
    assert np.isnan(late[0]) and latency_figures(late)["paired"] == 0


def test_the_sent_setpoints_are_read_from_a_tlog_as_offboard_fly_writes_it(tmp_path):
    tlog = tmp_path / "flight.tlog"
    mav = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
    q = quats(0.1, 0.2)
    log = TlogWriter(tlog)
    for k, stamp in enumerate((1000, 1050)):
        log.write(k * 50_000, mavlink.MAVLink_attitude_message(stamp, 0.1, 0, 0, 0, 0, 0).pack(mav))
        msg = mavlink.MAVLink_set_attitude_target_message(stamp, 1, 1, 0, list(map(float, q[k])), 0, 0, 0, 0.5)
        log.write(k * 50_000 + 10, msg.pack(mav))
    log.close()
    stamps, sent = sent_setpoints(tlog)
    np.testing.assert_array_equal(stamps, [1000.0, 1050.0])
    np.testing.assert_array_equal(sent, q)


def test_a_folder_without_one_px4_log_or_a_missing_run_is_one_line(tmp_path, capsys):
    with pytest.raises(ValueError, match="0 PX4 logs"):
        px4_ulog(tmp_path)
    assert main([str(tmp_path / "nowhere"), str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("px4_log: ")


def test_a_file_that_is_not_a_px4_log_is_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    mav = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)
    log = TlogWriter(run / "flight.tlog")
    log.write(0, mavlink.MAVLink_set_attitude_target_message(1000, 1, 1, 0, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0.5).pack(mav))
    log.close()
    (tmp_path / "px4" / "log" / "2026-12-05").mkdir(parents=True)
    (tmp_path / "px4" / "log" / "2026-12-05" / "bad.ulg").write_bytes(b"junkjunkjunk")
    assert main([str(run), str(tmp_path / "px4")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a PX4 log (ULog)" in err[0], err
