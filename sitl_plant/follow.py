"""PX4's Follow Target in miniature (AUTO_FOLLOW_TARGET, main mode 4 sub mode 8): pure, no sockets,
no clock (it is given the time, the vehicle's position and the target's reports).

PX4 v1.16 flies the mode with the flight task ``FlightTaskAutoFollowTarget`` and its
``TargetEstimator`` (``src/modules/flight_mode_manager/tasks/AutoFollowTarget``, v1.13 on); both
are followed here, in the same steps:

- **The target estimator** (``TargetEstimator``): an alpha-beta-gamma filter of the target's
  position, velocity and acceleration, fed by the FOLLOW_TARGET messages a ground station sends
  (latitude, longitude, altitude AMSL, velocity NED; MAVLink #144). The gains come from
  ``FLW_TGT_RS`` (responsiveness r, within [0.1, 1]): beta = r^(1/3), G = 1 - beta^3,
  H = 1.5 (1 - beta)^2 (1 + beta), K = 0.5 (1 - beta)^3 for a position report, and with
  beta_v = 0.9 beta, G_v = 1 - beta_v^2, H_v = (1 - beta_v)^2 for a velocity report. Positions
  are fused at most every 0.5 s, velocities every 0.1 s; between reports the estimate is predicted
  forward (constant acceleration). When no report has come for 3 s the estimate stops where it is
  (velocity and acceleration zeroed): the vehicle then holds its place about it.
- **The flight task** (``FollowTarget``): a second-order filter (natural frequency 1 rad/s,
  damping 0.7071) smooths the estimate; the target's course is its filtered velocity's direction,
  kept while it moves slower than 1 m/s. The vehicle's place is on a circle of radius
  ``FLW_TGT_DST`` about the filtered target, at the orbit angle course + ``FLW_TGT_FA`` (180:
  behind); the orbit angle moves towards it as a trajectory limited to ``FLW_TGT_MAX_VEL`` / r
  (rad/s), 2 / r (rad/s^2) and the braking distance that a jerk of 4 / r (rad/s^3) allows. The
  height is ``FLW_TGT_HT`` above home (``FLW_TGT_ALT_M`` 0, and 1 over the plant's flat ground) or
  above the target (2). More than 3 m from that height only the height is flown (the horizontal
  position held); within it, the place with the target's filtered velocity plus the orbit's
  tangential velocity as feed-forward, and the orbit's acceleration. The nose points at the
  filtered target when it is more than 1 m away.

Not simulated: the sticks' adjustment of height, distance and angle (MANUAL_CONTROL in this mode),
the gimbal, the emergency climb below 1 m above the ground, and PX4's velocity-only hold (with
no target yet the plant holds the position where the mode began; PX4 drifted about 1 m in 4 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sitl_plant.params import ParamTable

# TargetEstimator.hpp (PX4 v1.16)
STALE_TIMEOUT_S = 3.0  # GPS_MESSAGE_STALE_TIMEOUT_MS: the target is lost; its estimate stops
POS_FUSION_INTERVAL_S = 0.5  # MINIMUM_TIME_BETWEEN_POS_FUSIONS_MS
VEL_FUSION_INTERVAL_S = 0.1  # MINIMUM_TIME_BETWEEN_VEL_FUSIONS_MS
ACCELERATION_SATURATION_M_S2 = 20.0  # ACCELERATION_SATURATION (2 g)
# FlightTaskAutoFollowTarget.hpp (PX4 v1.16)
FILTER_NATURAL_FREQUENCY_RAD_S = 1.0  # TARGET_POS_VEL_FILTER_NATURAL_FREQUENCY
FILTER_DAMPING = 0.7071  # TARGET_POS_VEL_FILTER_DAMPING_RATIO
COURSE_SPEED_DEADZONE_M_S = 1.0  # TARGET_SPEED_DEADZONE_FOR_ORIENTATION_TRACKING
ORBIT_MAX_JERK_M_S3 = 4.0  # ORBIT_TRAJECTORY_MAX_JERK (divided by the distance: rad/s^3)
ORBIT_MAX_ACC_M_S2 = 2.0  # ORBIT_TRAJECTORY_MAX_ACCELERATION (divided by the distance: rad/s^2)
ALT_ACCEPTANCE_M = 3.0  # ALT_ACCEPTANCE_THRESHOLD: farther from the height, only the height is flown
YAW_MIN_DISTANCE_M = 1.0  # MINIMUM_DISTANCE_TO_TARGET_FOR_YAW_CONTROL

ALT_MODE_HOME, ALT_MODE_TERRAIN, ALT_MODE_TARGET = 0, 1, 2  # FLW_TGT_ALT_M

Vec3 = tuple[float, float, float]


def _finite(v: Vec3 | None) -> bool:
    return v is not None and math.isfinite(v[0] + v[1] + v[2])  # a NaN or an infinity stays one in the sum


def estimator_gains(responsiveness: float) -> tuple[float, float, float, float, float]:
    """(G_p, H_p, K_p, G_v, H_v) of PX4's TargetEstimator (``update_filter_gains``) for
    ``FLW_TGT_RS``, clipped to [0.1, 1] as PX4 clips it."""
    r = min(max(responsiveness, 0.1), 1.0)
    beta_p = r ** (1.0 / 3.0)  # G = 1 - beta^3 = 1 - r
    beta_v = 0.9 * beta_p
    return (1.0 - beta_p**3, 1.5 * (1.0 - beta_p) ** 2 * (1.0 + beta_p), 0.5 * (1.0 - beta_p) ** 3,
            1.0 - beta_v**2, (1.0 - beta_v) ** 2)  # fmt: skip


@dataclass
class TargetEstimator:
    """The target's position, velocity and acceleration (local NED, m, m/s, m/s^2) from its
    FOLLOW_TARGET reports: PX4's alpha-beta-gamma filter (module docstring)."""

    responsiveness: float = 0.1
    pos: Vec3 | None = None
    vel: Vec3 | None = None
    acc: Vec3 | None = None
    last_report_s: float | None = None
    _pos_fused_s: float | None = None
    _vel_fused_s: float | None = None
    _pos_old: Vec3 | None = None
    _vel_old: Vec3 | None = None

    @property
    def valid(self) -> bool:
        """Whether the estimate's position, velocity and acceleration are all finite."""
        return _finite(self.pos) and _finite(self.vel) and _finite(self.acc)

    def stale(self, now_s: float) -> bool:
        """Whether no report came in the last ``STALE_TIMEOUT_S`` (or none ever)."""
        return self.last_report_s is None or now_s - self.last_report_s >= STALE_TIMEOUT_S

    def report(self, now_s: float, pos_ned_m: Vec3, vel_ned_m_s: Vec3) -> None:
        """A FOLLOW_TARGET received at ``now_s`` (PX4 stamps it on reception)."""
        if self.last_report_s is not None and now_s <= self.last_report_s:
            return  # a duplicate or one from the past: PX4 skips it
        if not _finite(pos_ned_m):
            return
        if self.last_report_s is None:  # the first report initialises the filter
            self.pos = pos_ned_m
            self.vel = vel_ned_m_s if _finite(vel_ned_m_s) else (0.0, 0.0, 0.0)
            self.acc = (0.0, 0.0, 0.0)
            self._pos_old, self._vel_old = pos_ned_m, vel_ned_m_s
        self.last_report_s = now_s
        g_p, h_p, k_p, g_v, h_v = estimator_gains(self.responsiveness)
        assert self.pos is not None and self.vel is not None and self.acc is not None
        if self._fusable(now_s, pos_ned_m, self._pos_old, self._pos_fused_s, POS_FUSION_INTERVAL_S):
            dt = min(max(now_s - (self._pos_fused_s if self._pos_fused_s is not None else -math.inf), 1e-3), 20.0)
            self._pos_fused_s = now_s
            innov = [m - e for m, e in zip(pos_ned_m, self.pos)]
            self.pos = _add(self.pos, [g_p * i for i in innov])
            self.vel = _add(self.vel, [h_p / dt * i for i in innov])
            self.acc = _add(self.acc, [2.0 * k_p / (dt * dt) * i for i in innov])
            self._pos_old = pos_ned_m
        if self._fusable(now_s, vel_ned_m_s, self._vel_old, self._vel_fused_s, VEL_FUSION_INTERVAL_S):
            dt = min(max(now_s - (self._vel_fused_s if self._vel_fused_s is not None else -math.inf), 1e-3), 20.0)
            self._vel_fused_s = now_s
            innov = [m - e for m, e in zip(vel_ned_m_s, self.vel)]
            self.vel = _add(self.vel, [g_v * i for i in innov])
            self.acc = _add(self.acc, [h_v / dt * i for i in innov])
            self._vel_old = vel_ned_m_s
        a = math.sqrt(sum(x * x for x in self.acc))
        if a > ACCELERATION_SATURATION_M_S2:
            k = ACCELERATION_SATURATION_M_S2 / a
            self.acc = (self.acc[0] * k, self.acc[1] * k, self.acc[2] * k)

    @staticmethod
    def _fusable(now_s: float, value: Vec3, old: Vec3 | None, fused_s: float | None, interval_s: float) -> bool:
        """PX4's ``measurement_can_be_fused``: finite, at least ``interval_s`` after the last
        fusion, and changed (or the last fusion more than twice the interval ago)."""
        since = math.inf if fused_s is None else now_s - fused_s
        changed = old is None or not _finite(old) or math.dist(value, old) > 2.0 * 1.2e-7  # 2 FLT_EPSILON
        return _finite(value) and since > interval_s and (changed or since > 2.0 * interval_s)

    def predict(self, now_s: float, dt: float) -> None:
        """Move the estimate forward by ``dt`` (PX4 runs it every 10 ms); a lost target's estimate
        stops (velocity and acceleration zero)."""
        if not self.valid:
            return
        assert self.pos is not None and self.vel is not None and self.acc is not None
        if dt > 0.0:
            self.pos = _add(self.pos, [v * dt + 0.5 * a * dt * dt for v, a in zip(self.vel, self.acc)])
            self.vel = _add(self.vel, [a * dt for a in self.acc])
        if self.stale(now_s):
            self.vel, self.acc = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class FollowSetpoint:
    """What the flight task asks for: a position (``hold_xy`` False: only the height, the
    horizontal position where the vehicle is), a velocity and horizontal acceleration
    feed-forward, and a yaw (rad)."""

    pos_ned_m: Vec3
    yaw_rad: float
    vel_ned_m_s: Vec3 = (0.0, 0.0, 0.0)
    acc_ff_ne_m_s2: tuple[float, float] = (0.0, 0.0)


