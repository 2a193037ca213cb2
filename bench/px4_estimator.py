"""What PX4 SIH's estimator tells the offboard, against SIH's own truth (issue 11's PX4 holds).

``offboard fly`` closes its loops on EKF2's LOCAL_POSITION_NED, as any offboard does. This flies
the paper helix on a real PX4 SITL (`offboard fly`, no controller file) while a second client on
PX4's ground-station link records HIL_STATE_QUATERNION, which PX4 fills from SIH's ground truth,
beside LOCAL_POSITION_NED on the same link; then compares them:

- over the airborne flight: EKF2's position and velocity error (RMS, north, east, down), and the
  error of the velocity the law reads (``[law] velocity_from_position_s``, ConsistentVelocity),
  as the flight read it (its T, identified in flight with ``velocity_from_position_identify``)
  and, offline on the same record, with other T and with the T the whole record identifies
  (``offboard.controller.velocity.estimate_noise``: is the identified T the one the truth favours?);
- over the second half of the hold at 12 m (18.5-25 s of the mission): how far the vehicle really
  wanders (its true position's standard deviation) while the estimate it is held on stays put,
  EKF2's mean velocity error there, the tilt the flight shows (its ATTITUDE, as the tests and
  ``make bench`` measure it), the vehicle's true tilt (HIL_STATE_QUATERNION's attitude) and
  EKF2's mean attitude error (roll and pitch);
- EKF2's heading (ATTITUDE's yaw) against SIH's (HIL_STATE_QUATERNION's attitude): its largest
  error in the first 5 s of the mission, where EKF2 aligns its heading in flight 1.5 m above the
  take-off point (``offboard fly --takeoff-heading-hold``, docs/controller-design.md), and after.

    python bench/px4_estimator.py [--speed F] [--json] [-- OFFBOARD FLY OPTIONS]

(``-- --takeoff-heading-hold off`` flies the helix without the take-off heading hold.)

Needs a PX4 SITL (``$PX4_SITL`` or ``../shared/px4-sitl/px4-sitl``); says so in one line without.
HIL_STATE_QUATERNION carries no usable time (PX4 sends time_usec 0): each truth sample takes the
time of the LOCAL_POSITION_NED before it on the same link, and the two are aligned by the lag
(within +-50 ms) that best correlates their vertical velocities.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.px4sitl import SKIP_REASON, px4_launcher, running_px4  # noqa: E402
from offboard.controller.design import AxisGains, Design, EstimateErrorSpectra, axis_plants, noise_response, with_gains  # noqa: E402
from offboard.controller.tuning import design_for_vehicle  # noqa: E402
from offboard.controller.velocity import ConsistentVelocity, estimate_noise  # noqa: E402
from offboard.missions import MISSIONS_DIR  # noqa: E402

HELIX = MISSIONS_DIR / "paper-helix.toml"
HOLD_S = (18.5, 25.0)  # the second half of the helix's hold at 12 m, mission time
AIRBORNE_DOWN_M = -5.0  # "airborne": the estimate more than 5 m up
RECORD_RATE_HZ = 50.0
#: the velocity filter's time constants compared offline on the same record (0: EKF2's velocity)
TIME_CONSTANTS_S = (0.0, 0.01, 0.05, 0.1, 0.25, 0.5, 1.0)
EARTH_RADIUS_M = 6378137.0
MAV_CMD_SET_MESSAGE_INTERVAL = 511
HIL_STATE_QUATERNION_ID = 115
LOCAL_POSITION_NED_ID = 32
#: Welch segments of the error spectra (``error_spectra``): 256 samples at 20 Hz, 0.078 Hz apart
SPECTRUM_SEGMENT_S = 12.8


@dataclass
class GroundStationRecord:
    """What the ground-station link carried: (time_boot s, x, y, z, vx, vy, vz) estimates and
    (time s, lat deg, lon deg, alt m, vn, ve, vd) truths, the truth stamped with the estimate before it."""

    estimates: list[tuple[float, ...]] = field(default_factory=list)
    truths: list[tuple[float, ...]] = field(default_factory=list)
    #: (time_boot s, EKF2's yaw rad) from ATTITUDE, and (time s, SIH's yaw rad), stamped as ``truths``
    headings: list[tuple[float, float]] = field(default_factory=list)
    true_headings: list[tuple[float, float]] = field(default_factory=list)
    #: (time_boot s, EKF2's roll rad, pitch rad) from ATTITUDE, and (time s, SIH's roll, pitch),
    #: stamped as ``truths``: the vehicle's true tilt in the hold beside the one EKF2 reports
    attitudes: list[tuple[float, float, float]] = field(default_factory=list)
    true_attitudes: list[tuple[float, float, float]] = field(default_factory=list)


def record_ground_station(port: int, stop: threading.Event, record: GroundStationRecord) -> None:
    """Listen on PX4's ground-station link until ``stop``; ask for both messages every 2 s."""
    from pymavlink import mavutil

    link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=250)
    try:
        if link.wait_heartbeat(timeout=30) is None:
            return
        interval_us = 1e6 / RECORD_RATE_HZ
        asked = 0.0
        last_time: float | None = None
        while not stop.is_set():
            if time.monotonic() - asked > 2.0:
                for message_id in (HIL_STATE_QUATERNION_ID, LOCAL_POSITION_NED_ID):
                    link.mav.command_long_send(link.target_system, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                               message_id, interval_us, 0, 0, 0, 0, 0)  # fmt: skip
                asked = time.monotonic()
            msg = link.recv_match(type=["LOCAL_POSITION_NED", "HIL_STATE_QUATERNION", "ATTITUDE"], blocking=True, timeout=0.2)
            if msg is None:
                continue
            if msg.get_type() == "LOCAL_POSITION_NED":
                last_time = msg.time_boot_ms / 1000.0
                record.estimates.append((last_time, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
            elif msg.get_type() == "ATTITUDE":
                record.headings.append((msg.time_boot_ms / 1000.0, msg.yaw))
                record.attitudes.append((msg.time_boot_ms / 1000.0, msg.roll, msg.pitch))
            elif last_time is not None:
                record.truths.append((last_time, msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0,
                                      msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0))  # fmt: skip
                w, x, y, z = msg.attitude_quaternion
                record.true_headings.append((last_time, math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))))
                record.true_attitudes.append((last_time, math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
                                              math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))))  # fmt: skip
    finally:
        link.close()


