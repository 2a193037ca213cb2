"""The measured state carried over the latency: what the law is handed instead of the measurement.

Through a link, the setpoint a sample computes acts ``L`` after the measurement it came from (the
telemetry's age, the link both ways, the processing: ``offboard fly`` measures it at start-up).
A law fed the measurement answers a state that is already ``L`` old, and its gains must be slow
enough for that (docs/controller-design.md: the design for 114 ms settles in 8.7 s where the one
for no latency settles in 3.7 s). Fed the state ``L`` ahead, it sees the loop it was designed
for, and the design keeps its bandwidth (4.1 s at 114 ms).

``LatencyPredictor`` computes that state with the design's own linear model of the inner loop
(``design.latency_predictor``), per axis:

- forward (the pitch loop) and right (the roll loop), in the heading frame: position, velocity,
  tilt (``-pitch`` forward, ``roll`` right: ``v_dot = g tilt``) and its rate (``-q``, ``p``);
  the rate loop's integral and the motors' torque, not measured, are taken at hover, or observed
  with ``model.observe`` (below);
- up (the thrust's lag): position and velocity; the lagged acceleration taken at hover;
- the setpoints still in flight: the last ``m + 1`` samples' (``L = m To + delta``), as the model's
  input, ``g tilt_sp`` per horizontal axis and ``u cos(roll_sp) cos(pitch_sp) / m - g`` up.

It keeps no model state between samples beyond those setpoints and the observer's last
measurement (a Smith predictor in finite form): a model error costs accuracy over one latency
and a sample, never a drift.

**The rate loop observed** (``model.observe``, ``design.attitude_observer``). Each sample the
last measured tilt and rate, with the integral and torque observed then, are carried by the
model through the setpoints that acted since to the new measurement's instant, and a share of
what they miss of the measured tilt and rate is put down to the integral and the torque: the
deadbeat correction spread over the observer's memory T (``model.observer_memory_at``, 20
samples: 1 s at To = 50 ms), so that the link's timing noise of one sample moves the estimates
by a twentieth of what it would, and an error of theirs is forgotten within about T.

**The measurement's age.** Sampled on our own clock, a sample reads the telemetry that came last,
and how long ago it came changes from sample to sample: at 100 Hz telemetry and 20 Hz samples, a
sample taken as a burst arrives reads it or the one 10 ms older, by turns, when the two clocks'
phases meet (a real-time flight's position stamps then stepped 40, 60, 40, 60 ms apart). Predicted
over a fixed L, every other state was 10 ms short, and the law answered with setpoints that
alternated by 6 deg of tilt and 0.5 N of thrust sample to sample (1.3 deg where the phases did not
meet, and 0.4 deg in lockstep). An estimate that carries ``age_s`` is predicted over
``L + age - mean age`` (the mean over the last ``AGE_AVERAGE_SAMPLES``): the design's latency on
average, the same instant after the sample every time. The horizons are tabulated around L at
``HORIZON_STEP_S``. The heading is taken as
constant over the latency (the yaw reference's rate is bounded by MPC_YAWRAUTO_MAX, 45 deg/s:
7 deg over 150 ms). Pure numpy; no clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from offboard.controller.command import StateEstimate
from offboard.controller.design import (
    GRAVITY_M_S2,
    HORIZONTAL_MEASURED,
    OBSERVER_MEMORY_SAMPLES,
    VERTICAL_MEASURED,
    InnerLoopModel,
    attitude_observer,
    latency_predictor,
    tilt_axis_plant,
    vertical_plant,
)
from offboard.model.rotations import quat_from_euler


@dataclass(frozen=True)
class PredictedState:
    """A ``StateEstimate`` carried ``latency_s`` ahead (NED/FRD), with the measurement's stamps."""

    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    euler_rad: np.ndarray
    body_rate_frd_rad_s: np.ndarray
    quat_wxyz: np.ndarray
    position_time_boot_ms: float | None = None
    horizon_s: float = 0.0  # how far ahead (s): the latency, moved by the measurement's age


#: the horizons' grid (s): 1 ms of horizon is at most a few tenths of a millimetre and a
#: hundredth of a degree of the predicted state at the law's speeds
HORIZON_STEP_S = 0.001
#: samples over which the measurement's usual age is averaged (exponentially): the observer's
#: memory, the link's timing averaged over one window
AGE_AVERAGE_SAMPLES = OBSERVER_MEMORY_SAMPLES


