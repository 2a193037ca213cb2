"""When each of the offboard's setpoints reached PX4, in PX4's own clock (its ULog).

``offboard fly`` designs the law for a latency it measures from its own side (``latency N ms
for the design``: the TIMESYNC round trip and one telemetry period, in the offboard's clock). On
the vehicle's side that latency is the time from the estimate a setpoint answers (the
SET_ATTITUDE_TARGET's ``time_boot_ms`` echoes the ATTITUDE it read, stamped by PX4) to PX4
taking the setpoint (the ``vehicle_attitude_setpoint`` record its MAVLink receiver publishes on
receipt, stamped with PX4's ``hrt_absolute_time()``, the clock of ``time_boot_ms``). Both stamps
are PX4's, so the difference holds at any ``--speed``: it is the latency in the vehicle's time,
which the offboard's round trip does not give once the vehicle's clock runs faster than its
own (docs/controller-design.md, "PX4 at --speed 4"). ``offboard fly`` measures the same latency
over MAVLink from PX4's ATTITUDE_TARGET echo (``offboard.echo``); PX4's own log is the
independent check of that (``tests/e2e/test_px4_flight.py`` compares the two).

Each setpoint is found in PX4's log by its quaternion, which PX4 copies float for float into
``q_d``: the first record with the same four floats after the previous match, within
``WINDOW_MS`` of the stamp the setpoint answers. A setpoint whose attitude equals the one sent
before it cannot be told from it and is left out (the holds before and after the mission), as
is one PX4's logger did not keep.

    python bench/px4_log.py RUN_DIR PX4_DIR

(RUN_DIR: ``offboard fly``'s run folder with flight.tlog and summary.json; PX4_DIR: the PX4
SITL's working folder, whose ``log/`` holds the flight's .ulg, or the .ulg itself.) Needs pyulog
(``make bench`` and ``make test`` install it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from offboard.echo import latency_figures as echo_latency_figures  # noqa: E402
from offboard import jsonout  # noqa: E402
from offboard.model.rotations import euler_from_quat_floats  # noqa: E402

#: How long after the stamp it answers a setpoint may reach PX4 and still be paired with a record, ms.
WINDOW_MS = 500.0


def pair_setpoints(stamps_ms: np.ndarray, sent_q: np.ndarray, logged_us: np.ndarray, logged_q: np.ndarray,
                   window_ms: float = WINDOW_MS) -> np.ndarray:  # fmt: skip
    """The latency of each setpoint, ms: the time of its record in PX4's log less the stamp it
    answers (module docstring); NaN where it is left out.

    Parameters
    ----------
    stamps_ms : ndarray (n,)
        The ``time_boot_ms`` each setpoint answers, in the order sent.
    sent_q : ndarray (n, 4)
        Their attitude quaternions (w, x, y, z), float32 as sent.
    logged_us : ndarray (m,)
        PX4's ``vehicle_attitude_setpoint`` timestamps, us, in the order logged.
    logged_q : ndarray (m, 4)
        Their ``q_d``, float32.
    window_ms : float
        The longest latency paired.
    """
    stamps = np.asarray(stamps_ms, dtype=float)
    sent = np.asarray(sent_q, dtype=np.float32)
    logged_ms = np.asarray(logged_us, dtype=float) / 1000.0
    index: dict[bytes, list[int]] = {}
    for j, q in enumerate(np.asarray(logged_q, dtype=np.float32)):
        index.setdefault(q.tobytes(), []).append(j)
    out = np.full(len(stamps), np.nan)
    after = 0  # PX4 logs the setpoints in the order they came
    for i, (stamp, q) in enumerate(zip(stamps, sent, strict=True)):
        if i > 0 and np.array_equal(q, sent[i - 1]):
            continue  # the same attitude again: which record is whose cannot be told
        for j in index.get(q.tobytes(), ()):
            if j >= after and stamp <= logged_ms[j] <= stamp + window_ms:
                out[i] = logged_ms[j] - stamp
                after = j + 1
                break
    return out


def px4_ulog(px4_dir: Path) -> Path:
    """The one .ulg of a PX4 SITL's working folder (``<dir>/log/<date>/*.ulg``), or ``px4_dir`` if it is one."""
    if px4_dir.suffix == ".ulg":
        return px4_dir
    logs = sorted(px4_dir.glob("log/*/*.ulg"))
    if len(logs) != 1:
        raise ValueError(f"{px4_dir}: {len(logs)} PX4 logs (.ulg) under log/, one expected")
    return logs[0]