def error_spectra(position_error: np.ndarray, velocity_error: np.ndarray, sample_time_s: float,
                  segment_s: float = SPECTRUM_SEGMENT_S) -> EstimateErrorSpectra:  # fmt: skip
    """Welch's estimate of one axis's error spectra (``design.EstimateErrorSpectra``) from errors
    sampled every ``sample_time_s``: Hann windows of ``segment_s`` overlapping by half, each
    segment's mean removed, one-sided densities per Hz (scipy.signal.welch and csd's scaling and
    conventions)."""
    p = np.asarray(position_error, dtype=float)
    v = np.asarray(velocity_error, dtype=float)
    n = int(round(segment_s / sample_time_s))
    if len(p) < n or len(v) != len(p):
        raise ValueError(f"{len(p)} error samples: too few for one {segment_s:g} s spectrum segment")
    window = np.hanning(n + 1)[:-1]  # periodic Hann, as scipy's
    scale = sample_time_s / np.sum(window**2)
    starts = range(0, len(p) - n + 1, n // 2)
    fp = np.array([np.fft.rfft(window * (p[k:k + n] - p[k:k + n].mean())) for k in starts])
    fv = np.array([np.fft.rfft(window * (v[k:k + n] - v[k:k + n].mean())) for k in starts])
    one_sided = np.full(fp.shape[1], 2.0)
    one_sided[0] = 1.0
    if n % 2 == 0:
        one_sided[-1] = 1.0
    density = lambda a, b: one_sided * scale * np.mean(np.conj(a) * b, axis=0)  # noqa: E731
    return EstimateErrorSpectra(np.fft.rfftfreq(n, sample_time_s), density(fp, fp).real, density(fv, fv).real, density(fp, fv))


def _unique(rows: list[tuple[float, ...]], width: int = 7) -> np.ndarray:
    a = np.asarray(rows, dtype=float).reshape(-1, width)
    _, first = np.unique(a[:, 0], return_index=True)
    return a[first]


def _velocity_read(pos: np.ndarray, vel: np.ndarray, t: np.ndarray, time_constant_s: float, sample_time_s: float,
                   identify: bool = False) -> np.ndarray:  # fmt: skip
    """The velocity the law reads at each sample with ``[law] velocity_from_position_s`` = T (0: EKF2's own),
    and ``velocity_from_position_identify``."""
    if time_constant_s <= 0:
        return vel.copy()
    consistent = ConsistentVelocity(time_constant_s, sample_time_s, identify=identify)
    return np.array([consistent.update(pos[n], vel[n], t[n]) for n in range(len(t))])


def compare(record: GroundStationRecord, series: np.ndarray, velocity_from_position_s: float, sample_time_s: float,
            identify: bool = False, design: Design | None = None) -> dict:  # fmt: skip
    """The figures of the module docstring from a flight's ground-station record and its series.csv
    (a structured array with t_s, time_boot_ms and euler_rad_0/1), the law's velocity filter
    with T = ``velocity_from_position_s`` and ``identify`` as the flight's controller had them;
    with the flown ``design``, also the tilt and estimate error its loop makes of the errors
    recorded (``predicted_noise``)."""
    est, tru = _unique(record.estimates), _unique(record.truths)
    if len(est) < 100 or len(tru) < 100:
        raise ValueError(f"too little recorded on the ground-station link ({len(est)} estimates, {len(tru)} truths)")
    lat0, lon0 = tru[0, 1], tru[0, 2]
    true_pos = np.stack([np.radians(tru[:, 1] - lat0) * EARTH_RADIUS_M,
                         np.radians(tru[:, 2] - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
                         -tru[:, 3]], axis=1)  # fmt: skip
    true_vel = tru[:, 4:7]
    lags = np.arange(-0.05, 0.0501, 0.0025)
    scores = [np.corrcoef(np.interp(est[:, 0] + lag, tru[:, 0], true_vel[:, 2]), est[:, 6])[0, 1] for lag in lags]
    lag = float(lags[int(np.nanargmax(scores))])
    # the law's samples: every To of the estimate's clock
    t = np.arange(est[0, 0], est[-1, 0], sample_time_s)
    pos = np.stack([np.interp(t, est[:, 0], est[:, 1 + k]) for k in range(3)], axis=1)
    vel = np.stack([np.interp(t, est[:, 0], est[:, 4 + k]) for k in range(3)], axis=1)
    tpos = np.stack([np.interp(t + lag, tru[:, 0], true_pos[:, k]) for k in range(3)], axis=1)
    tvel = np.stack([np.interp(t + lag, tru[:, 0], true_vel[:, k]) for k in range(3)], axis=1)
    airborne = pos[:, 2] < AIRBORNE_DOWN_M
    tpos += (pos[airborne] - tpos[airborne]).mean(axis=0)  # the estimate's origin, where the truth has none
    read = _velocity_read(pos, vel, t, velocity_from_position_s, sample_time_s, identify)
    noise = estimate_noise(pos, vel, sample_time_s, time_s=t)  # the whole record, as identify weighs its last 30 s
    identified_s = float(noise.time_constant_s())
    mission_start = series["time_boot_ms"][0] / 1000.0 - series["t_s"][0]
    hold = (t >= mission_start + HOLD_S[0]) & (t < mission_start + HOLD_S[1])
    s_hold = (series["t_s"] >= HOLD_S[0]) & (series["t_s"] < HOLD_S[1])
    tilt = np.degrees(np.arccos(np.cos(series["euler_rad_0"][s_hold]) * np.cos(series["euler_rad_1"][s_hold])))

    def rms(x: np.ndarray) -> list[float]:
        return [round(float(v), 4) for v in np.sqrt(np.mean(x**2, axis=0))]

    return {
        "truth_lag_s": lag,
        "airborne_samples": int(airborne.sum()),
        "position_error_rms_m": rms((pos - tpos)[airborne]),
        "velocity_error_rms_m_s": rms((vel - tvel)[airborne]),
        "velocity_read_error_rms_m_s": rms((read - tvel)[airborne]),
        "velocity_from_position_s": velocity_from_position_s,
        "velocity_from_position_identify": identify,
        "identified": {"time_constant_s": round(identified_s, 4), "bias_walk_m_s_sqrt_s": round(float(noise.bias_walk_m_s_sqrt_s), 4),
                       "white_m_s": round(float(noise.white_m_s), 4), "position_white_m": round(float(noise.position_white_m), 5),
                       "velocity_read_error_rms_m_s": rms((_velocity_read(pos, vel, t, identified_s, sample_time_s) - tvel)[airborne])},
        "velocity_read_error_rms_by_time_constant_m_s": {
            f"{tc:g}": rms((_velocity_read(pos, vel, t, tc, sample_time_s) - tvel)[airborne]) for tc in TIME_CONSTANTS_S
        },
        "hold_samples": int(hold.sum()),
        "hold_true_position_std_m": [round(float(v), 4) for v in tpos[hold].std(axis=0)],
        "hold_estimated_position_std_m": [round(float(v), 4) for v in pos[hold].std(axis=0)],
        "hold_velocity_error_mean_m_s": [round(float(v), 4) for v in (vel - tvel)[hold].mean(axis=0)],
        "hold_velocity_read_error_rms_m_s": rms((read - tvel)[hold]),
        "hold_tilt_max_deg": round(float(tilt.max()), 3) if tilt.size else None,
        "hold_tilt_rms_deg": round(float(np.sqrt(np.mean(tilt**2))), 3) if tilt.size else None,
        "predicted_noise": None if design is None else predicted_noise(
            design, pos - tpos, vel - tvel, airborne, identified_s if identify else velocity_from_position_s),
        **heading_errors(record, mission_start, lag),
        **true_hold_tilt(record, mission_start, lag),
    }


def _tilt_deg(roll_pitch: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.cos(roll_pitch[:, 0]) * np.cos(roll_pitch[:, 1]), -1.0, 1.0)))