class LatencyPredictor:
    """The state ``model.latency_s`` after the measurement (module docstring).

    Parameters
    ----------
    model : InnerLoopModel
        The vehicle's inner loop and the latency (``design.inner_loop_from_params``).
    sample_time_s : float
        The law's To.
    mass_kg, gravity_m_s2 : float
        What the law believes: the vertical input is the thrust's acceleration less gravity.
    """

    def __init__(self, model: InnerLoopModel, sample_time_s: float, mass_kg: float, gravity_m_s2: float = GRAVITY_M_S2) -> None:
        if not (model.latency_s > 0.0 and math.isfinite(model.latency_s)):
            raise ValueError(f"a prediction needs a latency > 0, got {model.latency_s}")
        if not (mass_kg > 0.0 and sample_time_s > 0.0):
            raise ValueError(f"mass_kg and sample_time_s must be > 0, got {mass_kg}, {sample_time_s}")
        self.latency_s = model.latency_s
        self.sample_time_s = sample_time_s
        self.mass_kg = mass_kg
        self.gravity_m_s2 = gravity_m_s2
        drag = model.drag_per_s
        axes = ((tilt_axis_plant(model.pitch, gravity_m_s2, drag), HORIZONTAL_MEASURED),
                (tilt_axis_plant(model.roll, gravity_m_s2, drag), HORIZONTAL_MEASURED),
                (vertical_plant(model.thrust_time_constant_s, drag), VERTICAL_MEASURED))  # fmt: skip
        # horizons L + k step, k = -K..K, within [0, L + To]: an age may move the horizon by up to a sample
        steps = int(round(sample_time_s / HORIZON_STEP_S))
        self._horizons = [self.latency_s + k * HORIZON_STEP_S for k in range(-steps, steps + 1)
                          if self.latency_s + k * HORIZON_STEP_S > 0.0]  # fmt: skip
        self._centre = next(i for i, h in enumerate(self._horizons) if abs(h - self.latency_s) < HORIZON_STEP_S / 2)
        self.observe = model.observe
        # the horizontal axes' Mx with every state's column: the observed integral and torque act
        # through the last two (without the observer their estimates stay at hover's zero)
        known = tuple(range(axes[0][0][0].shape[0]))
        tables = [[latency_predictor(a, b, sample_time_s, h, known if self.observe and i < 2 else measured) for h in self._horizons]
                  for i, ((a, b), measured) in enumerate(axes)]  # fmt: skip
        self.in_flight = max(mu.shape[1] for axis in tables for _, mu in axis)  # m + 1 setpoints at the longest horizon
        # per horizon: (Mx, Mu) of forward, right, up, Mu padded with zero columns to in_flight
        self._tables = [tuple((mx, np.pad(mu, ((0, 0), (0, self.in_flight - mu.shape[1])))) for mx, mu in
                              (axis[i] for axis in tables)) for i in range(len(self._horizons))]  # fmt: skip
        # the observer's steps on the horizons' grid, up to two samples (a longer interval, a gap in
        # the telemetry, restarts the estimates at hover; one under half a sample is carried uncorrected)
        self._step_count = int(round(sample_time_s / HORIZON_STEP_S))
        self.observer_memory_s = model.observer_memory_at(sample_time_s)
        self._observer = ([{k: attitude_observer(a, b, k * HORIZON_STEP_S, self.observer_memory_s) for k in range(1, 2 * self._step_count + 1)}
                           for (a, b), _ in axes[:2]] if self.observe else [])  # fmt: skip
        # the setpoints the observer's last interval may reach back to: a latency, two samples and an age
        self._inputs: deque[tuple[float, float, float]] = deque(maxlen=self.in_flight + 3)
        self.reset()

    def reset(self) -> None:
        """No setpoint in flight: the vehicle holds hover's (zero inputs); no age seen yet."""
        self._inputs.clear()
        self._inputs.extend([(0.0, 0.0, 0.0)] * (self.in_flight + 3))
        self._mean_age_s: float | None = None
        #: the observer's last measurement: tilt and rate forward and right, its age (s), and the
        #: observed integral and torque then (hover's zero until a second measurement)
        self._last: tuple[np.ndarray, np.ndarray, float] | None = None
        self._observed = np.zeros((2, 2))

    def horizon_s(self, age_s: float | None) -> float:
        """The horizon a measurement ``age_s`` old is predicted over (module docstring), on the
        grid; the latency itself without an age. Averages the age in (call once a sample)."""
        if age_s is None or not math.isfinite(age_s):
            return self.latency_s
        age = max(0.0, age_s)
        if self._mean_age_s is None:
            self._mean_age_s = age
        else:
            self._mean_age_s += (age - self._mean_age_s) / AGE_AVERAGE_SAMPLES
        k = self._centre + int(round((age - self._mean_age_s) / HORIZON_STEP_S))
        return self._horizons[min(max(k, 0), len(self._horizons) - 1)]

    def _index(self, horizon_s: float) -> int:
        return self._centre + int(round((horizon_s - self.latency_s) / HORIZON_STEP_S))

    def record(self, thrust_n: float, roll_setpoint_rad: float, pitch_setpoint_rad: float) -> None:
        """The setpoint this sample sent (roll and pitch about the heading), as the model's inputs."""
        g = self.gravity_m_s2
        up = thrust_n * math.cos(roll_setpoint_rad) * math.cos(pitch_setpoint_rad) / self.mass_kg - g
        self._inputs.appendleft((-g * pitch_setpoint_rad, g * roll_setpoint_rad, up))  # slot 0: u(n-1) next sample

    def predict(self, state: StateEstimate, vel_ned_m_s: np.ndarray | None = None) -> PredictedState:
        """``state`` carried over the latency (``vel_ned_m_s``: a velocity in place of its own)."""
        pos = np.asarray(state.pos_ned_m, dtype=float)
        vel = np.asarray(state.vel_ned_m_s if vel_ned_m_s is None else vel_ned_m_s, dtype=float)
        roll, pitch, yaw = (float(v) for v in state.euler_rad)
        p_rate, q_rate, r_rate = (float(v) for v in state.body_rate_frd_rad_s)
        c, s = math.cos(yaw), math.sin(yaw)
        # heading frame: forward (c, s), right (-s, c)
        fwd = np.array([c * pos[0] + s * pos[1], c * vel[0] + s * vel[1], -pitch, -q_rate, 0.0, 0.0])
        right = np.array([-s * pos[0] + c * pos[1], -s * vel[0] + c * vel[1], roll, p_rate, 0.0, 0.0])
        up = np.array([-pos[2], -vel[2], 0.0])
        history = np.array(self._inputs)  # u(n-1), u(n-2), ...
        inputs = history[: self.in_flight]  # (m + 1, 3): u(n-1) ... u(n-m-1)
        age_s = getattr(state, "age_s", None)
        horizon = self.horizon_s(age_s)
        if self.observe:
            age = max(0.0, age_s) if age_s is not None and math.isfinite(age_s) else 0.0
            fwd[4:], right[4:] = self._observe(np.array([fwd[2:4], right[2:4]]), age, history)
        (fx, fu), (rx, ru), (ux, uu) = self._tables[self._index(horizon)]
        f = fx @ fwd + fu @ inputs[:, 0]
        r = rx @ right + ru @ inputs[:, 1]
        u = ux @ up + uu @ inputs[:, 2]
        pos_ned = np.array([c * f[0] - s * r[0], s * f[0] + c * r[0], -u[0]])
        vel_ned = np.array([c * f[1] - s * r[1], s * f[1] + c * r[1], -u[1]])
        euler = np.array([r[2], -f[2], yaw])
        rates = np.array([r[3], -f[3], r_rate])
        return PredictedState(pos_ned, vel_ned, euler, rates, np.asarray(quat_from_euler(*euler), dtype=float),
                              getattr(state, "position_time_boot_ms", None), horizon)  # fmt: skip

    def _observe(self, measured: np.ndarray, age_s: float, history: np.ndarray) -> np.ndarray:
        """The rate loops' integral and torque now, forward and right (rows), from the tilt and rate
        ``measured`` now (rows: forward, right) ``age_s`` old (``design.attitude_observer``).

        On the sample's clock (this sample at 0) the last measurement was taken at ``-To - its
        age``, this one at ``-age``, and the setpoint of sample n + k acted over ``[k To + l, (k+1)
        To + l)`` with ``l`` the latency less the usual age (the instant ``predict`` carries a
        state to). The last estimate is carried over the interval through those setpoints and
        corrected by what was measured now.
        """
        last = self._last
        if last is None:
            self._last = (measured, self._observed, age_s)
            return self._observed
        step, count = HORIZON_STEP_S, self._step_count
        start = int(round((-self.sample_time_s - last[2]) / step))
        end = int(round(-age_s / step))
        interval = end - start
        if interval <= 0:  # the same measurement again: the same estimate
            self._last = (last[0], last[1], last[2] + self.sample_time_s)
            return self._observed
        if interval > 2 * count:  # a gap in the telemetry: start again from hover's
            self._observed = np.zeros((2, 2))
            self._last = (measured, self._observed, age_s)
            return self._observed
        offset = int(round((self.latency_s - (self._mean_age_s or 0.0)) / step))
        estimate = np.concatenate([last[0], last[1]], axis=1)  # rows forward, right: tilt, rate, integral, torque
        t = start
        while t < end:
            k = (t - offset) // count  # the setpoint acting at t: sample n + k's, u(n-1) in slot 0
            until = min((k + 1) * count + offset, end)
            slot = min(max(-1 - k, 0), len(history) - 1)
            for axis in (0, 1):
                phi, gamma, _ = self._observer[axis][until - t]
                estimate[axis] = phi @ estimate[axis] + gamma[:, 0] * history[slot, axis]
            t = until
        observed = estimate[:, 2:].copy()
        if interval >= count // 2:  # a shorter interval says too little of the two: carried only
            for axis in (0, 1):
                observed[axis] += self._observer[axis][interval][2] @ (measured[axis] - estimate[axis, :2])
        self._observed = observed
        self._last = (measured, observed, age_s)
        return observed