def sent_setpoints(flight_tlog: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ms, quaternions) of the SET_ATTITUDE_TARGETs an ``offboard fly`` tlog holds, in order."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(flight_tlog), dialect="common")
    stamps, quats = [], []
    try:
        while (msg := log.recv_match(type="SET_ATTITUDE_TARGET")) is not None:
            stamps.append(float(msg.time_boot_ms))
            quats.append(msg.q)
    finally:
        log.close()
    return np.array(stamps), np.array(quats, dtype=np.float32).reshape(-1, 4)


def _topic(ulog: Path, name: str) -> dict:
    """The fields of one uORB topic's first instance in a PX4 log; ValueError (one line) for a file
    that is not one, a log without the topic, or without pyulog."""
    try:
        from pyulog import ULog
        from pyulog.exceptions import ULogException
    except ImportError:
        raise ValueError("reading PX4's log needs pyulog (make bench and make test install it)") from None
    try:
        data = ULog(str(ulog), [name]).data_list
    except (ULogException, EOFError) as exc:
        raise ValueError(f"{ulog}: not a PX4 log (ULog): {exc}") from None
    if not data:
        raise ValueError(f"{ulog}: no {name} in PX4's log")
    return data[0].data


def logged_setpoints(ulog: Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps us, q_d) of ``vehicle_attitude_setpoint`` in a PX4 log; ValueError (one line)
    for a file that is not one, or without pyulog."""
    d = _topic(ulog, "vehicle_attitude_setpoint")
    return np.asarray(d["timestamp"], dtype=float), np.stack([d[f"q_d[{k}]"] for k in range(4)], axis=1).astype(np.float32)


def true_roll_pitch(ulog: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps us, roll rad, pitch rad) of the simulator's own attitude in a PX4 SITL's log
    (``vehicle_attitude_groundtruth``: SIH's truth, not EKF2's estimate, which ATTITUDE carries),
    on the clock of ATTITUDE's ``time_boot_ms``; ValueError (one line) as ``logged_setpoints``."""
    d = _topic(ulog, "vehicle_attitude_groundtruth")
    euler = np.array([euler_from_quat_floats(*q) for q in zip(*(np.asarray(d[f"q[{k}]"], dtype=float) for k in range(4)))])
    return np.asarray(d["timestamp"], dtype=float), euler[:, 0], euler[:, 1]


def setpoint_latencies_ms(flight_tlog: Path, px4_dir: Path) -> np.ndarray:
    """``pair_setpoints`` of a flight's tlog against PX4's log (NaN: left out)."""
    stamps, quats = sent_setpoints(flight_tlog)
    logged_us, logged_q = logged_setpoints(px4_ulog(px4_dir))
    return pair_setpoints(stamps, quats, logged_us, logged_q)


def latency_figures(latencies_ms: np.ndarray) -> dict:
    """How many setpoints were sent, and ``offboard.echo.latency_figures`` of those paired
    (the same figures ``offboard fly`` gives of the ATTITUDE_TARGET echo)."""
    return {"sent": int(latencies_ms.size), **echo_latency_figures(latencies_ms.tolist())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python bench/px4_log.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="offboard fly's run folder (flight.tlog, summary.json)")
    parser.add_argument("px4_dir", type=Path, help="the PX4 SITL's working folder (its log/), or the .ulg")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    tlog = args.run_dir / "flight.tlog"
    try:
        figures = latency_figures(setpoint_latencies_ms(tlog, args.px4_dir))
    except (OSError, ValueError, KeyError) as exc:
        print(f"px4_log: {exc}", file=sys.stderr)
        return 1
    summary = args.run_dir / "summary.json"
    designed = json.loads(summary.read_text()).get("predicted_latency_s") if summary.is_file() else None
    figures["designed_ms"] = None if designed is None else round(float(designed) * 1000.0, 2)
    if args.json:
        print(jsonout.dumps(figures))
        return 0
    if figures["paired"] == 0:
        print(f"px4_log: none of the {figures['sent']} setpoints of {tlog} found in PX4's log", file=sys.stderr)
        return 1
    print(f"{figures['paired']} of {figures['sent']} setpoints found in PX4's log: latency in PX4's clock (from the "
          f"ATTITUDE stamp each answers to PX4 taking it) p50 {figures['p50_ms']:g} ms, p90 {figures['p90_ms']:g} ms, "
          f"max {figures['max_ms']:g} ms" + ("" if designed is None else f"; the law was designed for {figures['designed_ms']:g} ms"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