def true_hold_tilt(record: GroundStationRecord, mission_start_s: float, lag_s: float) -> dict:
    """The vehicle's true tilt over the hold's second half (SIH's attitude, at each ATTITUDE of
    the ground-station link), its maximum and RMS, and EKF2's attitude error there (its roll and
    pitch less SIH's: mean, deg); None without attitudes."""
    est, tru = _unique(record.attitudes, 3), _unique(record.true_attitudes, 3)
    mission = est[:, 0] - mission_start_s if len(est) else np.zeros(0)
    hold = (mission >= HOLD_S[0]) & (mission < HOLD_S[1])
    if len(tru) < 10 or not hold.any():
        return {"hold_true_tilt_max_deg": None, "hold_true_tilt_rms_deg": None, "hold_attitude_error_mean_deg": None}
    t = est[hold, 0]
    truth = np.stack([np.interp(t + lag_s, tru[:, 0], tru[:, 1 + k]) for k in range(2)], axis=1)
    tilt = _tilt_deg(truth)
    error = np.degrees(est[hold, 1:3] - truth).mean(axis=0)
    return {"hold_true_tilt_max_deg": round(float(tilt.max()), 3), "hold_true_tilt_rms_deg": round(float(np.sqrt(np.mean(tilt**2))), 3),
            "hold_attitude_error_mean_deg": [round(float(v), 3) for v in error]}


