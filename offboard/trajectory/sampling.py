"""Sample a trajectory on a time grid, and summarise it (lengths, bounds, peak speed, jumps).

Used by ``offboard mission show`` and by the mission checks; pure (no files, no printing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from offboard.trajectory.base import PhaseKind, Trajectory
from offboard.trajectory.segment import wrap_pi
from offboard.trajectory.sequence import Sequence

#: Default grid spacing for summaries and checks (s): 10 ms, five times the controller's rate.
DEFAULT_DT_S = 0.01


@dataclass(frozen=True)
class Samples:
    """A trajectory sampled at times ``t_s`` (shape (n,)); vectors have shape (n, 3), NED."""

    t_s: np.ndarray
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    acc_ned_m_s2: np.ndarray
    yaw_rad: np.ndarray
    yaw_rate_rad_s: np.ndarray


def sample(traj: Trajectory, dt_s: float = DEFAULT_DT_S, t_start_s: float = 0.0, t_end_s: float | None = None) -> Samples:
    """Evaluate ``traj.reference`` on a grid from ``t_start_s`` to ``t_end_s`` (default: its end), both included."""
    t_end = traj.duration_s if t_end_s is None else t_end_s
    n = max(2, int(math.ceil((t_end - t_start_s) / dt_s)) + 1)
    t = np.linspace(t_start_s, t_end, n)
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    acc = np.empty((n, 3))
    yaw = np.empty(n)
    yaw_rate = np.empty(n)
    for i, ti in enumerate(t):
        ref = traj.reference(float(ti))
        pos[i] = ref.pos_ned_m
        vel[i] = ref.vel_ned_m_s
        acc[i] = ref.acc_ned_m_s2
        yaw[i] = ref.yaw_rad
        yaw_rate[i] = ref.yaw_rate_rad_s
    return Samples(t, pos, vel, acc, yaw, yaw_rate)


@dataclass(frozen=True)
class SegmentSummary:
    """One segment: where it sits in time and how long, fast and hard it is (sampled)."""

    name: str
    type: str
    kind: PhaseKind | Literal["mixed"]  # its one phase's; "mixed": phases of both kinds (a waypoint hold)
    start_s: float
    duration_s: float
    length_m: float
    max_speed_m_s: float
    max_accel_m_s2: float
    max_yaw_rate_rad_s: float


@dataclass(frozen=True)
class Jump:
    """A discontinuity of the reference where one segment hands over to the next."""

    t_s: float
    position_m: float
    yaw_rad: float
    from_segment: str
    to_segment: str


@dataclass(frozen=True)
class VelocityStep:
    """A jump of the velocity reference (an unbounded acceleration: a corner flown without
    blending, or the speed changing between segments), sampled."""

    t_s: float
    speed_change_m_s: float  # |v after - v before|
    where: str  # the segment, or "from -> to" between segments


#: A sampled velocity change counts as a step when it exceeds what the analytic acceleration
#: explains over the grid step by this much (m/s).
VELOCITY_STEP_M_S = 0.01


@dataclass(frozen=True)
class Summary:
    """A trajectory at a glance; bounds are NED metres, [min, max] per axis."""

    segments: tuple[SegmentSummary, ...]
    jumps: tuple[Jump, ...]
    duration_s: float
    length_m: float
    min_ned_m: tuple[float, float, float]
    max_ned_m: tuple[float, float, float]
    max_speed_m_s: float
    max_accel_m_s2: float
    max_yaw_rate_rad_s: float
    velocity_steps: tuple[VelocityStep, ...] = ()


def _velocity_steps(s: Samples, t0_s: float, where: str) -> list[VelocityStep]:
    """Steps inside a segment; its last sample is left out (a segment at its end reports the
    state it stops in: the hand-over to the next segment is checked apart)."""
    vel, acc, t = s.vel_ned_m_s[:-1], s.acc_ned_m_s2[:-1], s.t_s[:-1]
    dv = np.linalg.norm(np.diff(vel, axis=0), axis=1)
    accel = np.linalg.norm(acc, axis=1)
    explained = 0.5 * (accel[:-1] + accel[1:]) * np.diff(t)
    steps = np.nonzero(dv > 2.0 * explained + VELOCITY_STEP_M_S)[0]
    return [VelocityStep(t0_s + float(t[k + 1]), float(dv[k]), where) for k in steps]


def _segments(traj: Trajectory) -> list[tuple[float, Trajectory]]:
    if isinstance(traj, Sequence):
        out: list[tuple[float, Trajectory]] = []
        for t0, seg in zip(traj.starts_s, traj.segments):
            out.extend((t0 + t1, inner) for t1, inner in _segments(seg))
        return out
    return [(0.0, traj)]


def summarize(traj: Trajectory, dt_s: float = DEFAULT_DT_S) -> Summary:
    """Per-segment and overall figures of ``traj`` from samples every ``dt_s`` seconds.

    Lengths are the sampled path lengths inside segments (a jump between segments is not
    path); jumps larger than 1 mm or 1 mrad are listed separately.
    """
    rows: list[SegmentSummary] = []
    jumps: list[Jump] = []
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    prev_end = None
    prev_name = ""
    steps: list[VelocityStep] = []
    prev_end_vel = np.zeros(3)
    for t0, seg in _segments(traj):
        s = sample(seg, dt_s)
        steps.extend(_velocity_steps(s, t0, getattr(seg, "name", type(seg).__name__)))
        speed = np.linalg.norm(s.vel_ned_m_s, axis=1)
        accel = np.linalg.norm(s.acc_ned_m_s2, axis=1)
        length = float(np.linalg.norm(np.diff(s.pos_ned_m, axis=0), axis=1).sum())
        name = getattr(seg, "name", type(seg).__name__)
        kind: PhaseKind | Literal["mixed"] = seg.phases()[0].kind if len(seg.phases()) == 1 else "mixed"
        rows.append(
            SegmentSummary(
                name, type(seg).__name__, kind, t0, seg.duration_s, length,
                float(speed.max()), float(accel.max()), float(np.abs(s.yaw_rate_rad_s).max()),
            )
        )
        lo = np.minimum(lo, s.pos_ned_m.min(axis=0))
        hi = np.maximum(hi, s.pos_ned_m.max(axis=0))
        start = seg.reference(0.0)
        if prev_end is not None:
            dp = float(np.linalg.norm(start.pos_ned_m - prev_end.pos_ned_m))
            dyaw = wrap_pi(start.yaw_rad - prev_end.yaw_rad)
            if dp > 1e-3 or abs(dyaw) > 1e-3:
                jumps.append(Jump(t0, dp, dyaw, prev_name, name))
            dv = float(np.linalg.norm(start.vel_ned_m_s - prev_end_vel))
            if dv > VELOCITY_STEP_M_S:
                steps.append(VelocityStep(t0, dv, f"{prev_name} -> {name}"))
        prev_end = seg.reference(seg.duration_s)
        prev_end_vel = seg.reference(max(seg.duration_s - 1e-6, 0.0)).vel_ned_m_s  # the speed it hands over
        prev_name = name
    return Summary(
        segments=tuple(rows),
        jumps=tuple(jumps),
        duration_s=float(traj.duration_s),
        length_m=float(sum(r.length_m for r in rows)),
        min_ned_m=tuple(float(x) for x in lo),  # type: ignore[arg-type]
        max_ned_m=tuple(float(x) for x in hi),  # type: ignore[arg-type]
        max_speed_m_s=max(r.max_speed_m_s for r in rows),
        max_accel_m_s2=max(r.max_accel_m_s2 for r in rows),
        max_yaw_rate_rad_s=max(r.max_yaw_rate_rad_s for r in rows),
        velocity_steps=tuple(sorted(steps, key=lambda v: v.t_s)),
    )
