"""How well a flight's latency prediction predicted: each sample's state carried over the latency
(``offboard.controller.prediction.LatencyPredictor``, the flight's own latency and telemetry ages,
the setpoints it logged as the ones in flight) against what the vehicle reported that much later.

``offboard fly`` hands the law the state at the moment its setpoint will act
(docs/controller-design.md, "Latency"); the log holds what the vehicle then reported, so the
prediction can be checked after the fact, on sitl-plant's flights as on a real PX4's. The same
figures for the measured state itself (no prediction: what a law handed the measurement answers)
say what the prediction bought. The inputs in flight are the logged SET_ATTITUDE_TARGETs, not a
re-run law's, so a log with gaps (a link that drops or reorders) is checked as flown.

Pure numpy over arrays from the log; no files, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from offboard.controller.prediction import LatencyPredictor
from offboard.trajectory.base import Phase


@dataclass(frozen=True)
class PredictionCheck:
    """RMS differences between a state and what the vehicle reported at its horizon.

    Attributes
    ----------
    latency_s : float
        The latency the flight predicted over (the horizon with the usual telemetry age).
    samples : int
        Samples whose horizon the log covers.
    position_rms_m, velocity_rms_m_s, tilt_rms_deg : float
        The predicted state against the reported one at its horizon: 3D position and velocity
        differences, and the angle between the two thrust axes (body z) in degrees.
    position_rms_measured_m, velocity_rms_measured_m_s, tilt_rms_measured_deg : float
        The same for the measured state, not carried over the latency.
    """

    latency_s: float
    samples: int
    position_rms_m: float
    velocity_rms_m_s: float
    tilt_rms_deg: float
    position_rms_measured_m: float
    velocity_rms_measured_m_s: float
    tilt_rms_measured_deg: float
    phases: tuple[tuple[str, PredictionCheck], ...] = ()

    def to_dict(self) -> dict:
        """The figures for summary.json (rounded: they are RMS figures, not bit-exact values)."""
        return {"latency_s": round(self.latency_s, 6), "samples": self.samples,
                "position_rms_m": round(self.position_rms_m, 6), "velocity_rms_m_s": round(self.velocity_rms_m_s, 6),
                "tilt_rms_deg": round(self.tilt_rms_deg, 4),
                "position_rms_measured_m": round(self.position_rms_measured_m, 6),
                "velocity_rms_measured_m_s": round(self.velocity_rms_measured_m_s, 6),
                "tilt_rms_measured_deg": round(self.tilt_rms_measured_deg, 4),
                "phases": {name: check.to_dict() for name, check in self.phases}}  # fmt: skip

    def describe(self) -> str:
        """A line for the flight, then one a phase: the predicted state's differences, the
        measured state's in brackets."""
        lines = [f"prediction over {self.latency_s * 1000:.0f} ms, against what the vehicle reported then (the measured "
                 f"state's in brackets): {self._figures()} over the flight ({self.samples} samples)"]
        lines += [f"  {name}: {check._figures()}" for name, check in self.phases]
        return "\n".join(lines)

    def _figures(self) -> str:
        return (f"position {self.position_rms_m * 1000:.1f} mm RMS ({self.position_rms_measured_m * 1000:.1f}), velocity "
                f"{self.velocity_rms_m_s * 1000:.1f} mm/s ({self.velocity_rms_measured_m_s * 1000:.1f}), thrust axis "
                f"{self.tilt_rms_deg:.2f} deg ({self.tilt_rms_measured_deg:.2f})")  # fmt: skip


