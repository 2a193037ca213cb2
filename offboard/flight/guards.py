"""What a flight watches of the vehicle's flying, as opposed to its link and mode: is it still on
its reference, and does its estimator still know where it is?

Both end the flight early and hand the vehicle to its own landing (``Flight``), because the law
flies on the vehicle's estimate and nothing else would: PX4 v1.16 keeps an attitude-driven
Offboard running with its position estimate gone (a SIH flight whose GPS and barometer stopped at
take-off flew 321 m RMS off by SIH's truth, in Offboard to the mission's end:
docs/controller-design.md), and has no notion of a reference to be off.

- ``TrackGuard``: LOST_TRACK in flight, when the 3D error (estimate against reference) has
  stayed above ``metrics.LOST_TRACK_M`` through the last ``metrics.LOST_TRACK_WINDOW_S`` and did
  not shrink over it: the vehicle is off and not coming back (blown away, a fly-away). A vehicle
  far off but closing (a reference step longer than the limit) flies on; where it ends is
  ``metrics.check_tracking``'s verdict.
- ``EstimatorGuard``: ESTIMATE_LOST, when the vehicle's ESTIMATOR_STATUS stops vouching for an
  estimate the law reads (attitude, horizontal and vertical velocity, horizontal position
  relative to the origin, vertical position). SYS_STATUS's sensor health is reported as it
  changes (``sensor_health_changes``) but not acted on: the estimator says what a lost sensor
  costs (a GPS lost under vision-aided flight costs nothing).
- ``HeadingResetWatch``: the estimator's heading resets, read from ATTITUDE alone (a jump of its
  yaw that its body rates do not account for, ``heading_reset_deg``): noted, not acted on. PX4's
  EKF2 re-aligns its heading from the magnetometer 1.5 m above the ground (docs/controller-design.md,
  "The take-off heading hold"); ``offboard replay`` lists the same resets as events.

Pure: they take numbers and flags, and know nothing of the link.
"""

from __future__ import annotations

import math
from collections import deque

from offboard.metrics import LOST_TRACK_M, LOST_TRACK_WINDOW_S
from pymavlink.dialects.v20 import common as mavlink

#: ESTIMATOR_STATUS flags the law needs, with what each vouches for (MAVLink's words).
NEEDED_ESTIMATES: dict[int, str] = {
    mavlink.ESTIMATOR_ATTITUDE: "attitude",
    mavlink.ESTIMATOR_VELOCITY_HORIZ: "horizontal velocity",
    mavlink.ESTIMATOR_VELOCITY_VERT: "vertical velocity",
    mavlink.ESTIMATOR_POS_HORIZ_REL: "horizontal position",
    mavlink.ESTIMATOR_POS_VERT_ABS: "vertical position",
}
#: SYS_STATUS sensors whose health is reported as it changes.
WATCHED_SENSORS: dict[int, str] = {
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO: "gyro",
    mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL: "accelerometer",
    mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG: "magnetometer",
    mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE: "barometer",
    mavlink.MAV_SYS_STATUS_SENSOR_GPS: "GPS",
    mavlink.MAV_SYS_STATUS_AHRS: "AHRS",
    mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL: "horizontal position control",
}


def lost_estimates(flags: int) -> tuple[str, ...]:
    """The ``NEEDED_ESTIMATES`` an ESTIMATOR_STATUS with ``flags`` no longer vouches for."""
    return tuple(name for bit, name in NEEDED_ESTIMATES.items() if not flags & bit)


def missing_estimates(flags: int) -> str | None:
    """``lost_estimates`` in words (None: the estimator vouches for everything the law reads)."""
    missing = lost_estimates(flags)
    if not missing:
        return None
    return f"the vehicle's estimator no longer vouches for its {', '.join(missing)} (ESTIMATOR_STATUS flags 0x{flags:x})"


class TrackGuard:
    """LOST_TRACK in flight (module docstring).

    Parameters
    ----------
    limit_m : float
        The 3D error above which the vehicle may be lost (inf: never).
    window_s : float
        How long it must stay above, without shrinking, to be lost.
    """

    def __init__(self, limit_m: float = LOST_TRACK_M, window_s: float = LOST_TRACK_WINDOW_S) -> None:
        if not (limit_m > 0 and window_s > 0):
            raise ValueError(f"the lost-track limit and window must be > 0, got {limit_m} m, {window_s} s")
        self.limit_m = limit_m
        self.window_s = window_s
        self._above: deque[tuple[float, float]] = deque()  # (t, error) since the error last went above the limit

    def reset(self) -> None:
        """Forget the history (the controller restarted: its error before is not its doing)."""
        self._above.clear()

    def update(self, t_s: float, error_m: float) -> str | None:
        """The error at mission time ``t_s``; why the vehicle is lost, or None.

        A non-finite error (no reference) is no verdict and starts the window again."""
        if not (math.isfinite(error_m) and error_m > self.limit_m):
            self._above.clear()
            return None
        above = self._above
        above.append((t_s, error_m))
        if t_s - above[0][0] < self.window_s - 1e-9:
            return None
        while len(above) > 1 and t_s - above[1][0] >= self.window_s - 1e-9:
            above.popleft()  # above[0]: the latest sample at least a window old
        t0, e0 = above[0]
        if error_m < e0:
            return None  # closing in
        return (f"at t = {t_s:.2f} s the vehicle was {error_m:.1f} m off the reference, above {self.limit_m:g} m "
                f"since t = {t0:.2f} s and not closing ({e0:.1f} m then)")  # fmt: skip


