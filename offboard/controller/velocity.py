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

import math
from dataclasses import dataclass

import numpy as np


class ConsistentVelocity:
    """The complementary filter of the module docstring, one sample per ``update``.

    Works elementwise on any shape of estimates ((3,) for one vehicle, (n, 3) for a batch).

    Parameters
    ----------
    time_constant_s : float
        T, s (> 0); with ``identify``, the T until the estimates' noise is known.
    sample_time_s : float
        h, the law's sample time, s (> 0).
    identify : bool
        Choose T from the estimates' own noise as they arrive (``InconsistencyVariogram`` over
        the last ``IDENTIFY_MEMORY_S``, from ``IDENTIFY_AFTER_S`` of samples on and every
        ``IDENTIFY_EVERY_S`` after; each vehicle of a batch its own): the steady-state Kalman
        filter of their velocity bias (``EstimateNoise.time_constant_s``). ``time_constant_s``
        reads the T in use, ``noise`` what was identified.
    """

    def __init__(self, time_constant_s: float, sample_time_s: float, *, identify: bool = False) -> None:
        if not (time_constant_s > 0 and sample_time_s > 0):
            raise ValueError(f"time constant and sample time must be > 0, got {time_constant_s}, {sample_time_s}")
        self.sample_time_s = float(sample_time_s)
        self.initial_time_constant_s = float(time_constant_s)
        self.identify = bool(identify)
        self.reset()

    def reset(self) -> None:
        """Forget the previous sample (the next one is handed on as measured) and what was identified."""
        self._pos: np.ndarray | None = None
        self._vel: np.ndarray | None = None
        self._time_s: float | None = None
        self.correction_m_s = np.zeros(3)
        self.time_constant_s: float | np.ndarray = self.initial_time_constant_s
        self.noise: EstimateNoise | None = None  # what ``identify`` found, once it has
        self.variogram = (InconsistencyVariogram(self.sample_time_s, memory_s=IDENTIFY_MEMORY_S)
                          if self.identify else None)  # fmt: skip

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
            inconsistency = (pos - self._pos) / h - 0.5 * (vel + self._vel)
            if self.variogram is not None:
                self.variogram.add(inconsistency)
                after = self.variogram.samples - round(IDENTIFY_AFTER_S / self.sample_time_s)
                every = max(round(IDENTIFY_EVERY_S / self.sample_time_s), 1)
                if after >= 0 and after % every == 0 and self.variogram.ready:
                    self.noise = self.variogram.noise()
                    self.time_constant_s = self.noise.time_constant_s()
            constant = np.asarray(self.time_constant_s)
            gain = h / (constant + h)
            if constant.ndim:  # one T per vehicle of a batch: over its axes
                gain = gain[..., None]
            self.correction_m_s = self.correction_m_s + gain * (inconsistency - self.correction_m_s)
        self._pos, self._vel, self._time_s = pos, vel, time_s
        return vel + self.correction_m_s


# --- choosing T from the estimates' own noise --------------------------------------------------

#: The longest lag of the inconsistency the variogram fits, s, and so the longest T it chooses:
#: a bias that walks more slowly than a record resolves over this span is invisible in it.
NOISE_FIT_SPAN_S = 1.0
#: ``ConsistentVelocity(identify=True)``: identifies from this many seconds of samples on, every
#: IDENTIFY_EVERY_S, ...
IDENTIFY_AFTER_S = 5.0
IDENTIFY_EVERY_S = 1.0
#: ... weighting each sample by exp(-age / IDENTIFY_MEMORY_S) (an estimator's noise changes with
#: what the vehicle does: on the ground, hovering, manoeuvring).
IDENTIFY_MEMORY_S = 30.0


