"""How far PX4 SIH's estimate runs from the truth once its GPS stops (sitl-plant's SIM_DR_ACC_ERR).

``offboard fly --ignore-estimator`` holds 5 m on a real PX4 SITL (the offboard flies on as
long as the mission lasts, as a client that does not read ESTIMATOR_STATUS would), the GPS is
stopped from PX4's shell (``sensor_gps_sim stop``: this SIH build never answers
MAV_CMD_INJECT_FAILURE) 10 s into the hold, and a second client on PX4's ground-station link
records LOCAL_POSITION_NED beside HIL_STATE_QUATERNION (SIH's truth; ``bench/px4_estimator.py``'s
recorder). Printed: the horizontal distance of the estimate from the truth at a few times after the
stop (less the mean offset of the 5 s before, where the frames' origins differ), with the b of
1/2 b t^2 each implies, and where the vehicle itself went. With ``--land`` the offboard keeps its
estimator guard: ESTIMATE_LOST hands the vehicle to PX4's Land about 5 s after the stop, and the
truth's horizontal speed is printed through the blind landing, then the estimate's error through the
landing and 15 s after it.

    python bench/px4_dead_reckoning.py [--speed F] [--land]

Needs a PX4 SITL (``$PX4_SITL`` or ``../shared/px4-sitl/px4-sitl``); says so in one line without.
The stop is timed from the last estimate recorded before PX4's shell is called (the call itself
takes a few tenths of a second of wall time: at ``--speed 4`` up to a second or so of PX4's).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.px4_estimator import EARTH_RADIUS_M, GroundStationRecord, _unique, record_ground_station  # noqa: E402
from bench.px4sitl import SKIP_REASON, px4_launcher, running_px4  # noqa: E402

HOLD_S = 70.0  # the mission: a hold at 5 m this long
STOP_AFTER_S = 10.0  # vehicle seconds into the hold when the GPS is stopped
REPORT_AT_S = (2.0, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0, 40.0)
AFTER_LANDING_S = 15.0  # --land: vehicle seconds recorded after the flight has ended (landed, disarmed)


def fly(folder: Path, speed: float, land: bool = False) -> tuple[GroundStationRecord, float]:
    """One hold on a fresh PX4 SITL, its GPS stopped: the ground-station record and the stop's time
    (boot s). ``land``: the offboard's estimator guard on (it hands the vehicle to Land)."""
    mission = folder / "hold.toml"
    mission.write_text('[mission]\nname = "hold"\nframe = "paper-zup"\nangle_unit = "rad"\nstart = [0, 0, 0]\nstart_yaw = 0\n\n'
                       f'[[mission.segment]]\ntype = "hold"\nname = "hold"\nposition = [0, 0, 5]\nyaw = 0\nuntil_s = {HOLD_S:g}\n')  # fmt: skip
    record, stop = GroundStationRecord(), threading.Event()
    stderr = folder / "fly.stderr"
    with running_px4(folder / "px4", speed=speed) as px4:
        recorder = threading.Thread(target=record_ground_station, args=(px4.gcs_listen_port, stop, record), daemon=True)
        recorder.start()
        with stderr.open("w") as err:
            fly = subprocess.Popen([sys.executable, "-m", "offboard.cli", "fly", str(mission), "--connect",
                                    f"udpin:127.0.0.1:{px4.api_listen_port}", "--run-dir", str(folder / "run"), "--no-plots",
                                    *([] if land else ["--ignore-estimator", "--lost-track-m", "inf"]),
                                    *(["--clock", "vehicle"] if speed != 1.0 else [])],
                                   stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)  # fmt: skip
        try:
            deadline = time.monotonic() + 120.0
            while "mission started" not in stderr.read_text() and fly.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            if fly.poll() is not None or not record.estimates:
                raise RuntimeError(f"the flight did not start: {stderr.read_text().strip().splitlines()[-1:]}")
            time.sleep(STOP_AFTER_S / speed)
            stopped_at = record.estimates[-1][0]
            px4.shell("sensor_gps_sim", "stop")
            fly.wait(timeout=HOLD_S / speed * 4 + 60)
            if land:
                time.sleep(AFTER_LANDING_S / speed)  # the estimate on the ground too
        finally:
            if fly.poll() is None:
                fly.kill()
                fly.wait()
            stop.set()
            recorder.join(timeout=5)
    return record, stopped_at