def thrust_axis(roll_rad: np.ndarray | float, pitch_rad: np.ndarray | float, yaw_rad: np.ndarray | float) -> np.ndarray:
    """Body z (FRD, down through the rotors' thrust) in NED of ZYX angles, shape (..., 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll_rad), np.sin(roll_rad), np.cos(pitch_rad), np.sin(pitch_rad), np.cos(yaw_rad), np.sin(yaw_rad)
    return np.stack([cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp], axis=-1)


def setpoint_tilt_about(q_wxyz: np.ndarray, heading_rad: float) -> tuple[float, float]:
    """(roll, pitch) of a setpoint quaternion's thrust axis about ``heading_rad``: the x7ez, x9ez
    the law wrote it from (``frames.setpoint_attitude`` keeps the thrust axis they give about the
    law's heading, whatever the setpoint's own yaw)."""
    w, x, y, z = (float(v) for v in q_wxyz)
    # body z of q in NED: the third column of its rotation matrix
    zn, ze, zd = 2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    forward, right = c * zn + s * ze, -s * zn + c * ze  # body z in the heading frame (forward, right, down)
    # ZYX about the heading: body z = (cos(roll) sin(pitch), -sin(roll), cos(roll) cos(pitch))
    roll = math.asin(max(-1.0, min(1.0, -right)))
    return roll, math.atan2(forward, zd)


def check_prediction(predictor: LatencyPredictor, measured: list, setpoints: np.ndarray, thrust_n: np.ndarray,
                     headings_rad: np.ndarray, attitude: np.ndarray, position: np.ndarray, *, t_s: np.ndarray | None = None,
                     phases: list[Phase] | tuple[Phase, ...] = ()) -> PredictionCheck | None:  # fmt: skip
    """Carry each sample's ``measured`` state (a ``StateEstimate`` with ``time_boot_ms``,
    ``position_time_boot_ms`` and, in real time, ``age_s``) over the flight's latency with the
    setpoints in flight (``setpoints``: each sample's logged quaternion, w x y z; ``thrust_n``, as
    sent: within the vehicle's range; the heading its tilt was written about), and compare with
    the telemetry at the horizon.

    ``attitude``: rows (time_boot_ms, roll, pitch, yaw, ...); ``position``: rows (time_boot_ms,
    x, y, z, vx, vy, vz, ...), as ``LogScan`` tables. With ``t_s`` (each sample's mission time)
    the figures of each of the mission's ``phases`` too (``PredictionCheck.phases``: a step, a
    turn, a hold predict differently). None when no sample's horizon lies within the log.
    """
    att = _by_time(attitude)
    pos = _by_time(position)
    if len(att) < 2 or len(pos) < 2:
        return None
    yaw_unwrapped = np.unwrap(att[:, 3])
    rows, times = [], []
    t_all = np.full(len(measured), np.nan) if t_s is None else np.asarray(t_s, dtype=float)
    for state, q, thrust, heading, t in zip(measured, setpoints, thrust_n, headings_rad, t_all):
        ahead = predictor.predict(state)
        horizon_ms = 1000.0 * ahead.horizon_s
        t_att = float(state.time_boot_ms) + horizon_ms
        t_pos = float(getattr(state, "position_time_boot_ms", None) or state.time_boot_ms) + horizon_ms
        if np.all(np.isfinite(q)) and math.isfinite(thrust):
            predictor.record(float(thrust), *setpoint_tilt_about(q, float(heading)))
        if not (att[0, 0] <= t_att <= att[-1, 0] and pos[0, 0] <= t_pos <= pos[-1, 0]):
            continue
        then_pos = np.array([np.interp(t_pos, pos[:, 0], pos[:, i]) for i in (1, 2, 3)])
        then_vel = np.array([np.interp(t_pos, pos[:, 0], pos[:, i]) for i in (4, 5, 6)])
        then_axis = thrust_axis(np.interp(t_att, att[:, 0], att[:, 1]), np.interp(t_att, att[:, 0], att[:, 2]),
                                np.interp(t_att, att[:, 0], yaw_unwrapped))  # fmt: skip
        axes = thrust_axis(np.array([ahead.euler_rad[0], state.euler_rad[0]]), np.array([ahead.euler_rad[1], state.euler_rad[1]]),
                           np.array([ahead.euler_rad[2], state.euler_rad[2]]))  # fmt: skip
        angles = np.degrees(np.arccos(np.clip(axes @ then_axis, -1.0, 1.0)))
        rows.append((float(np.linalg.norm(ahead.pos_ned_m - then_pos)), float(np.linalg.norm(state.pos_ned_m - then_pos)),
                     float(np.linalg.norm(ahead.vel_ned_m_s - then_vel)), float(np.linalg.norm(state.vel_ned_m_s - then_vel)),
                     float(angles[0]), float(angles[1])))  # fmt: skip
        times.append(t)
    if not rows:
        return None
    table, when = np.array(rows), np.array(times)

    def summed(keep: np.ndarray) -> PredictionCheck:
        r = np.sqrt(np.mean(np.square(table[keep]), axis=0))
        return PredictionCheck(predictor.latency_s, int(np.count_nonzero(keep)), float(r[0]), float(r[2]), float(r[4]), float(r[1]),
                               float(r[3]), float(r[5]))  # fmt: skip

    each = tuple((ph.name, summed(k)) for ph in phases if (k := (when >= ph.start_s) & (when < ph.end_s)).any())
    return replace(summed(np.ones(len(table), bool)), phases=each)


def _by_time(table: np.ndarray) -> np.ndarray:
    """The rows in time order, one per stamp (the first logged)."""
    table = np.asarray(table, dtype=float)
    if table.ndim != 2 or not len(table):
        return np.zeros((0, 7))
    _, first = np.unique(table[:, 0], return_index=True)  # sorted by stamp
    return table[first]


__all__ = ["PredictionCheck", "check_prediction", "setpoint_tilt_about", "thrust_axis"]
