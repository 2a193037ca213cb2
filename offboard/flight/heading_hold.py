"""The take-off heading hold: the yaw reference kept at the heading the vehicle took off with until
its estimator has aligned its heading in flight (PX4's EKF2 with a magnetometer).

Why (docs/controller-design.md, "The take-off heading hold"): EKF2 resets its heading and its
earth magnetic field once the vehicle is 1.5 m above the ground after take-off
(``Ekf::checkHaglYawResetReq``, ``mag_anomalies_max_hagl``, in v1.16's mag_control.cpp), from
its low-passed magnetometer (``_mag_lpf``). A vehicle turning then is given a heading that lags
the turn: on PX4 SIH the paper helix's 45 deg/s turn to its first heading, at that moment, got a
reset of -32 to -35 deg off the truth in every flight. That heading error turns the estimate's
horizontal acceleration by as much: EKF2's velocity ran 0.31 m/s off the truth 0.2 s after the
reset and 0.46 m/s 0.45 s after, and the join's tail decided whether the helix met 0.10 m. PX4's own flight modes do the same for the
same reason: they leave the yaw loop open until this alignment, and one second more (PX4 pull
request 18624, "Close yaw loop after final mag alignment only").

``TakeoffHeadingHold`` is pure: it takes the mission time and the vehicle's height and hands on
the references with their yaw held (rate 0) until ``delay_s + settle_s`` after the vehicle first
rose ``align_height_m`` above its take-off point (EKF2 aligns ``delay_s``, its EKF2_DELAY_MAX,
after); then it hands them on unchanged for good (the law's
yaw-rate bound, PX4's MPC_YAWRAUTO_MAX, then turns the vehicle to the mission's heading).
"""

from __future__ import annotations

import math
from dataclasses import replace

from offboard.trajectory.base import Reference, Trajectory

#: EKF2's height above the ground for its in-flight heading alignment (m): v1.16's
#: ``mag_anomalies_max_hagl`` (without a range finder the ground is where it took off).
EKF2_ALIGN_HEIGHT_M = 1.5
#: How long after the alignment the heading stays held (s): PX4's own modes give the estimate one
#: second to settle after the in-air alignment before they close the yaw loop.
EKF2_ALIGN_SETTLE_S = 1.0
#: EKF2_DELAY_MAX's default (s): EKF2 fuses, and checks the height, on a state this far behind the
#: estimate it publishes; its alignment comes that long after the published height passes 1.5 m
#: (PX4 SIH, measured: 0.19-0.25 s later).
EKF2_DELAY_MAX_S = 0.2
#: What ``aligns_in_flight`` reads of the vehicle.
HEADING_ALIGN_PARAMS = ("EKF2_MAG_TYPE", "SYS_HAS_MAG", "EKF2_DELAY_MAX")
#: EKF2_MAG_TYPE's "None": no magnetometer fusion, hence no in-flight alignment to wait for.
EKF2_MAG_TYPE_NONE = 5


def aligns_in_flight(vehicle_params: dict[str, float]) -> bool:
    """Whether the vehicle's estimator resets its heading from the magnetometer after take-off:
    it publishes EKF2_MAG_TYPE (PX4's EKF2) other than None, and SYS_HAS_MAG is not 0 where it
    is published. sitl-plant publishes neither: its estimate has no heading to align."""
    mag_type = vehicle_params.get("EKF2_MAG_TYPE")
    if mag_type is None or int(mag_type) == EKF2_MAG_TYPE_NONE:
        return False
    return int(vehicle_params.get("SYS_HAS_MAG", 1)) != 0


def alignment_delay_s(vehicle_params: dict[str, float]) -> float:
    """How long EKF2's alignment follows the published height's passing: its EKF2_DELAY_MAX (ms),
    ``EKF2_DELAY_MAX_S`` where it does not say."""
    ms = vehicle_params.get("EKF2_DELAY_MAX")
    return EKF2_DELAY_MAX_S if ms is None or not (math.isfinite(ms) and ms >= 0) else float(ms) / 1000.0


def highest_down_m(trajectory: Trajectory, sample_time_s: float) -> float:
    """The reference's highest point over the mission's samples, as NED down (m): a take-off
    point more than ``EKF2_ALIGN_HEIGHT_M`` below it has an in-flight alignment to wait for."""
    n = int(math.floor(trajectory.duration_s / sample_time_s + 1e-9))
    return min(float(trajectory.reference(k * sample_time_s).pos_ned_m[2]) for k in range(n + 1))


class TakeoffHeadingHold:
    """Holds the references' yaw at ``heading_rad`` until ``delay_s + settle_s`` after the vehicle
    first rose ``align_height_m`` above ``takeoff_down_m`` (NED down, m): EKF2 aligns ``delay_s``
    after that (``alignment_delay_s``), and its estimate is given ``settle_s`` more.

    ``update(t_s, down_m)`` once a sample, then ``apply(ref)`` on each reference of that sample.
    ``released_s``: the mission time it let go (None while it holds)."""

    def __init__(self, heading_rad: float, takeoff_down_m: float, align_height_m: float = EKF2_ALIGN_HEIGHT_M,
                 delay_s: float = EKF2_DELAY_MAX_S, settle_s: float = EKF2_ALIGN_SETTLE_S) -> None:  # fmt: skip
        if not (math.isfinite(heading_rad) and math.isfinite(takeoff_down_m)):
            raise ValueError(f"heading ({heading_rad}) and take-off height ({takeoff_down_m}) must be finite")
        if not (align_height_m > 0 and delay_s >= 0 and settle_s >= 0):
            raise ValueError(f"align_height_m must be > 0, delay_s and settle_s >= 0, got {align_height_m}, {delay_s}, {settle_s}")
        self.heading_rad = float(heading_rad)
        self.takeoff_down_m = float(takeoff_down_m)
        self.align_height_m = float(align_height_m)
        self.delay_s = float(delay_s)
        self.settle_s = float(settle_s)
        self.passed_s: float | None = None  # mission time the vehicle first rose past the height
        self.released_s: float | None = None
        self._as_flown = False
        self._release_at_s: float | None = None

    @property
    def holding(self) -> bool:
        """Whether the heading is still held (it has not let go)."""
        return self.released_s is None

    def update(self, t_s: float, down_m: float) -> bool:
        """Take the vehicle's height at mission time ``t_s``; whether the heading is still held."""
        if self.released_s is not None:
            return False
        if self._as_flown:  # a recorded flight's: it let go at its recorded time, whatever the height
            if self._release_at_s is not None and t_s >= self._release_at_s - 1e-9:
                self.released_s = t_s
            return self.released_s is None
        if self.passed_s is None and self.takeoff_down_m - down_m > self.align_height_m:
            self.passed_s = t_s
        if self.passed_s is not None and t_s >= self.passed_s + self.delay_s + self.settle_s - 1e-9:
            self.released_s = t_s
        return self.released_s is None

    @classmethod
    def as_flown(cls, heading_rad: float, released_s: float | None) -> TakeoffHeadingHold:
        """The hold of a recorded flight (``summary.json``'s ``takeoff_heading_hold``): held at
        ``heading_rad`` until mission time ``released_s`` (None: never let go), for a re-run."""
        hold = cls(heading_rad, 0.0)
        hold._as_flown = True
        hold._release_at_s = released_s
        return hold

    def apply(self, ref: Reference) -> Reference:
        """``ref`` with its yaw held (rate 0) while holding, else ``ref`` itself."""
        if self.released_s is not None:
            return ref
        return replace(ref, yaw_rad=self.heading_rad, yaw_rate_rad_s=0.0)