@dataclass(frozen=True)
class EstimateNoise:
    """What the inconsistency ``d_k`` of a vehicle's estimates is made of, at the sample time h.

    The model: ``d_k = b_k + e_k``, a velocity bias b that walks at ``bias_walk_m_s_sqrt_s``
    (sigma_b: its change over t seconds has a standard deviation of sigma_b sqrt(t)) seen through
    a sample-to-sample noise e of standard deviation ``white_m_s`` (sigma_e), which the
    position's white noise sigma_p makes correlated over one sample only
    (e_k = (w_k - w_{k-1}) / h - (v_k + v_{k-1}) / 2 noise). For a lag of L >= 2 samples the
    half mean square change of d is then a line in L,

        V(L) = 1/2 E[(d_{k+L} - d_k)^2] = sigma_e^2 + 1/2 sigma_b^2 h L,

    which ``InconsistencyVariogram`` fits over L = 2 ... ``NOISE_FIT_SPAN_S`` / h (intercept and
    slope each at least 0). At L = 1 the variogram exceeds the line by minus e's lag-1
    covariance, sigma_p^2 / h^2 where the velocity's own noise is smaller: ``position_white_m``
    (for the record; T does not need it). Each field is a float, or an array over a batch.
    """

    sample_time_s: float
    white_m_s: float | np.ndarray
    bias_walk_m_s_sqrt_s: float | np.ndarray
    position_white_m: float | np.ndarray
    samples: int

    def time_constant_s(self) -> float | np.ndarray:
        """The T for which ``ConsistentVelocity`` is the steady-state Kalman filter of the bias.

        The bias b_k = b_{k-1} + u_k (var Q = sigma_b^2 h) seen through d_k = b_k + e_k (var
        R = sigma_e^2, taken as white): the prior variance P = Q/2 + sqrt(Q^2/4 + Q R), the gain
        K = P / (P + R), and the filter's gain h / (T + h) equals K at T = h (1 - K) / K; kept
        within a hundredth of h (R = 0: the position's derivative alone) and
        ``NOISE_FIT_SPAN_S`` (Q = 0, or too small for the record to show).
        """
        h = self.sample_time_s
        q = np.asarray(self.bias_walk_m_s_sqrt_s, dtype=float) ** 2 * h
        r = np.asarray(self.white_m_s, dtype=float) ** 2
        prior = 0.5 * q + np.sqrt(0.25 * q * q + q * r)
        with np.errstate(divide="ignore", invalid="ignore"):
            constant = np.where(prior > 0.0, h * r / np.where(prior > 0.0, prior, 1.0), np.inf)
        constant = np.where((q > 0.0) & (r <= 0.0), 0.0, constant)
        constant = np.clip(constant, 0.01 * h, max(NOISE_FIT_SPAN_S, 4 * h))
        return float(constant) if constant.ndim == 0 else constant


class InconsistencyVariogram:
    """The half mean square changes V(L) of the inconsistency d over lags L = 1 ... span, as the
    samples arrive, and the ``EstimateNoise`` fitted to them (``EstimateNoise``'s model).

    ``add`` takes d of one sample: shape (..., 3) (NED; one vehicle, or a batch), of which
    ``axes`` (default north and east, the ones the tilt answers) are pooled. ``memory_s``: each
    sample weighted by exp(-age / memory_s); None weights them alike.
    """

    def __init__(self, sample_time_s: float, *, memory_s: float | None = None, axes: tuple[int, ...] = (0, 1)) -> None:
        h = float(sample_time_s)
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"sample time must be > 0, got {sample_time_s}")
        if memory_s is not None and not (memory_s > 0):
            raise ValueError(f"memory must be > 0 s, got {memory_s}")
        self.sample_time_s = h
        self.span = max(round(NOISE_FIT_SPAN_S / h), 4)
        self.lags = np.arange(1, self.span + 1)
        self.keep = 1.0 if memory_s is None else math.exp(-h / memory_s)
        self.axes = list(axes)
        self.samples = 0  # added, folded or not
        self._folded = 0
        self._pending: list[np.ndarray] = []  # added since the last fold
        self._recent: np.ndarray | None = None  # the last span folded samples' d, oldest first
        self._sums: np.ndarray | None = None  # per lag: weighted sum of the pooled half squares
        self._weights = np.zeros(self.span)  # per lag: weighted count of the pairs

    def add(self, inconsistency_m_s: np.ndarray) -> None:
        """One sample's d (a copy is kept); the sums take it in at the next ``noise``."""
        self._pending.append(np.array(inconsistency_m_s, dtype=float)[..., self.axes])
        self.samples += 1
        if len(self._pending) >= 1024:
            self._fold()

    def _fold(self) -> None:
        """The pending samples into the sums, as one sample after another would be (each pair
        weighted keep^(its age in samples)), in one pass over a block: cheaper than per sample."""
        if not self._pending:
            return
        block = np.stack(self._pending)
        self._pending = []
        m, span = block.shape[0], self.span
        if self._recent is None or self._sums is None:
            self._recent = np.zeros((span, *block.shape[1:]))
            self._sums = np.zeros((span, *block.shape[1:-1]))
        history = np.concatenate([self._recent, block])  # the block's sample j at span + j
        ages = self.keep ** np.arange(m - 1, -1, -1, dtype=float)  # newest: 1
        decay = self.keep**m
        self._sums *= decay
        self._weights *= decay
        first = self._folded  # the global index of the block's first sample
        lags = self.lags[:, None]
        weights = np.where(np.arange(first, first + m)[None, :] - lags >= 0, ages[None, :], 0.0)  # (lag, j)
        if block.ndim == 2:  # one vehicle: every lag at once, (lag, j, axis)
            past = history[span - lags + np.arange(m)[None, :]]
            half = 0.5 * np.mean((block[None] - past) ** 2, axis=-1)
            self._sums += (weights * half).sum(axis=1)
        else:  # a batch: lag by lag, each over the vehicles (all lags at once outgrow the cache)
            for lag in range(1, span + 1):
                half = 0.5 * np.mean((block - history[span - lag : span - lag + m]) ** 2, axis=-1)
                self._sums[lag - 1] += np.tensordot(weights[lag - 1], half, axes=(0, 0))
        self._weights += weights.sum(axis=1)
        self._recent = history[-span:]
        self._folded += m

    @property
    def ready(self) -> bool:
        """Whether ``noise`` has the samples it needs (5 spans)."""
        return self.samples >= 5 * self.span

    def noise(self) -> EstimateNoise:
        """The fit of ``EstimateNoise``'s model; raises ``ValueError`` before there are 5 spans of samples."""
        self._fold()
        if not self.ready or self._sums is None:
            h = self.sample_time_s
            raise ValueError(f"need at least {5 * self.span} samples ({5 * self.span * h:g} s at {h:g} s), got {self.samples}")
        h = self.sample_time_s
        v = self._sums / self._weights.reshape((-1,) + (1,) * (self._sums.ndim - 1))
        lags = self.lags[1:].astype(float).reshape((-1,) + (1,) * (v.ndim - 1))
        fit = v[1:]
        mean_lag, mean_v = lags.mean(axis=0), fit.mean(axis=0)
        slope = ((lags - mean_lag) * (fit - mean_v)).sum(axis=0) / ((lags - mean_lag) ** 2).sum(axis=0)
        intercept = mean_v - slope * mean_lag
        through_origin = (lags * fit).sum(axis=0) / (lags * lags).sum(axis=0)  # where the intercept came out < 0
        slope = np.maximum(np.where(intercept < 0.0, through_origin, slope), 0.0)
        intercept = np.maximum(intercept, 0.0)
        excess = np.maximum(v[0] - (intercept + slope), 0.0)  # at L = 1: sigma_p^2 / h^2

        def out(a: np.ndarray) -> float | np.ndarray:
            return float(a) if np.ndim(a) == 0 else a

        return EstimateNoise(h, out(np.sqrt(intercept)), out(np.sqrt(2.0 * slope / h)), out(h * np.sqrt(excess)),
                             self.samples)  # fmt: skip


