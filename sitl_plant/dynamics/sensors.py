"""Sensor models: what the controller measures of the true ``VehicleState``.

Each model is an object with ``measure(truth) -> VehicleState``, called once per control
sample with the true state, and ``reset()`` to start a new run with the same seed. Kinds:

- ``CleanSensors``: the truth.
- ``PaperAccelNoise``: the paper's Simulation 2 (Section 4): white Gaussian noise on the
  measured accelerations, 5 % of their value, with velocity and position obtained by
  integrating them (so their errors drift as random walks); attitude and rates clean.
- ``ImuNoise``: ordinary white noise on position, velocity, attitude, rates and acceleration,
  the size of a GPS/EKF estimate's sample-to-sample jitter.

``DeadReckoning`` is not one of them: it is what the plant's estimate becomes once its GPS is
lost (``advance(dt_s)`` as time passes, ``measure(state)``), on top of whichever
model measures.

Two ways in: a command-line spec (``sensors_from_spec("paper:0.05", seed)``) and a TOML
table (``sensors_from_table``). See ``docs/model.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from offboard.model.euler_lagrange import zyx_euler_rates_from_body_rates
from offboard.model.rotations import euler_from_quat, quat_multiply, wrap_pi
from offboard.model.errors import UserError
from offboard.model.state import VehicleState
from offboard.model.tomlfile import Fields
from sitl_plant.dynamics import specstring

__all__ = [
    "SensorModel",
    "SensorSpecError",
    "CleanSensors",
    "PaperAccelNoise",
    "ImuNoise",
    "DeadReckoning",
    "IMU_DEFAULTS",
    "sensors_from_spec",
    "sensors_from_table",
    "SENSOR_SPEC_HELP",
]

SENSOR_SPEC_HELP = "clean | paper[:FRACTION] | imu[:pos=M,vel=M_S,att=RAD,rate=RAD_S,acc=M_S2]"


class SensorModel(Protocol):
    """What the controller sees of the true state."""

    def measure(self, truth: VehicleState) -> VehicleState:
        """The measured state for this control sample."""
        ...

    def reset(self) -> None:
        """Forget past samples and restart the noise from the seed."""
        ...


class SensorSpecError(UserError, ValueError):
    """A sensor spec string the user wrote is malformed; the message is one line."""


class CleanSensors:
    """Perfect measurements: ``measure`` returns the truth."""

    def measure(self, truth: VehicleState) -> VehicleState:
        """The truth itself."""
        return truth

    def reset(self) -> None:
        """Nothing to forget."""

    def __repr__(self) -> str:
        return "CleanSensors()"


class PaperAccelNoise:
    """The paper's measurement noise: 5 % on the accelerations, integrated into speed and position.

    Between samples n and n+1 (interval ``dt``) the mean acceleration is
    ``a = (v(n+1) - v(n)) / dt``; the accelerometer reads it with white Gaussian noise
    ``eta ~ N(0, (fraction |a_i|)^2)`` on each axis. Integrating the noisy acceleration adds
    ``eta dt`` to the measured velocity and, over the interval, ``dt (e_v(n) + e_v(n+1)) / 2``
    to the measured position (exact for an error that grows linearly over the interval)::

        v_meas(n+1) = v_meas(n) + (v(n+1) - v(n)) + eta dt
        p_meas(n+1) = p_meas(n) + (p(n+1) - p(n)) + dt (e_v(n) + e_v(n+1)) / 2,  e_v = v_meas - v

    so with ``fraction = 0`` the measurement is the truth exactly (no integration drift), and
    otherwise the velocity and position errors are random walks. The reported acceleration
    is the truth plus ``eta``. Attitude, angular rates and everything else are clean. The
    first sample (or one whose time is not after the previous) starts a new integration
    from the truth.

    Parameters
    ----------
    fraction : float
        Noise standard deviation as a fraction of the acceleration's magnitude, per axis
        (the paper's 5 % = 0.05), >= 0.
    seed : int or sequence of int
        Seeds ``numpy.random.default_rng``.
    """

    def __init__(self, fraction: float = 0.05, seed: int | Sequence[int] = 0) -> None:
        if not (math.isfinite(fraction) and fraction >= 0):
            raise ValueError(f"fraction must be >= 0, got {fraction}")
        self.fraction = float(fraction)
        self.seed = seed
        self.reset()

    def reset(self) -> None:
        """Back to the seed's first draw, with no integrated error."""
        self._rng = np.random.default_rng(np.random.SeedSequence(self.seed))
        self._previous: VehicleState | None = None
        self._vel_error = np.zeros(3)
        self._pos_error = np.zeros(3)

    def normals(self, samples: int) -> np.ndarray:
        """(samples, 3): the standard normals ``measure`` draws after a ``reset``, three a sample,
        in order (what a batch of these flights draws at once: ``offboard.sweep.batch``)."""
        return np.random.default_rng(np.random.SeedSequence(self.seed)).standard_normal((samples, 3))

    def measure(self, truth: VehicleState) -> VehicleState:
        """The truth with this sample's acceleration noise (``fraction`` of the mean acceleration since the
        last sample, a draw per axis), and the velocity and position errors it integrates to (trapezoidal).
        """
        previous, self._previous = self._previous, truth
        if previous is None or not truth.time_s > previous.time_s:
            self._vel_error = np.zeros(3)
            self._pos_error = np.zeros(3)
            noise = self.fraction * np.abs(truth.acc_ned_m_s2) * self._rng.standard_normal(3)
        else:
            dt = truth.time_s - previous.time_s
            mean_acc = (truth.vel_ned_m_s - previous.vel_ned_m_s) / dt
            noise = self.fraction * np.abs(mean_acc) * self._rng.standard_normal(3)
            vel_error = self._vel_error + noise * dt
            self._pos_error = self._pos_error + 0.5 * dt * (self._vel_error + vel_error)
            self._vel_error = vel_error
        return replace(
            truth,
            pos_ned_m=truth.pos_ned_m + self._pos_error,
            vel_ned_m_s=truth.vel_ned_m_s + self._vel_error,
            acc_ned_m_s2=truth.acc_ned_m_s2 + noise,
        )

    def __repr__(self) -> str:
        return f"PaperAccelNoise(fraction={self.fraction}, seed={self.seed})"


# Standard deviations of ImuNoise's defaults: the sample-to-sample jitter of a PX4 EKF2 local
# position estimate with a good GNSS fix and a calibrated IMU (not its slowly varying bias).
IMU_DEFAULTS = {"pos": 0.02, "vel": 0.05, "att": 0.002, "rate": 0.01, "acc": 0.1}


class ImuNoise:
    """Independent white Gaussian noise on each measured quantity.

    - position and velocity (NED): ``N(0, pos_std^2)``, ``N(0, vel_std^2)`` per axis;
    - attitude: the true quaternion turned by a small body rotation vector of
      ``N(0, att_std^2)`` per axis; the Euler angles change by the same rotation (keeping the
      truth's yaw branch, so an unwrapped yaw stays unwrapped);
    - body rates: ``N(0, rate_std^2)`` per axis, and the Euler rates by ``W_zyx^-1`` of it;
    - acceleration: ``N(0, acc_std^2)`` per axis.

    Parameters
    ----------
    pos_std_m, vel_std_m_s, att_std_rad, rate_std_rad_s, acc_std_m_s2 : float
        Standard deviations, >= 0 (defaults ``IMU_DEFAULTS``).
    seed : int or sequence of int
        Seeds ``numpy.random.default_rng``.
    """

    def __init__(
        self,
        pos_std_m: float = IMU_DEFAULTS["pos"],
        vel_std_m_s: float = IMU_DEFAULTS["vel"],
        att_std_rad: float = IMU_DEFAULTS["att"],
        rate_std_rad_s: float = IMU_DEFAULTS["rate"],
        acc_std_m_s2: float = IMU_DEFAULTS["acc"],
        seed: int | Sequence[int] = 0,
    ) -> None:
        stds = (pos_std_m, vel_std_m_s, att_std_rad, rate_std_rad_s, acc_std_m_s2)
        for name, value in zip(("pos_std_m", "vel_std_m_s", "att_std_rad", "rate_std_rad_s", "acc_std_m_s2"), stds):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value}")
        self.pos_std_m, self.vel_std_m_s, self.att_std_rad, self.rate_std_rad_s, self.acc_std_m_s2 = (
            float(v) for v in stds
        )
        self.seed = seed
        self.reset()

    def reset(self) -> None:
        """Back to the seed's first draw."""
        self._rng = np.random.default_rng(np.random.SeedSequence(self.seed))

    def measure(self, truth: VehicleState) -> VehicleState:
        """The truth with one draw of each noise (class docstring)."""
        noise = self._rng.standard_normal((5, 3))
        rotation = self.att_std_rad * noise[2]
        angle = float(np.linalg.norm(rotation))
        if angle > 0.0:
            turn = np.concatenate([[math.cos(0.5 * angle)], math.sin(0.5 * angle) / angle * rotation])
            quat = quat_multiply(truth.quat_wxyz, turn)
            change = euler_from_quat(quat) - euler_from_quat(truth.quat_wxyz)
            euler = truth.euler_rad + np.array([wrap_pi(float(c)) for c in change])
        else:
            quat, euler = truth.quat_wxyz, truth.euler_rad
        rate_noise = self.rate_std_rad_s * noise[3]
        return replace(
            truth,
            pos_ned_m=truth.pos_ned_m + self.pos_std_m * noise[0],
            vel_ned_m_s=truth.vel_ned_m_s + self.vel_std_m_s * noise[1],
            quat_wxyz=quat,
            euler_rad=euler,
            body_rate_frd_rad_s=truth.body_rate_frd_rad_s + rate_noise,
            euler_rate_rad_s=truth.euler_rate_rad_s + zyx_euler_rates_from_body_rates(euler, rate_noise),
            acc_ned_m_s2=truth.acc_ned_m_s2 + self.acc_std_m_s2 * noise[4],
        )

    def __repr__(self) -> str:
        return (
            f"ImuNoise(pos_std_m={self.pos_std_m}, vel_std_m_s={self.vel_std_m_s}, att_std_rad={self.att_std_rad}, "
            f"rate_std_rad_s={self.rate_std_rad_s}, acc_std_m_s2={self.acc_std_m_s2}, seed={self.seed})"
        )


