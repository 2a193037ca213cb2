"""The velocity the law's damping reads, made consistent with the position it tracks.

The law (eq. 28-42) closes its loops on the vehicle's position *and* velocity estimates, and it
assumes that the one is the derivative of the other. An autopilot's estimator need not keep them
so: PX4 v1.16 SITL's EKF2 on its SIH vehicle (whose simulated accelerometer has 0.5-1.7 m/s^2 of
noise) reports velocities that differ from the derivative of its own position estimate by
0.12-0.20 m/s RMS a axis, up to 0.5 m/s, wandering with a correlation time of 1-2 s, and up to
0.3 m/s standing on the ground (docs/controller-design.md, "The velocity the law reads").
A PD law that reads a velocity off by b settles a position error of (k_v / k_p) b away from its
reference; an integral of the velocity error moves the vehicle itself at -b.

``ConsistentVelocity`` is a first-order complementary filter of time constant T: below 1/T the
velocity handed to the law is the derivative of the position estimate, above it the vehicle's
velocity estimate. With the sample time h and the estimates p_k, v_k of sample k,

    d_k = (p_k - p_{k-1}) / h - (v_k + v_{k-1}) / 2       the inconsistency over the last sample
    c_k = c_{k-1} + h / (T + h) (d_k - c_{k-1})           its low-pass (c_0 = 0)
    v'_k = v_k + c_k                                      the velocity the law reads

When the two estimates agree (a rigid body's true state, sitl-plant's streams) d_k is the
trapezoidal rule's error, O(h^2 jerk), and v' = v: the designed loop and its margins are
unchanged. T = 0 switches it off (the paper's law reads the velocity as measured).

Over MAVLink the estimates a sample reads are the latest LOCAL_POSITION_NED, whose age varies
from sample to sample (and a sample may find none newer than the last): h is then the time
between the two messages' own stamps, and a sample with no newer position leaves c as it was.
With h taken as To instead, 20 ms of age jitter on a 2 m/s helix reads as 0.8 m/s of
inconsistency, and sitl-plant at ``--speed 4`` (its position every other sample) flew the helix
with a sample-to-sample ripple.
"""

from __future__ import annotations

import numpy as np


class ConsistentVelocity:
    """The complementary filter of the module docstring, one sample per ``update``.

    Parameters
    ----------
    time_constant_s : float
        T, s (> 0).
    sample_time_s : float
        h, the law's sample time, s (> 0).
    """

    def __init__(self, time_constant_s: float, sample_time_s: float) -> None:
        if not (time_constant_s > 0 and sample_time_s > 0):
            raise ValueError(f"time constant and sample time must be > 0, got {time_constant_s}, {sample_time_s}")
        self.sample_time_s = float(sample_time_s)
        self.time_constant_s = float(time_constant_s)
        self.gain = sample_time_s / (time_constant_s + sample_time_s)
        self.reset()

    def reset(self) -> None:
        """Forget the previous sample: the next one is handed on as measured."""
        self._pos: np.ndarray | None = None
        self._vel: np.ndarray | None = None
        self._time_s: float | None = None
        self.correction_m_s = np.zeros(3)

    def update(self, pos_ned_m: np.ndarray, vel_ned_m_s: np.ndarray, time_s: float | None = None) -> np.ndarray:
        """The velocity the law reads at this sample (NED, m/s).

        ``time_s``: when the estimates were made (the position message's stamp, s), if known;
        without it the samples are To apart.
        """
        pos = np.asarray(pos_ned_m, dtype=float)
        vel = np.asarray(vel_ned_m_s, dtype=float)
        if self._pos is not None and self._vel is not None:
            h = self.sample_time_s if time_s is None or self._time_s is None else time_s - self._time_s
            if h <= 0.0:  # no newer position than the last sample's: nothing to learn
                return vel + self.correction_m_s
            gain = self.gain if time_s is None else h / (self.time_constant_s + h)
            inconsistency = (pos - self._pos) / h - 0.5 * (vel + self._vel)
            self.correction_m_s = self.correction_m_s + gain * (inconsistency - self.correction_m_s)
        self._pos, self._vel, self._time_s = pos, vel, time_s
        return vel + self.correction_m_s