def estimate_noise(pos_ned_m: np.ndarray, vel_ned_m_s: np.ndarray, sample_time_s: float,
                   time_s: np.ndarray | None = None, axes: tuple[int, ...] = (0, 1)) -> EstimateNoise:  # fmt: skip
    """``EstimateNoise`` of a record of estimates sampled every ``sample_time_s`` (arrays (n, 3),
    NED, in time order), every sample weighted alike, pooled over ``axes``.
    ``time_s``: the estimates' own stamps, if known (as ``ConsistentVelocity.update`` takes them:
    the derivative then divides by their differences; a repeated stamp is skipped).

    Raises ``ValueError`` naming the fault: fewer samples than 5 fitted spans, a non-finite
    value, shapes that differ, stamps that go backwards.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    vel = np.asarray(vel_ned_m_s, dtype=float)
    if pos.shape != vel.shape or pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"position and velocity must both be (n, 3), got {pos.shape} and {vel.shape}")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
        raise ValueError("the estimates hold a non-finite value")
    variogram = InconsistencyVariogram(sample_time_s, axes=axes)
    if pos.shape[0] <= 5 * variogram.span:
        raise ValueError(f"need more than {5 * variogram.span} samples ({5 * variogram.span * variogram.sample_time_s:g} s "
                         f"at {variogram.sample_time_s:g} s), got {pos.shape[0]}")
    step = np.full(pos.shape[0] - 1, variogram.sample_time_s)
    if time_s is not None:
        stamps = np.asarray(time_s, dtype=float)
        if stamps.shape != (pos.shape[0],) or not np.all(np.isfinite(stamps)):
            raise ValueError(f"time_s must hold one finite stamp per sample, got shape {stamps.shape}")
        step = np.diff(stamps)
        if np.any(step < 0):
            raise ValueError("time_s goes backwards")
    fresh = step > 0
    d = np.diff(pos, axis=0)[fresh] / step[fresh, None] - 0.5 * (vel[1:] + vel[:-1])[fresh]
    for row in d:
        variogram.add(row)
    return variogram.noise()