class DeadReckoning:
    """The horizontal estimate of an estimator that lost its position aid (the GPS).

    Without the GPS an estimator like PX4's EKF2 integrates the accelerometer alone and no
    longer learns its error: a constant horizontal acceleration error ``b`` (north, east) puts the
    estimate ``b t`` off in velocity and ``1/2 b t^2`` in position, ``t`` seconds after the loss,
    whatever the vehicle does: PX4 v1.16 SIH's estimate ran on after the vehicle had landed
    (docs/plant.md; its velocity error grew more slowly there). The vertical estimate keeps its
    aid (the barometer) and the attitude its own (the gyro and the gravity vector): both stay as
    measured. ``drawn`` takes the error's direction at random (a bias has none preferred) and
    its size from ``SIM_DR_ACC_ERR``.
    """

    def __init__(self, accel_error_ne_m_s2: tuple[float, float]) -> None:
        north, east = (float(v) for v in accel_error_ne_m_s2)
        if not (math.isfinite(north) and math.isfinite(east)):
            raise ValueError(f"the acceleration error must be finite, got {accel_error_ne_m_s2}")
        self.accel_error_ne_m_s2 = (north, east)
        self._accel = np.array([north, east, 0.0])
        self.pos_error_ned_m = np.zeros(3)
        self.vel_error_ned_m_s = np.zeros(3)

    @classmethod
    def drawn(cls, magnitude_m_s2: float, rng: np.random.Generator) -> DeadReckoning:
        """An error of ``magnitude_m_s2`` in a direction drawn uniformly from ``rng``."""
        heading = float(rng.uniform(0.0, 2.0 * math.pi))
        return cls((magnitude_m_s2 * math.cos(heading), magnitude_m_s2 * math.sin(heading)))

    def advance(self, dt_s: float) -> None:
        """``dt_s`` seconds more of dead reckoning: the errors grow exactly as a constant ``b``
        makes them."""
        if dt_s > 0.0:
            self.pos_error_ned_m = self.pos_error_ned_m + self.vel_error_ned_m_s * dt_s + 0.5 * self._accel * dt_s * dt_s
            self.vel_error_ned_m_s = self.vel_error_ned_m_s + self._accel * dt_s

    def measure(self, state: VehicleState) -> VehicleState:
        """``state`` as the estimator reports it now."""
        return replace(state, pos_ned_m=state.pos_ned_m + self.pos_error_ned_m, vel_ned_m_s=state.vel_ned_m_s + self.vel_error_ned_m_s)

    def __repr__(self) -> str:
        return f"DeadReckoning(accel_error_ne_m_s2={self.accel_error_ne_m_s2})"