#: The mission's first seconds, in which EKF2 aligns its heading in flight (the helix passes 1.5 m
#: above the take-off point at about 1 s)
TAKEOFF_S = 5.0


def heading_errors(record: GroundStationRecord, mission_start_s: float, lag_s: float) -> dict:
    """EKF2's heading against SIH's: the largest error (signed, deg) in the mission's first
    ``TAKEOFF_S`` and after, and when the first was (mission time); None without headings."""
    est, tru = _unique(record.headings, 2), _unique(record.true_headings, 2)
    if len(est) < 10 or len(tru) < 10:
        return {"takeoff_heading_error_deg": None, "takeoff_heading_error_at_s": None, "later_heading_error_deg": None}
    t = est[:, 0]
    truth = np.interp(t + lag_s, tru[:, 0], np.unwrap(tru[:, 1]))
    error = np.degrees((est[:, 1] - truth + math.pi) % (2.0 * math.pi) - math.pi)
    mission = t - mission_start_s
    first = (mission >= 0.0) & (mission < TAKEOFF_S)
    later = mission >= TAKEOFF_S

    def largest(mask: np.ndarray) -> tuple[float | None, float | None]:
        if not mask.any():
            return None, None
        k = np.flatnonzero(mask)[int(np.argmax(np.abs(error[mask])))]
        return round(float(error[k]), 2), round(float(mission[k]), 2)

    (takeoff, at), (after, _) = largest(first), largest(later)
    return {"takeoff_heading_error_deg": takeoff, "takeoff_heading_error_at_s": at, "later_heading_error_deg": after}