class EstimatorGuard:
    """ESTIMATE_LOST (module docstring): the vehicle's ESTIMATOR_STATUS against ``NEEDED_ESTIMATES``.

    Attributes
    ----------
    heard : bool
        Whether an ESTIMATOR_STATUS has come (a vehicle that sends none is not watched).
    """

    def __init__(self) -> None:
        self.heard = False

    def update(self, flags: int) -> str | None:
        """One ESTIMATOR_STATUS's ``flags``; what it no longer vouches for, or None."""
        self.heard = True
        return missing_estimates(int(flags))


def sensor_health_changes(previous: dict[str, bool] | None, present: int, enabled: int, health: int) -> tuple[dict[str, bool], list[str]]:
    """SYS_STATUS's health of ``WATCHED_SENSORS`` (present and enabled ones), and one line per
    sensor whose health changed since ``previous`` (None: the first SYS_STATUS, which reports the
    unhealthy ones only). A sensor that stops being reported present is lost too: PX4 v1.16 drops
    a GPS that stopped (and a magnetometer) from ``present`` and leaves its health bit set
    (measured, docs/offboard.md)."""
    now = {name: bool(health & bit) for bit, name in WATCHED_SENSORS.items() if present & bit and enabled & bit}
    lines = []
    for name, ok in now.items():
        was = None if previous is None else previous.get(name)
        if was is None:
            if not ok or previous is not None:
                lines.append(f"{name} {'back' if ok else 'unhealthy'} (SYS_STATUS)")
        elif was != ok:
            lines.append(f"{name} {'healthy again' if ok else 'unhealthy'} (SYS_STATUS)")
    if previous is not None:
        lines += [f"{name} no longer reported (SYS_STATUS)" for name in previous if name not in now]
    return now, lines


#: A jump of ATTITUDE's yaw that its body rates do not account for, at least this (deg), between
#: samples at most ``HEADING_RESET_MAX_GAP_S`` apart, is an estimator's heading reset (PX4's
#: EKF2 aligns its heading in flight 1.5 m above the ground: -32 deg on the paper helix's first
#: turn, docs/controller-design.md). Integrating the rates over 50 ms of a 100 rad/s^2 swing
#: errs by about 1 deg.
HEADING_RESET_MIN_DEG = 5.0
HEADING_RESET_MAX_GAP_S = 0.1


def heading_reset_deg(before: tuple, after: tuple) -> float | None:
    """The heading reset between two ATTITUDE rows ``(time_boot_ms, roll, pitch, yaw, p, q, r, ...)``
    (deg), or None: the yaw's change less the Euler yaw rate ``(q sin(roll) + r cos(roll)) /
    cos(pitch)`` integrated over the gap (trapezoid), where that is at least
    ``HEADING_RESET_MIN_DEG``, the gap positive and at most ``HEADING_RESET_MAX_GAP_S``, and the
    pitch away from +-90 deg (where the Euler yaw is not defined)."""
    dt = (after[0] - before[0]) / 1000.0
    if not 0.0 < dt <= HEADING_RESET_MAX_GAP_S:
        return None
    rates = []
    for roll, pitch, q, r in ((before[1], before[2], before[5], before[6]), (after[1], after[2], after[5], after[6])):
        c = math.cos(pitch)
        if abs(c) < 0.3 or not all(math.isfinite(v) for v in (roll, pitch, q, r)):
            return None
        rates.append((q * math.sin(roll) + r * math.cos(roll)) / c)
    turned = 0.5 * (rates[0] + rates[1]) * dt
    change = after[3] - before[3]
    unexplained = math.degrees((change - turned + math.pi) % (2.0 * math.pi) - math.pi)
    return unexplained if math.isfinite(unexplained) and abs(unexplained) >= HEADING_RESET_MIN_DEG else None


class HeadingResetWatch:
    """``heading_reset_deg`` on consecutive ATTITUDE rows ``(time_boot_ms, roll, pitch, yaw, p, q,
    r)``; ``resets`` keeps ``(time_boot_ms, deg)`` of each reset found."""

    def __init__(self) -> None:
        self._last: tuple | None = None
        self.resets: list[tuple[int, float]] = []

    def observe(self, row: tuple) -> float | None:
        """The reset (deg) between the last row and ``row``, or None; a row stamped no later than
        the last one (a repeat, a reordered packet) is ignored."""
        last = self._last
        if last is not None and row[0] <= last[0]:
            return None
        self._last = row
        jump = None if last is None else heading_reset_deg(last, row)
        if jump is not None:
            self.resets.append((int(row[0]), jump))
        return jump