@dataclass
class FollowTarget:
    """PX4's ``FlightTaskAutoFollowTarget`` with its target estimator, for one activation
    (module docstring). ``params``: the plant's table (``FLW_TGT_*``), read at every step."""

    params: ParamTable
    estimator: TargetEstimator = field(default_factory=TargetEstimator)
    home_down_m: float = 0.0
    yaw_sp: float = 0.0
    orbit_angle: float = 0.0  # rad, from north towards east, of the vehicle about the target
    orbit_rate: float = 0.0  # rad/s
    course: float = 0.0  # rad: the target's direction of motion
    filt_pos: Vec3 | None = None
    filt_vel: Vec3 = (0.0, 0.0, 0.0)
    last_s: float | None = None

    def activate(self, yaw_rad: float, home_down_m: float, now_s: float) -> None:
        """The mode begins: PX4 builds the task (and its estimator) afresh."""
        self.estimator = TargetEstimator(float(self.params["FLW_TGT_RS"]))
        self.home_down_m = home_down_m
        self.yaw_sp = yaw_rad
        self.orbit_angle = self.orbit_rate = self.course = 0.0
        self.filt_pos, self.filt_vel = None, (0.0, 0.0, 0.0)
        self.last_s = now_s

    def report(self, now_s: float, pos_ned_m: Vec3, vel_ned_m_s: Vec3) -> None:
        """A FOLLOW_TARGET received at ``now_s``, handed to the target estimator."""
        self.estimator.report(now_s, pos_ned_m, vel_ned_m_s)

    def step(self, now_s: float, pos_ned_m: Vec3) -> FollowSetpoint | None:
        """Advance to ``now_s`` with the vehicle at ``pos_ned_m``; None while there is no target
        estimate (the autopilot holds)."""
        dt = 0.0 if self.last_s is None else max(0.0, now_s - self.last_s)
        self.last_s = now_s
        est = self.estimator
        est.predict(now_s, dt)
        if not est.valid:
            return None
        assert est.pos is not None and est.vel is not None
        self._filter(est.pos, est.vel, dt)
        assert self.filt_pos is not None
        p = self.params
        dist = max(float(p["FLW_TGT_DST"]), 1e-3)
        follow_angle = _wrap(math.radians(float(p["FLW_TGT_FA"])))
        fvel = self.filt_vel
        if math.hypot(fvel[0], fvel[1]) >= COURSE_SPEED_DEADZONE_M_S and math.hypot(est.vel[0], est.vel[1]) >= COURSE_SPEED_DEADZONE_M_S:
            self.course = math.atan2(fvel[1], fvel[0])
        acc_angular = self._orbit(self.course + follow_angle, dist, float(p["FLW_TGT_MAX_VEL"]), dt)
        th = self.orbit_angle
        tangent = (-math.sin(th), math.cos(th))
        v_tan = self.orbit_rate * dist
        height = float(p["FLW_TGT_HT"])
        down = self.filt_pos[2] - height if int(p["FLW_TGT_ALT_M"]) == ALT_MODE_TARGET else self.home_down_m - height
        want = (self.filt_pos[0] + dist * math.cos(th), self.filt_pos[1] + dist * math.sin(th), down)
        to_target = (self.filt_pos[0] - pos_ned_m[0], self.filt_pos[1] - pos_ned_m[1])
        if math.hypot(*to_target) > YAW_MIN_DISTANCE_M:
            self.yaw_sp = math.atan2(to_target[1], to_target[0])
        if abs(want[2] - pos_ned_m[2]) >= ALT_ACCEPTANCE_M:
            return FollowSetpoint((pos_ned_m[0], pos_ned_m[1], want[2]), self.yaw_sp)  # the height first
        centripetal = v_tan * v_tan / dist
        acc = (-centripetal * math.cos(th) + acc_angular * dist * tangent[0], -centripetal * math.sin(th) + acc_angular * dist * tangent[1])
        vel = (v_tan * tangent[0] + fvel[0], v_tan * tangent[1] + fvel[1], 0.0)
        return FollowSetpoint(want, self.yaw_sp, vel, acc)

    def _filter(self, pos: Vec3, vel: Vec3, dt: float) -> None:
        """PX4's SecondOrderReferenceModel of the target (position with velocity as the rate
        sample): x'' = wn^2 (p - x) + 2 zeta wn (v - x'); reset to the estimate at first."""
        if self.filt_pos is None:
            self.filt_pos, self.filt_vel = pos, vel
            return
        k, d = FILTER_NATURAL_FREQUENCY_RAD_S**2, 2.0 * FILTER_DAMPING * FILTER_NATURAL_FREQUENCY_RAD_S
        acc = [k * (p - x) + d * (v - xd) for p, x, v, xd in zip(pos, self.filt_pos, vel, self.filt_vel)]
        self.filt_vel = _add(self.filt_vel, [a * dt for a in acc])
        self.filt_pos = _add(self.filt_pos, [v * dt for v in self.filt_vel])

    def _orbit(self, goal: float, dist: float, max_vel_m_s: float, dt: float) -> float:
        """The orbit angle towards ``goal`` (rad), PX4's ``updateOrbitAngleTrajectory`` with the
        rate limited to FLW_TGT_MAX_VEL / r and by the braking distance (``computeMaxSpeedFromDistance``,
        jerk 4 / r, acceleration 2 / r), reached at 2 / r rad/s^2 (PX4's smoothing also limits the
        jerk). Returns the angular acceleration (rad/s^2)."""
        remaining = _wrap(goal - self.orbit_angle)
        jerk, acc_max, rate_max = ORBIT_MAX_JERK_M_S3 / dist, ORBIT_MAX_ACC_M_S2 / dist, max(max_vel_m_s, 0.0) / dist
        b = 4.0 * acc_max * acc_max / jerk
        braking = 0.5 * (-b + math.sqrt(b * b + 8.0 * acc_max * abs(remaining)))
        want = math.copysign(min(braking, rate_max), remaining)
        if dt <= 0.0:
            return 0.0
        change = min(max(want - self.orbit_rate, -acc_max * dt), acc_max * dt)
        self.orbit_rate += change
        self.orbit_angle = _wrap(self.orbit_angle + self.orbit_rate * dt)
        return change / dt


def _add(a: Vec3, b: list[float]) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


__all__ = ["TargetEstimator", "FollowTarget", "FollowSetpoint", "estimator_gains", "STALE_TIMEOUT_S"]