# --- the command-line spec and the TOML table ----------------------------------------------------


def sensors_from_spec(spec: str, seed: int = 0) -> SensorModel:
    """A sensor model from a command-line spec (``SENSOR_SPEC_HELP``).

    ``clean``; ``paper`` or ``paper:FRACTION`` (default 0.05); ``imu`` or
    ``imu:pos=M,vel=M_S,att=RAD,rate=RAD_S,acc=M_S2`` (any subset, the rest ``IMU_DEFAULTS``).

    Raises
    ------
    SensorSpecError
        (a ``ValueError``) naming the bad part, in one line.
    """
    kind, args = specstring.kind_and_args(spec.strip())

    def fail(message: str) -> SensorSpecError:
        return SensorSpecError(f"sensor spec {spec!r}: {message}")

    if kind == "clean":
        if args:
            raise SensorSpecError(f"sensor spec {spec!r}: 'clean' takes no arguments")
        return CleanSensors()
    if kind == "paper":
        return PaperAccelNoise(specstring.number("fraction", args, fail, nonnegative=True) if args else 0.05, seed)
    if kind == "imu":
        values = dict(IMU_DEFAULTS)
        for key, value in (specstring.options(args, tuple(IMU_DEFAULTS), fail) if args else {}).items():
            values[key] = specstring.number(key, value, fail, nonnegative=True)
        return ImuNoise(values["pos"], values["vel"], values["att"], values["rate"], values["acc"], seed)
    raise SensorSpecError(f"sensor spec {spec!r}: unknown model {kind!r} (expected {SENSOR_SPEC_HELP})")