def predicted_noise(design: Design, position_error: np.ndarray, velocity_error: np.ndarray, airborne: np.ndarray,
                    velocity_from_position_s: float) -> dict:  # fmt: skip
    """What the flown design's loop makes of the estimator's errors over the airborne flight
    (``design.noise_response`` on each tilt axis, the spectra by ``error_spectra``): the RMS tilt
    (north with the pitch loop, east with the roll loop, and the two together as the tilt a hold
    shows), the part of it the position error alone gives, and the RMS error of the estimate the
    law holds against its reference."""
    span = np.flatnonzero(airborne)
    if span.size == 0:
        raise ValueError("the record has no airborne sample: no spectra of the estimator's errors")
    part = slice(span[0], span[-1] + 1)
    north_plant, east_plant, _ = axis_plants(design.model, design.sample_time_s)
    out = [noise_response(plant, axis.gains, design.sample_time_s,
                          error_spectra(position_error[part, k], velocity_error[part, k], design.sample_time_s),
                          velocity_from_position_s)
           for k, (plant, axis) in enumerate(((north_plant, design.north), (east_plant, design.east)))]  # fmt: skip
    return {
        "tilt_rms_deg": [round(r.tilt_rms_deg, 3) for r in out],
        "tilt_rms_both_deg": round(math.hypot(*(r.tilt_rms_deg for r in out)), 3),
        "tilt_from_position_deg": [round(r.tilt_from_position_deg, 3) for r in out],
        "estimate_error_rms_m": [round(r.estimate_error_rms_m, 4) for r in out],
    }


def fly(folder: Path, speed: float, fly_args: tuple[str, ...] = ()) -> dict:
    """One helix on a fresh PX4 SITL with the ground-station recorder: ``compare``'s figures."""
    record, stop = GroundStationRecord(), threading.Event()
    run = folder / "run"
    with running_px4(folder / "px4", speed=speed) as px4:
        recorder = threading.Thread(target=record_ground_station, args=(px4.gcs_listen_port, stop, record), daemon=True)
        recorder.start()
        try:
            flown = subprocess.run(
                [sys.executable, "-m", "offboard.cli", "fly", str(HELIX), "--connect", f"udpin:127.0.0.1:{px4.api_listen_port}",
                 "--run-dir", str(run), "--no-plots", "--json", *fly_args],
                capture_output=True, text=True, timeout=300, cwd=ROOT,
            )  # fmt: skip
        finally:
            stop.set()
            recorder.join(timeout=5)
    if flown.returncode != 0:
        raise RuntimeError(f"offboard fly exited {flown.returncode}: {flown.stderr.strip().splitlines()[-1:]}")
    summary = json.loads((run / "summary.json").read_text())
    series = np.genfromtxt(run / "series.csv", delimiter=",", names=True)
    controller = summary["controller"]
    figures = compare(record, series, float(controller["velocity_from_position_s"]), float(controller["sample_time_s"]),
                      bool(controller.get("velocity_from_position_identify", False)), flown_design(summary, flown.stderr))
    figures["speed"] = speed
    figures["fly_args"] = list(fly_args)
    figures["takeoff_heading_hold"] = summary.get("takeoff_heading_hold")
    return figures


def flown_design(summary: dict, stderr: str) -> Design:
    """The design ``offboard fly`` flew (its summary's vehicle parameters and gains, and the
    latency it said it designed for, predicted as the attitude output is by default)."""
    said = re.search(r"latency (\d+(?:\.\d+)?) ms for the design", stderr)
    latency_s = float(said.group(1)) / 1000.0 if said else 0.0
    controller = summary["controller"]
    design = design_for_vehicle(summary["vehicle_params"], sample_time_s=float(controller["sample_time_s"]),
                                latency_s=latency_s, predict=True)  # fmt: skip
    gains = controller["gains"]
    flown = AxisGains(gains["kx1"], gains["kx2"], float(controller["tilt_lead"]), 0.0,
                      float(controller["velocity_integral_gain_per_s2"]))  # fmt: skip
    return with_gains(design, flown, design.vertical)