def _estimate_error(record: GroundStationRecord, stopped_at: float) -> tuple[np.ndarray, ...]:
    """(t, estimates, truth north-east, truth velocity north-east, estimate minus truth north-east) at
    the estimates' times; the error less its mean over the 5 s before the stop (the frames' origins)."""
    est, tru = _unique(record.estimates), _unique(record.truths)
    if len(est) < 100 or len(tru) < 100:
        raise ValueError(f"too little recorded on the ground-station link ({len(est)} estimates, {len(tru)} truths)")
    lat0, lon0 = tru[0, 1], tru[0, 2]
    north = np.radians(tru[:, 1] - lat0) * EARTH_RADIUS_M
    east = np.radians(tru[:, 2] - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    t = est[:, 0]
    truth = np.stack([np.interp(t, tru[:, 0], north), np.interp(t, tru[:, 0], east)], axis=1)
    truth_vel = np.stack([np.interp(t, tru[:, 0], tru[:, 4]), np.interp(t, tru[:, 0], tru[:, 5])], axis=1)
    error = est[:, 1:3] - truth
    before = (t > stopped_at - 5.0) & (t <= stopped_at)
    error -= error[before].mean(axis=0)
    return t, est, truth, truth_vel, error


def acceleration_error(record: GroundStationRecord, stopped_at: float, fit_s: float = 4.0) -> np.ndarray:
    """b (north, east; m/s^2): the estimate's error over the first ``fit_s`` after the stop fitted by
    1/2 b t^2 + c t (least squares; c: what velocity error there was at the stop)."""
    t, _, _, _, error = _estimate_error(record, stopped_at)
    after = t[(t > stopped_at) & (t <= stopped_at + fit_s)] - stopped_at
    if len(after) < 10:
        raise ValueError(f"too little recorded in the {fit_s:g} s after the stop ({len(after)} estimates)")
    design = np.stack([0.5 * after**2, after], axis=1)
    return np.linalg.lstsq(design, error[(t > stopped_at) & (t <= stopped_at + fit_s)], rcond=None)[0][0]


def drift(record: GroundStationRecord, stopped_at: float) -> list[dict]:
    """Estimate minus truth (horizontal, m) at ``REPORT_AT_S`` after the stop, the b it implies,
    the estimate's velocity error (horizontal, m/s), the truth's distance from where it was at the stop."""
    t, est, truth, truth_vel, error = _estimate_error(record, stopped_at)
    at_stop = truth[np.searchsorted(t, stopped_at)]
    rows = []
    for after in REPORT_AT_S:
        i = int(np.searchsorted(t, stopped_at + after))
        if i >= len(t):
            break
        d = float(np.hypot(*error[i]))
        rows.append({"after_s": after, "estimate_error_m": d, "b_m_s2": 2.0 * d / after**2,
                     "velocity_error_m_s": float(np.hypot(*(est[i, 4:6] - truth_vel[i]))),
                     "vehicle_moved_m": float(np.hypot(*(truth[i] - at_stop)))})  # fmt: skip
    return rows


def landing_speeds(record: GroundStationRecord, stopped_at: float, b: np.ndarray, every_s: float = 0.5,
                   until_s: float = 20.0) -> list[tuple[float, float, float, float]]:  # fmt: skip
    """(time after the stop, the truth's horizontal speed, its descent rate (m/s), the cosine of its
    horizontal velocity with the estimate's acceleration error ``b`` (``acceleration_error``; nan at
    rest)), every ``every_s``. A vehicle
    held "level" by an estimate whose tilt is off by b / g would accelerate at -b: cosine -1."""
    tru = _unique(record.truths)
    if len(tru) < 100:
        raise ValueError(f"too little recorded on the ground-station link ({len(tru)} truths)")
    rows = []
    for k in range(int(until_s / every_s) + 1):
        t = stopped_at + k * every_s
        if t > tru[-1, 0]:
            break
        vn, ve, vd = (float(np.interp(t, tru[:, 0], tru[:, 4 + i])) for i in range(3))
        speed = math.hypot(vn, ve)
        cosine = (vn * b[0] + ve * b[1]) / (speed * math.hypot(*b)) if speed > 0.01 and math.hypot(*b) > 0 else math.nan
        rows.append((k * every_s, speed, vd, cosine))
    return rows


def print_drift(rows: list[dict]) -> None:
    """``drift``'s rows as a table on stdout."""
    print("after the stop | estimate from the truth | b of 1/2 b t^2 | its velocity error | the vehicle moved")
    for r in rows:
        print(f"{r['after_s']:11.0f} s | {r['estimate_error_m']:19.2f} m | {r['b_m_s2']:9.2f} m/s^2 | "
              f"{r['velocity_error_m_s']:14.2f} m/s | {r['vehicle_moved_m']:13.2f} m")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speed", type=float, default=1.0, help="PX4 SITL --speed (default: real time)")
    parser.add_argument("--land", action="store_true", help="keep the estimator guard: the truth's speed through PX4's blind Land")
    args = parser.parse_args(argv)
    if px4_launcher() is None:
        print(f"px4_dead_reckoning: {SKIP_REASON}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="px4-dead-reckoning-") as tmp:
        try:
            record, stopped_at = fly(Path(tmp), args.speed, land=args.land)
            rows = drift(record, stopped_at)
            b = acceleration_error(record, stopped_at)
            speeds = landing_speeds(record, stopped_at, b) if args.land else []
        except (RuntimeError, ValueError, AssertionError) as exc:
            print(f"px4_dead_reckoning: {str(exc).splitlines()[0]}", file=sys.stderr)
            return 1
    if args.land:
        print(f"PX4 SIH at --speed {args.speed:g}, GPS stopped {STOP_AFTER_S:g} s into an Offboard hold; offboard fly's guard lands it.")
        print(f"The estimate's acceleration error b (its first 4 s): ({b[0]:+.2f}, {b[1]:+.2f}) m/s^2 north, east.")
        print("after the stop | horizontal speed | descent | cos(velocity, b)")
        for after, speed, down, cosine in speeds:
            print(f"{after:11.1f} s | {speed:12.2f} m/s | {down:+5.2f} m/s | " + ("–" if math.isnan(cosine) else f"{cosine:+.2f}"))
        print("and the estimate, through the landing and after it:")
        print_drift(rows)
        return 0
    print(f"PX4 SIH at --speed {args.speed:g}, GPS stopped {STOP_AFTER_S:g} s into an Offboard hold flown on the estimate:")
    print_drift(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