_TABLE_KEYS = {
    "pos": "pos_std_m",
    "vel": "vel_std_m_s",
    "att": "att_std_rad",
    "rate": "rate_std_rad_s",
    "acc": "acc_std_m_s2",
}


def sensors_from_table(fields: Fields, seed: int = 0) -> SensorModel:
    """A sensor model from a TOML table::

        [sensors]
        model = "paper"                 # clean | paper | imu
        accel_noise_fraction = 0.05     # paper only (default 0.05)
        # imu only, each optional (defaults IMU_DEFAULTS):
        # pos_std_m, vel_std_m_s, att_std_rad, rate_std_rad_s, acc_std_m_s2

    Raises
    ------
    ParameterFileError
        Naming the file and the field (a key of another model is an unknown field).
    """
    model = fields.string("model", choices=("clean", "paper", "imu"))
    sensors: SensorModel
    if model == "clean":
        sensors = CleanSensors()
    elif model == "paper":
        sensors = PaperAccelNoise(fields.number("accel_noise_fraction", 0.05, ge=0), seed)
    else:
        stds = {short: fields.number(key, IMU_DEFAULTS[short], ge=0) for short, key in _TABLE_KEYS.items()}
        sensors = ImuNoise(stds["pos"], stds["vel"], stds["att"], stds["rate"], stds["acc"], seed)
    fields.reject_unknown()
    return sensors