def _axes(values: list[float], unit: str) -> str:
    return ", ".join(f"{name} {v:.3f}" for name, v in zip(("north", "east", "down"), values)) + f" {unit}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speed", type=float, default=1.0, help="PX4 SITL --speed (default: real time)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("fly_args", nargs="*", metavar="-- OFFBOARD FLY OPTIONS",
                        help="passed on to offboard fly (after --), e.g. -- --takeoff-heading-hold off")
    args = parser.parse_args(argv)
    if px4_launcher() is None:
        print(f"px4_estimator: {SKIP_REASON}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="px4-estimator-") as tmp:
        try:
            f = fly(Path(tmp), args.speed, tuple(args.fly_args))
        except (RuntimeError, ValueError) as exc:
            print(f"px4_estimator: {exc}", file=sys.stderr)
            return 1
    if args.json:
        try:
            print(json.dumps(f, allow_nan=False))
        except ValueError as exc:  # a figure not finite: strict JSON has no NaN
            print(f"px4_estimator: a figure is not a finite number ({exc}): no JSON written", file=sys.stderr)
            return 1
        return 0
    print(f"PX4 SIH helix at --speed {args.speed:g}, EKF2's LOCAL_POSITION_NED against SIH's truth (HIL_STATE_QUATERNION)")
    print(f"airborne ({f['airborne_samples']} samples): position error RMS {_axes(f['position_error_rms_m'], 'm')}")
    print(f"  velocity error RMS {_axes(f['velocity_error_rms_m_s'], 'm/s')}")
    how = "identified in flight from" if f["velocity_from_position_identify"] else "T"
    print(
        f"  the velocity the law reads ({how} {f['velocity_from_position_s']:g} s): error RMS {_axes(f['velocity_read_error_rms_m_s'], 'm/s')}"
    )
    ident = f["identified"]
    print(
        f"  identified from the whole record (offboard.controller.velocity.estimate_noise): bias walk "
        f"{ident['bias_walk_m_s_sqrt_s']:.3f} m/s/sqrt(s), white {ident['white_m_s']:.3f} m/s (position {ident['position_white_m'] * 1000:.1f} mm) "
        f"-> T {ident['time_constant_s']:.3f} s: error RMS {_axes(ident['velocity_read_error_rms_m_s'], 'm/s')}"
    )
    by_t = f["velocity_read_error_rms_by_time_constant_m_s"]
    print(
        "  the same record read with other time constants T (0: EKF2's velocity): "
        + "; ".join(f"T {tc} s: north {v[0]:.3f}, east {v[1]:.3f}" for tc, v in by_t.items())
        + " m/s"
    )
    print(f"hold at 12 m, {HOLD_S[0]:g}-{HOLD_S[1]:g} s ({f['hold_samples']} samples):")
    print(f"  true position std {_axes(f['hold_true_position_std_m'], 'm')}")
    print(f"  estimated position std {_axes(f['hold_estimated_position_std_m'], 'm')}")
    print(f"  EKF2 velocity error mean {_axes(f['hold_velocity_error_mean_m_s'], 'm/s')}")
    print(f"  the velocity the law reads: error RMS {_axes(f['hold_velocity_read_error_rms_m_s'], 'm/s')}")
    print(f"  tilt max {f['hold_tilt_max_deg']:.2f} deg, RMS {f['hold_tilt_rms_deg']:.2f} deg (EKF2's attitude, as the flight reads it)")
    if f["hold_true_tilt_max_deg"] is None:
        print("  the true tilt: too few ATTITUDE or truth samples recorded")
    else:
        roll, pitch = f["hold_attitude_error_mean_deg"]
        print(f"  true tilt max {f['hold_true_tilt_max_deg']:.2f} deg, RMS {f['hold_true_tilt_rms_deg']:.2f} deg (SIH's); "
              f"EKF2's attitude error mean roll {roll:+.2f}, pitch {pitch:+.2f} deg")
    noise = f["predicted_noise"]
    print("what the flown design's loop makes of the airborne errors above (design.noise_response):")
    print(f"  tilt RMS north {noise['tilt_rms_deg'][0]:.2f}, east {noise['tilt_rms_deg'][1]:.2f}, both {noise['tilt_rms_both_deg']:.2f} deg "
          f"(of it the position error alone: {noise['tilt_from_position_deg'][0]:.2f}, {noise['tilt_from_position_deg'][1]:.2f} deg)")
    print(f"  estimate error RMS north {noise['estimate_error_rms_m'][0]:.3f}, east {noise['estimate_error_rms_m'][1]:.3f} m")
    hold = f["takeoff_heading_hold"] or {}
    held = f"held until {hold['released_s']:.2f} s" if hold.get("held") and hold.get("released_s") is not None else "not held"
    if f["takeoff_heading_error_deg"] is None:
        print("EKF2's heading against SIH's: too few ATTITUDE or truth samples recorded")
    else:
        print(f"EKF2's heading against SIH's: largest error {f['takeoff_heading_error_deg']:+.1f} deg at "
              f"{f['takeoff_heading_error_at_s']:.2f} s of the first {TAKEOFF_S:g} s (take-off heading {held}), "
              f"{f['later_heading_error_deg']:+.1f} deg after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
