"""Gains for the law from a model of what it really drives (docs/controller-design.md).

Flown through an autopilot, the law's angle references (x7ez, x9ez of eq. 28-29) are not reached
within one sample, as eq. 23 assumes: an attitude P loop, a rate PID and the motors reach them
after 100-200 ms, and the link adds its latency. This module models that chain, linearised about
hover, one axis at a time, and designs the law's per-sample gains for it:

- **The inner loop** (``TiltLoop``), continuous time, input the tilt setpoint, per axis::

      omega_sp = P_att (theta_sp - theta)                       (MC_ROLL_P)
      tau_c    = T1 (Kp (omega_sp - omega) + Ki int(omega_sp - omega) - Kd omega_dot)
      tau_dot  = (tau_c - tau) / tau_m                          (motor lag, SIM_MOT_TAU / SIH_T_TAU)
      omega_dot = tau / I,  theta_dot = omega,  v_dot = g theta - delta v, p_dot = v

  with T1 the body torque at normalised torque 1 and delta = d / m the vehicle's linear drag per
  unit mass (SIM_KDV / SIH_KDV over the mass; 0 without); the vertical axis is ``a_dot = (a_c -
  a) / tau_m``, ``v_dot = a - delta v``, ``p_dot = v``. The law's acceleration command ``dv / To`` (eq. 34,
  with tan(theta) = dv / (dv6 + g To) of eq. 28-29, ~ a_c / g) is held for a sample
  (zero-order hold) and applied ``latency_s`` after the measurement it was computed from.
- **The law on one axis** (eq. 32-34), linear: with memory ``vd(n)`` (x2d of the last sample)::

      vd(n+1) = (r(n+1) - k_pos r(n)) / To + (k_pos - 1) / To  p(n)          (eq. 32)
      a_c(n)  = (vd(n+1) - k_vel vd(n) + (k_vel - 1) v(n)) / To + delta v(n)  (eq. 33-34)

  (k_pos, k_vel) are (kx1, kx2) for north, (kx3, kx4) for east, (kx5, kx6) for up; ``delta v(n)``
  is the believed drag the law makes up (``[model] linear_drag_n_s_m``). It makes up the drag of
  the measured speed through the lagged loop, so the drag acts on v(t) and its compensation on
  v(t - lag): on a circle a force of about delta lag a outwards, which the reference lead below
  then cancels with the rest (PX4 SIH's SIH_KDV 1 N s/m: 0.2 m/s^2 at the helix's 2 m/s^2).
- **The closed loop** is then one linear discrete system: its poles (``spectral_radius``), the
  loop's gain, phase and delay margins broken at the plant input, and the transfer from the
  reference to the position: the law's eq. 32 hands the reference's velocity on exactly, so at
  low frequency ``T = 1 + c2 s^2``; handing the law ``r - c2 r''`` (``[law]
  reference_lead_s2``, from the trajectory's own acceleration) cancels what the lag leaves of
  a smooth reference's error, to second order.

The law's extensions enter the same state space (``law_state_space``): the tilt lead (the
attitude setpoint led past the measured angle, ``[law] tilt_lead``) and the optional integral
action. ``design_gains`` searches (k_pos, k_vel) and the lead for the fastest closed loop
(smallest spectral radius) that keeps stated margins (``MarginSpec``). ``noise_response`` says
what the closed loop makes of an estimator's errors (the tilt a hold takes on PX4 SIH's EKF2,
bench/px4_estimator.py). Everything here is pure numpy: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class TiltLoop:
    """One tilt axis of the autopilot's attitude and rate controllers (PX4's shape), linearised.

    Attributes
    ----------
    attitude_p_per_s : float
        MC_ROLL_P / MC_PITCH_P: body-rate setpoint per radian of attitude error (1/s).
    rate_p, rate_i, rate_d : float
        MC_ROLLRATE_P/I/D: normalised torque per rad/s, per rad (integral), per rad/s^2.
    torque_per_unit_nm : float
        Body torque at normalised torque 1 (N m).
    inertia_kg_m2 : float
        Moment of inertia about the axis (kg m^2).
    motor_time_constant_s : float
        First-order lag of the rotors' thrust (s); 0 for none.
    """

    attitude_p_per_s: float = 6.5
    rate_p: float = 0.15
    rate_i: float = 0.2
    rate_d: float = 0.003
    torque_per_unit_nm: float = 1.0
    inertia_kg_m2: float = 3.8e-3
    motor_time_constant_s: float = 0.02

    def __post_init__(self) -> None:
        for name in ("attitude_p_per_s", "rate_p", "torque_per_unit_nm", "inertia_kg_m2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value}")
        for name in ("rate_i", "rate_d", "motor_time_constant_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value}")


@dataclass(frozen=True)
class InnerLoopModel:
    """What the law's setpoints drive: both tilt axes, the collective thrust's lag and the latency.

    Attributes
    ----------
    roll, pitch : TiltLoop
        Roll moves the vehicle east (paper y, kx3/kx4), pitch north (paper x, kx1/kx2).
    thrust_time_constant_s : float
        Lag of the collective thrust (s): the vertical axis.
    latency_s : float
        From the measurement a sample uses to the moment its setpoint acts (s): telemetry age,
        link and processing.
    source : str
        Where the numbers came from, for the controller file's comments.
    drag_per_s : float
        delta = d / m, the vehicle's linear drag per unit mass (1/s), which the law makes up
        (``[model] linear_drag_n_s_m``); 0 for none.
    angle_gains : AxisGains or None
        None: the law hands the autopilot an attitude, which its attitude P loop closes (``--output
        attitude``). Otherwise the law closes the attitude loop itself, eq. 32-33 on the angles
        with these (k_pos, k_vel) = (kx7, kx8) = (kx9, kx10), and hands the autopilot the body
        rates x8ref, x10ref, which only its rate loop flies (``--output rates``; ``rate_axis_plant``).
    predict : bool
        The law is handed the state predicted ``latency_s`` ahead (``latency_predictor``: the
        measured state carried over the latency by this model, with the setpoints in flight)
        instead of the measured one; an attitude output only.
    observe : bool
        With ``predict``: the rate loop's integral and the motors' torque, which no telemetry
        carries, are observed from how the tilt and the body rate moved over the last sample
        against this model (``attitude_observer``, ``observed_plant``) instead of being taken at
        hover.
    observer_memory_s : float or None
        How long the observer takes to forget an error of its estimates (``attitude_observer``'s
        T); None: ``OBSERVER_MEMORY_SAMPLES`` of the law's sample time; 0: none (deadbeat, as
        flights flew before the memory).
    """

    roll: TiltLoop
    pitch: TiltLoop
    thrust_time_constant_s: float = 0.02
    latency_s: float = 0.0
    source: str = ""
    drag_per_s: float = 0.0
    angle_gains: AxisGains | None = None
    predict: bool = False
    observe: bool = False
    observer_memory_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("thrust_time_constant_s", "latency_s", "drag_per_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value}")
        if self.observer_memory_s is not None and not (math.isfinite(self.observer_memory_s) and self.observer_memory_s >= 0):
            raise ValueError(f"observer_memory_s must be >= 0, got {self.observer_memory_s}")

    def observer_memory_at(self, sample_time_s: float) -> float:
        """The observer's memory T (s) at the law's sample time (``observer_memory_s``)."""
        return OBSERVER_MEMORY_SAMPLES * sample_time_s if self.observer_memory_s is None else self.observer_memory_s


def _param(params: Mapping[str, float], *names: str, default: float | None = None) -> float:
    for name in names:
        if name in params:
            return float(params[name])
    if default is None:
        raise KeyError(f"the vehicle publishes none of {', '.join(names)}")
    return default


#: PX4's control allocation normalises a quad X's roll and pitch columns so that each rotor takes
#: 1/sqrt(2) of a unit roll or pitch command (ControlAllocationPseudoInverse:
#: normalizeControlAllocationMatrix); SIH then makes ``L_ROLL * T_MAX`` of torque per unit of rotor
#: thrust difference on each of its 4 rotors.
SIH_TORQUE_PER_UNIT_FACTOR = 4.0 / math.sqrt(2.0)


def inner_loop_from_params(params: Mapping[str, float], latency_s: float = 0.0) -> InnerLoopModel:
    """The inner-loop model of a vehicle from its published parameters.

    ``sitl-plant`` publishes ``SIM_*`` (torque at normalised 1 ``SIM_TQ_RP_MAX``, inertia
    ``SIM_I**``, motor lag ``SIM_MOT_TAU``); PX4's SIH ``SIH_*`` (``SIH_T_MAX`` per rotor,
    ``SIH_L_ROLL``/``SIH_L_PITCH``, ``SIH_I**``, ``SIH_T_TAU``). Both publish PX4's ``MC_*``
    gains; where one is missing PX4's default is taken.

    Raises
    ------
    KeyError
        Neither the plant's nor SIH's inertia and torque scale are published (a real airframe:
        give them in a vehicle file).
    """

    def axis(name: str, rate: str, inertia: tuple[str, ...], arm: str) -> TiltLoop:
        if "SIM_TQ_RP_MAX" in params:
            torque = float(params["SIM_TQ_RP_MAX"])
        elif "SIH_T_MAX" in params:
            torque = _param(params, "SIH_T_MAX") * _param(params, arm, "SIH_L_ROLL") * SIH_TORQUE_PER_UNIT_FACTOR
        else:
            raise KeyError("the vehicle publishes neither SIM_TQ_RP_MAX nor SIH_T_MAX (torque at normalised 1)")
        return TiltLoop(
            attitude_p_per_s=_param(params, f"MC_{name}_P", default=6.5),
            rate_p=_param(params, f"MC_{rate}RATE_P", default=0.15),
            rate_i=_param(params, f"MC_{rate}RATE_I", default=0.2),
            rate_d=_param(params, f"MC_{rate}RATE_D", default=0.003),
            torque_per_unit_nm=torque,
            inertia_kg_m2=_param(params, *inertia),
            motor_time_constant_s=_param(params, "SIM_MOT_TAU", "SIH_T_TAU", default=0.0),
        )

    roll = axis("ROLL", "ROLL", ("SIM_IXX", "SIH_IXX"), "SIH_L_ROLL")
    pitch = axis("PITCH", "PITCH", ("SIM_IYY", "SIH_IYY"), "SIH_L_PITCH")
    source = "sitl-plant SIM_*" if "SIM_TQ_RP_MAX" in params else "PX4 SIH_*"
    drag = _param(params, "SIM_KDV", "SIH_KDV", default=0.0)
    mass = _param(params, "SIM_MASS", "SIH_MASS", default=0.0)
    return InnerLoopModel(roll, pitch, roll.motor_time_constant_s, latency_s, f"{source} and MC_* parameters",
                          drag / mass if drag > 0 and mass > 0 else 0.0)  # fmt: skip


# --- linear models -------------------------------------------------------------------------------


#: Where ``rate_axis_plant``'s tilt and body rate sit in its state.
TILT_STATE, RATE_STATE = 2, 3


def rate_axis_plant(loop: TiltLoop, gravity_m_s2: float = GRAVITY_M_S2, drag_per_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of one horizontal axis flown by body rates, states (p, v, theta, omega, rate
    integral, torque) as ``tilt_axis_plant``; input the body-rate setpoint omega_sp (rad/s), which
    the rate loop flies with no attitude P in front of it (PX4 with a rate setpoint)."""
    g = gravity_m_s2
    tm = max(loop.motor_time_constant_s, 1e-4)  # no lag: a lag far above every other pole
    i = loop.inertia_kg_m2
    t1 = loop.torque_per_unit_nm
    kp, ki, kd = loop.rate_p, loop.rate_i, loop.rate_d
    a = np.zeros((6, 6))
    b = np.zeros((6, 1))
    a[0, 1] = 1.0
    a[1, 1] = -drag_per_s
    a[1, 2] = g
    a[2, 3] = 1.0
    a[3, 5] = 1.0 / i
    a[4, 3], b[4, 0] = -1.0, 1.0  # the integral of omega_sp - omega
    # tau_dot = (tau_c - tau) / tau_m, tau_c = t1 (kp (omega_sp - omega) + ki int - kd tau / I)
    a[5, 3] = -t1 * kp / tm
    a[5, 4] = t1 * ki / tm
    a[5, 5] = (-t1 * kd / i - 1.0) / tm
    b[5, 0] = t1 * kp / tm
    return a, b


def rate_carry_s(loop: TiltLoop, horizon_s: float = 1.0, step_s: float = 1e-3) -> float:
    """How far the autopilot's rate loop carries a body rate once its setpoint drops to zero, as
    a time (s): a vehicle turning steadily at omega0 turns through at most omega0 * T more.

    T = max over t of the integral from 0 to t of (1 - y), y the closed rate loop's step response
    (``rate_axis_plant``'s omega, rate integral and torque, theta not acting back; stepped exactly
    at ``step_s`` for ``horizon_s``): the first-order loop's tau. The integral is not the mean
    response time -G'(0): with the rate integral, whose state is the angle error, the response
    overshoots until the area is paid back, and the mean time is 0 while the angle still goes
    on by omega0 T before it turns back. The horizon of the body-rate output's tilt bound
    (``ActionLimits.rate_carry_s``).
    """
    a, b = rate_axis_plant(loop)
    keep = slice(RATE_STATE, a.shape[0])
    sub_a, sub_b = a[keep, keep], b[keep]
    n = sub_a.shape[0]
    # one exact step of the held input: [x; u] -> expm([[A, B], [0, 0]] h)
    block = np.zeros((n + 1, n + 1))
    block[:n, :n], block[:n, n:] = sub_a * step_s, sub_b * step_s
    m = _expm(block)
    phi, gamma = m[:n, :n], m[:n, n]
    x = np.zeros(n)
    area = best = 0.0
    for _ in range(int(round(horizon_s / step_s))):
        nxt = phi @ x + gamma
        area += (1.0 - 0.5 * (x[0] + nxt[0])) * step_s  # the trapezoid of 1 - y over the step
        best = max(best, area)
        x = nxt
    return best


def tilt_axis_plant(loop: TiltLoop, gravity_m_s2: float = GRAVITY_M_S2, drag_per_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of one horizontal axis, states (p, v, theta, omega, rate integral, torque).

    Input: the acceleration command a_c (m/s^2), flown as the tilt setpoint a_c / g; the vehicle's
    linear drag ``drag_per_s`` (delta = d / m) slows v. It is ``rate_axis_plant`` with the
    attitude P in front: omega_sp = P_att (a_c / g - theta).
    """
    a, b = rate_axis_plant(loop, gravity_m_s2, drag_per_s)
    patt = loop.attitude_p_per_s
    a[:, TILT_STATE] -= patt * b[:, 0]
    return a, b * (patt / gravity_m_s2)


def vertical_plant(thrust_time_constant_s: float, drag_per_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the vertical axis, states (p, v, a); input the acceleration command (m/s^2)."""
    tm = max(thrust_time_constant_s, 1e-4)
    a = np.array([[0.0, 1.0, 0.0], [0.0, -drag_per_s, 1.0], [0.0, 0.0, -1.0 / tm]])
    b = np.array([[0.0], [0.0], [1.0 / tm]])
    return a, b


def _expm(m: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor series (small, well-scaled matrices)."""
    norm = float(np.max(np.sum(np.abs(m), axis=1)))
    squarings = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    x = m / (2.0**squarings)
    result = np.eye(m.shape[0])
    term = np.eye(m.shape[0])
    for k in range(1, 20):
        term = term @ x / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


def _zoh(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{Ah}, int_0^h e^{As} ds B)."""
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = a, b
    e = _expm(big * h)
    return e[:n, :n], e[:n, n:]


@dataclass(frozen=True)
class DiscretePlant:
    """x(n+1) = phi x(n) + gamma u(n), y(n) = (p(n), v(n), tilt(n)) = c x(n); the delay line is in x.

    The vertical axis has no tilt: its third row is zero. ``drag_per_s``: the plant's linear drag
    (delta), which the law makes up with ``delta v(n)``."""

    phi: np.ndarray
    gamma: np.ndarray
    c: np.ndarray
    drag_per_s: float = 0.0
    #: how far ahead of the sample the law's references are taken (s): the latency, when the law
    #: is handed the state predicted over it (``predicted_plant``), so that it meets them in time
    lookahead_s: float = 0.0


def distinct_plants(plants: tuple[DiscretePlant, ...]) -> tuple[DiscretePlant, ...]:
    """``plants`` without repeats (equal to the bit): a vehicle symmetric in roll and pitch (equal
    inertias and inner-loop gains, as PX4's defaults and the bundled vehicles are) has one
    horizontal plant twice, and a search over both did all its work twice."""
    out: list[DiscretePlant] = []
    for plant in plants:
        if not any(_same_plant(plant, seen) for seen in out):
            out.append(plant)
    return tuple(out)


def _same_plant(a: DiscretePlant, b: DiscretePlant) -> bool:
    return (a.drag_per_s == b.drag_per_s and a.lookahead_s == b.lookahead_s and np.array_equal(a.phi, b.phi)
            and np.array_equal(a.gamma, b.gamma) and np.array_equal(a.c, b.c))  # fmt: skip


def discretise(a: np.ndarray, b: np.ndarray, sample_time_s: float, latency_s: float, *, tilt_state: int | None = None,
               drag_per_s: float = 0.0) -> DiscretePlant:  # fmt: skip
    """Zero-order hold at ``sample_time_s`` with the input acting ``latency_s`` after the sample.

    With latency ``d = m To + delta`` the input over [n To, n To + delta) is u(n - m - 1) and
    over [n To + delta, (n+1) To) u(n - m); the m + 1 past inputs are extra states.
    """
    to = sample_time_s
    m = int(latency_s // to)
    delta = latency_s - m * to
    n = a.shape[0]
    phi, _ = _zoh(a, b, to)
    phi_late, gamma_late = _zoh(a, b, to - delta)  # the part after the switch
    _, gamma_early = _zoh(a, b, delta)  # the part before it, then carried over the rest
    gamma_early = phi_late @ gamma_early
    lags = m + 1  # u(n-1) ... u(n-m-1)
    size = n + lags
    big_phi = np.zeros((size, size))
    big_gamma = np.zeros((size, 1))
    big_phi[:n, :n] = phi
    # the input that acts first in the sample is u(n-m-1) (state n + m), then u(n-m)
    if m == 0:
        big_phi[:n, n] = gamma_early[:, 0]
        big_gamma[:n, 0] = gamma_late[:, 0]
    else:
        big_phi[:n, n + m] = gamma_early[:, 0]
        big_phi[:n, n + m - 1] = gamma_late[:, 0]
    # delay line: u(n) -> slot 0, slot k -> slot k+1
    big_gamma[n, 0] = 1.0
    for k in range(1, lags):
        big_phi[n + k, n + k - 1] = 1.0
    c = np.zeros((3, size))
    c[0, 0] = c[1, 1] = 1.0
    if tilt_state is not None:
        c[2, tilt_state] = 1.0
    return DiscretePlant(big_phi, big_gamma, c, drag_per_s)


# --- the state predicted over the latency -----------------------------------------------------------

#: The states of each axis's model the offboard measures (ATTITUDE, LOCAL_POSITION_NED): position,
#: velocity, tilt and body rate of a horizontal axis (``tilt_axis_plant``), position and velocity of
#: the vertical one (``vertical_plant``). The rate loop's integral, the motors' torque and the
#: thrust's lag are not measured: the prediction takes them at hover (zero), or observes the first
#: two (``observed_plant``, ``attitude_observer``).
HORIZONTAL_MEASURED = (0, 1, 2, 3)
VERTICAL_MEASURED = (0, 1)


def latency_predictor(a: np.ndarray, b: np.ndarray, sample_time_s: float, latency_s: float,
                      measured: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(Mx, Mu): the axis's state ``latency_s`` after the measurement, when the setpoint computed
    from it starts to act, from the measured states and the setpoints still in flight::

        x^(n To + L) = Mx x(n) + Mu (u(n-1), u(n-2), ..., u(n-m-1))

    with ``L = m To + delta`` as ``discretise``: over [n To, n To + delta) u(n-m-1) acts, then
    u(n-m), ..., u(n-1) a sample each. Mx is e^{AL} with the columns of the unmeasured states
    zeroed (they are taken at hover). A Smith predictor in finite form: it carries no model state
    of its own, so a model error costs accuracy over one latency, never a drift.
    """
    to, latency = sample_time_s, latency_s
    n = a.shape[0]
    m = int(latency // to)
    delta = latency - m * to
    mx = _zoh(a, b, latency)[0].copy()
    mx[:, [j for j in range(n) if j not in measured]] = 0.0
    mu = np.zeros((n, m + 1))
    _, gamma_delta = _zoh(a, b, delta)
    mu[:, m] = (_zoh(a, b, latency - delta)[0] @ gamma_delta)[:, 0]
    _, gamma_to = _zoh(a, b, to)
    for j in range(1, m + 1):  # u(n-m-1+j) over [delta + (j-1) To, delta + j To)
        mu[:, m - j] = (_zoh(a, b, latency - delta - j * to)[0] @ gamma_to)[:, 0]
    return mx, mu


#: A horizontal axis's attitude states within ``tilt_axis_plant``'s: tilt, body rate, the rate
#: loop's integral and the motors' torque. A system of their own (the position and the velocity do
#: not act back on them), whose first two are measured.
ATTITUDE_STATES = (2, 3, 4, 5)

#: The observer's memory in samples of the law (``attitude_observer``'s T = this x To): the same
#: 20 samples over which the prediction averages the telemetry's usual age
#: (``prediction.AGE_AVERAGE_SAMPLES``), the link's timing noise averaged alike.
OBSERVER_MEMORY_SAMPLES = 20


def attitude_observer(a: np.ndarray, b: np.ndarray, interval_s: float, memory_s: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, Gamma, K) of the observer of a horizontal axis's rate-loop integral and motor torque
    over ``interval_s`` between two measurements (``tilt_axis_plant``'s ``a``, ``b``).

    Over the interval the attitude states (``ATTITUDE_STATES``) go ``x <- Phi x + Gamma u`` for a
    held input; the estimate at the interval's start (the measured tilt and rate, the observed
    integral and torque) carried so is corrected by ``K (y - y_model)``, y the tilt and rate
    measured at its end::

        K = (1 - e^(-h / T)) Phi_uu Phi_mu^-1          h = interval_s, T = memory_s

    The error of the estimates then goes ``e <- e^(-h/T) Phi_uu e`` an interval. Uncorrected
    (T infinite) the inner loop's own dynamics forget it (the paper quad's Phi_uu over 50 ms has
    eigenvalues 0.972 and -0.157: about 1.8 s); T shortens that, and T = 0 is the deadbeat
    observer (``K = Phi_uu Phi_mu^-1``), the error gone at the interval's end. Deadbeat has no
    memory, but it puts all of what the model missed of the measured tilt and rate on the two
    estimates: over a link whose timing is off by milliseconds from sample to sample (when a
    setpoint began to act, when a measurement was taken), that is noise, which the prediction
    then carries over the latency (docs/controller-design.md, "The rate loop observed"). With T
    the correction is spread over about T / h intervals and the noise averaged.
    """
    if not (math.isfinite(memory_s) and memory_s >= 0.0):
        raise ValueError(f"the observer's memory must be >= 0 s, got {memory_s}")
    keep = list(ATTITUDE_STATES)
    phi, gamma = _zoh(a[np.ix_(keep, keep)], b[keep], interval_s)
    spread = 1.0 - math.exp(-interval_s / memory_s) if memory_s > 0.0 else 1.0
    gain = spread * phi[2:, 2:] @ np.linalg.inv(phi[:2, 2:])
    return phi, gamma, gain


def observed_plant(a: np.ndarray, b: np.ndarray, sample_time_s: float, latency_s: float, *, drag_per_s: float = 0.0,
                   believed: tuple[np.ndarray, np.ndarray] | None = None, memory_s: float = 0.0) -> DiscretePlant:  # fmt: skip
    """``predicted_plant`` of a horizontal axis whose rate-loop integral and motor torque are
    observed (``attitude_observer`` over a sample, with its ``memory_s``) instead of taken at
    hover: the two estimates are two more states, updated each sample from the last sample's
    measured tilt and rate, the estimates, the setpoints that acted and the measurement now; the
    law is handed the state predicted from the measured states and the estimates. ``believed``:
    the (A, B) the observer and the prediction run, when not the vehicle's own (a model error)."""
    plant = discretise(a, b, sample_time_s, latency_s, tilt_state=TILT_STATE, drag_per_s=drag_per_s)
    a_m, b_m = (a, b) if believed is None else believed
    model = discretise(a_m, b_m, sample_time_s, latency_s, tilt_state=TILT_STATE, drag_per_s=drag_per_s)
    n, size = a.shape[0], plant.phi.shape[0]
    unmeasured = [j for j in range(n) if j not in HORIZONTAL_MEASURED]
    keep = np.eye(size)  # the measured states and the delay line
    keep[unmeasured, unmeasured] = 0.0
    put = np.zeros((size, len(unmeasured)))  # the estimates into their states
    put[unmeasured, range(len(unmeasured))] = 1.0
    read = np.zeros((2, size))  # the measured tilt and rate
    read[[0, 1], [TILT_STATE, RATE_STATE]] = 1.0
    _, _, gain = attitude_observer(a_m, b_m, sample_time_s, memory_s)
    phi, gamma, phi_m, gamma_m = plant.phi, plant.gamma, model.phi, model.gamma
    # z(n) = put' X^(n|n-1) + K (read X(n) - read X^(n|n-1)),  X^(n|n-1) = phi_m (keep X(n-1) + put z(n-1)) + gamma_m u(n-1)
    big = size + len(unmeasured)
    big_phi = np.zeros((big, big))
    big_gamma = np.zeros((big, 1))
    big_phi[:size, :size], big_gamma[:size] = phi, gamma
    big_phi[size:, :size] = put.T @ phi_m @ keep + gain @ (read @ phi - read @ phi_m @ keep)
    big_phi[size:, size:] = put.T @ phi_m @ put - gain @ read @ phi_m @ put
    big_gamma[size:] = put.T @ gamma_m + gain @ (read @ gamma - read @ gamma_m)
    mx, mu = latency_predictor(a_m, b_m, sample_time_s, latency_s, tuple(range(n)))
    estimate = np.concatenate([keep, put], axis=1)  # (size, big): the state the predictor is handed
    c = plant.c[:, :n] @ np.concatenate([mx, mu], axis=1) @ estimate
    return DiscretePlant(big_phi, big_gamma, c, drag_per_s, lookahead_s=latency_s)


def predicted_plant(a: np.ndarray, b: np.ndarray, sample_time_s: float, latency_s: float, measured: tuple[int, ...], *,
                    tilt_state: int | None = None, drag_per_s: float = 0.0,
                    believed: tuple[np.ndarray, np.ndarray] | None = None) -> DiscretePlant:  # fmt: skip
    """``discretise``'s plant with the law fed the predicted state (``latency_predictor``): its
    output is (p, v, tilt) of ``Mx x + Mu (delay line)``, the delay line being the plant's own.
    ``believed``: the (A, B) the prediction runs, when not the vehicle's own (a model error)."""
    plant = discretise(a, b, sample_time_s, latency_s, tilt_state=tilt_state, drag_per_s=drag_per_s)
    n = a.shape[0]
    mx, mu = latency_predictor(*((a, b) if believed is None else believed), sample_time_s, latency_s, measured)
    ahead = np.concatenate([mx, mu], axis=1)  # (n, size): the predicted physical state
    return replace(plant, c=plant.c[:, :n] @ ahead, lookahead_s=latency_s)


# --- the law on one axis, closed loop --------------------------------------------------------------


@dataclass(frozen=True)
class AxisGains:
    """The law's parameters on one axis (scalars, or arrays of one shape for a search).

    Attributes
    ----------
    k_pos, k_vel : float or ndarray
        (kx1, kx2) north, (kx3, kx4) east, (kx5, kx6) up.
    lead : float or ndarray
        The tilt lead (``[law] tilt_lead``; 0 on the vertical axis).
    integral_per_s : float or ndarray
        ki of the integral action (``[law] integral_gain_per_s``), 1/s; 0 for none. In a search
        every entry is 0 or every entry is > 0 (the integral is then a state of the law).
    velocity_integral_per_s2 : float or ndarray
        ki of the velocity integral (``[law] velocity_integral_gain_per_s2``), 1/s^2; 0 for none;
        as ``integral_per_s`` in a search. At most one of the two integrals is designed.
    """

    k_pos: float | np.ndarray
    k_vel: float | np.ndarray
    lead: float | np.ndarray = 0.0
    integral_per_s: float | np.ndarray = 0.0
    velocity_integral_per_s2: float | np.ndarray = 0.0

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(k_pos, k_vel, lead, integral, velocity integral) as float arrays broadcast to one shape (a batch of
        candidate gains, or scalars as 0-d arrays).
        """
        return tuple(np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in
                                          (self.k_pos, self.k_vel, self.lead, self.integral_per_s,
                                           self.velocity_integral_per_s2))))  # type: ignore[return-value]


def law_state_space(gains: AxisGains, sample_time_s: float, gravity_m_s2: float = GRAVITY_M_S2,
                    drag_per_s: float = 0.0) -> dict[str, np.ndarray]:  # fmt: skip
    """The law on one axis as a discrete state space (module docstring), batch axes first.

    States (vd(n), and the integral i(n) when ``integral_per_s`` > 0 or the velocity integral
    iv(n) when ``velocity_integral_per_s2`` > 0); inputs y = (p, v, tilt) and the reference terms
    (w, r) with ``w = (r(n+1) - k_pos r(n)) / To``; output the acceleration setpoint
    a_sp = (1 + lead) a_c - lead g tilt::

        i(n+1)  = i(n) + ki To (r(n) - p(n))                         (optional integral action)
        iv(n+1) = iv(n) + kiv To (vd(n) - v(n))                      (optional velocity integral)
        vd(n+1) = w + (k_pos - 1) / To p(n) + i(n+1)                 (eq. 32)
        a_c(n)  = (vd(n+1) - k_vel vd(n) + (k_vel - 1) v(n)) / To + iv(n+1) + delta v(n)
                                                                     (eq. 33-34, believed drag)

    Returns a dict of ``a`` (.., nk, nk), ``b`` (.., nk, 3), ``br`` (.., nk, 2), ``c`` (.., 1, nk),
    ``d`` (.., 1, 3), ``dr`` (.., 1, 2).
    """
    to, g = sample_time_s, gravity_m_s2
    kp, kv, lead, ki, kiv = gains.arrays()
    integral = bool(np.any(ki > 0.0))
    velocity_integral = bool(np.any(kiv > 0.0))
    if integral and velocity_integral:
        raise ValueError("the design models one integral: the position or the velocity one, not both")
    nk = 2 if integral or velocity_integral else 1
    f = 1.0 + lead
    zero = np.zeros_like(kp)
    kit = ki * to
    cp = (kp - 1.0) / to - kit  # vd(n+1) per metre of p(n)
    shape = kp.shape
    a = np.zeros((*shape, nk, nk))
    b = np.zeros((*shape, nk, 3))
    br = np.zeros((*shape, nk, 2))
    c = np.zeros((*shape, 1, nk))
    b[..., 0, 0] = cp
    br[..., 0, 0] = 1.0
    br[..., 0, 1] = kit
    c[..., 0, 0] = -f * kv / to
    if integral:
        a[..., 0, 1] = 1.0
        a[..., 1, 1] = 1.0
        b[..., 1, 0] = -kit
        br[..., 1, 1] = kit
        c[..., 0, 1] = f / to
    kvt = kiv * to
    if velocity_integral:
        a[..., 1, 0] = kvt
        a[..., 1, 1] = 1.0
        b[..., 1, 1] = -kvt
        c[..., 0, 0] += f * kvt
        c[..., 0, 1] = f
    d = np.stack([f * cp / to, f * ((kv - 1.0) / to - kvt + drag_per_s), -lead * g + zero], axis=-1)[..., None, :]
    dr = np.stack([f / to + zero, f * kit / to], axis=-1)[..., None, :]
    return {"a": a, "b": b, "br": br, "c": c, "d": d, "dr": dr}


def closed_loop(plant: DiscretePlant, gains: AxisGains, sample_time_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(M, Br): the closed loop's state matrix (plant states, then the law's) and its reference
    input matrix for (w, r), batch axes first."""
    law = law_state_space(gains, sample_time_s, drag_per_s=plant.drag_per_s)
    n = plant.phi.shape[0]
    nk = law["a"].shape[-1]
    shape = law["a"].shape[:-2]
    gam = plant.gamma  # (n, 1)
    m = np.zeros((*shape, n + nk, n + nk))
    m[..., :n, :n] = plant.phi + gam @ law["d"] @ plant.c
    m[..., :n, n:] = gam @ law["c"]
    m[..., n:, :n] = law["b"] @ plant.c
    m[..., n:, n:] = law["a"]
    br = np.concatenate([np.broadcast_to(gam @ law["dr"], (*shape, n, 2)), law["br"]], axis=-2)
    return m, br


def closed_loop_matrix(plant: DiscretePlant, gains: AxisGains, sample_time_s: float) -> np.ndarray:
    """The closed loop's state matrix (``closed_loop``)."""
    return closed_loop(plant, gains, sample_time_s)[0]


# --- the law's own attitude loop: the body-rate output ------------------------------------------------


def angle_stage_plant(rates: DiscretePlant, sample_time_s: float) -> DiscretePlant:
    """A rate-flown axis (``rate_axis_plant`` discretised) as the law's angle stage sees it: input
    tau~ (eq. 40-42's angular acceleration, rad/s^2), outputs (theta, omega, 0).

    The body-rate output is x8ref = x8 + To tau~ (eq. 41 with eq. 32-33 on the angles), held for
    the sample: omega_sp(n) = omega(n) + To u(n). With (k_pos, k_vel) = (kx7, kx8) the law on the
    angles is then ``law_state_space`` itself, on (theta, omega) in place of (p, v), and the
    same search designs it (``design_angle_gains``). The position and velocity, which the angles
    drive but which do not act back on them, are left out (their poles at 1 are not the angle
    stage's).
    """
    to = sample_time_s
    keep = np.arange(TILT_STATE, rates.phi.shape[0])  # theta, omega, the rate integral, the torque, the delay line
    n = keep.size
    tilt, rate = 0, RATE_STATE - TILT_STATE
    rate_row = np.zeros((1, n))
    rate_row[0, rate] = 1.0
    c = np.zeros((3, n))
    c[0, tilt] = c[1, rate] = 1.0
    gamma = rates.gamma[keep]
    return DiscretePlant(rates.phi[np.ix_(keep, keep)] + gamma @ rate_row, gamma * to, c)


def rate_output_plant(rates: DiscretePlant, angle: AxisGains, sample_time_s: float,
                      gravity_m_s2: float = GRAVITY_M_S2) -> DiscretePlant:  # fmt: skip
    """A rate-flown axis closed by the law's angle stage, as the position law (eq. 32-34) sees it:
    input the acceleration command a_c (m/s^2), the angle reference x7ez = a_c / g (eq. 28-29,
    linearised); outputs (p, v, theta). Two states of the law join the plant's, x7ez(n-1) and
    x8d(n-1)::

        x8d(n)   = (x7ez(n) - kx7 (x7ez(n-1) - theta(n)) - theta(n)) / To   (eq. 32 on the angle)
        x8ref(n) = x8d(n) - kx8 (x8d(n-1) - omega(n))                       (eq. 33): omega_sp(n)
    """
    to, g = sample_time_s, gravity_m_s2
    k7, k8 = float(np.asarray(angle.k_pos)), float(np.asarray(angle.k_vel))
    n = rates.phi.shape[0]
    tilt, rate = np.zeros(n), np.zeros(n)
    tilt[TILT_STATE], rate[RATE_STATE] = 1.0, 1.0
    # x8d(n) = d_u a_c + d_m x7ez(n-1) + d_x . x
    d_u, d_m, d_x = 1.0 / (g * to), -k7 / to, (k7 - 1.0) / to * tilt
    gam = rates.gamma[:, 0]
    phi = np.zeros((n + 2, n + 2))
    gamma = np.zeros((n + 2, 1))
    phi[:n, :n] = rates.phi + np.outer(gam, d_x + k8 * rate)
    phi[:n, n] = gam * d_m
    phi[:n, n + 1] = -k8 * gam
    gamma[:n, 0] = gam * d_u
    gamma[n, 0] = 1.0 / g  # x7ez(n), kept for the next sample
    phi[n + 1, :n], phi[n + 1, n], gamma[n + 1, 0] = d_x, d_m, d_u  # x8d(n), kept likewise
    c = np.zeros((3, n + 2))
    c[:, :n] = rates.c
    return DiscretePlant(phi, gamma, c, rates.drag_per_s)


def _plant_response(plant: DiscretePlant, z: np.ndarray) -> np.ndarray:
    """G(z) = C (zI - phi)^-1 gamma for each z: shape (len(z), 3)."""
    n = plant.phi.shape[0]
    eye = np.eye(n)
    mats = z[:, None, None] * eye[None] - plant.phi[None]
    rhs = np.broadcast_to(plant.gamma, (len(z), n, 1))
    x = np.linalg.solve(mats, rhs)[..., 0]
    return x @ plant.c.T


def _law_response(gains: AxisGains, z: np.ndarray, to: float, drag_per_s: float = 0.0) -> np.ndarray:
    """K(z) = C (zI - A)^-1 B + D from (p, v, tilt) to the setpoint: shape (..., len(z), 3).

    In closed form: (zI - A)^-1 is 1/z for vd alone, and the 2 x 2 inverse with an integral
    (``law_state_space``)."""
    law = law_state_space(gains, to, drag_per_s=drag_per_s)
    a_nk = law["a"].shape[-1]
    zz = z.reshape((1,) * (law["a"].ndim - 2) + (-1, 1))  # (..., len(z), 1)
    b = law["b"][..., None, :, :]  # (..., 1, nk, 3)
    c = law["c"][..., None, 0, :]  # (..., 1, nk)
    if a_nk == 1:
        k = c[..., 0:1] * b[..., 0, :] / zz
    else:
        a = law["a"][..., None, :, :]  # (..., 1, 2, 2)
        m00, m01 = zz - a[..., 0, 0:1], -a[..., 0, 1:2]
        m10, m11 = -a[..., 1, 0:1], zz - a[..., 1, 1:2]
        det = m00 * m11 - m01 * m10
        row0 = (c[..., 0:1] * m11 - c[..., 1:2] * m10) / det  # C (zI - A)^-1
        row1 = (c[..., 1:2] * m00 - c[..., 0:1] * m01) / det
        k = row0 * b[..., 0, :] + row1 * b[..., 1, :]
    return k + law["d"][..., None, 0, :]


@dataclass(frozen=True)
class AxisAnalysis:
    """One axis of the closed loop with given gains.

    Attributes
    ----------
    gains : AxisGains
        The law's parameters on the axis.
    spectral_radius : float
        Largest |pole|: < 1 is stable; errors decay as spectral_radius^n.
    settling_time_s : float
        Time for the slowest mode to fall to 2 % (inf when unstable).
    gain_margin : float
        Factor on the loop gain at the plant input before instability (inf: none found).
    phase_margin_deg : float
        Phase margin at the loop's gain crossover(s), the smallest.
    delay_margin_s : float
        Extra latency the loop tolerates (phase margin / crossover frequency), the smallest.
    reference_lead_s2 : float
        c2 of the reference response (``tracking_lead_s2``).
    poles : ndarray
        Every closed-loop pole (z-plane).
    sensitivity_peak : float
        Ms = max |1 / (1 + L)|: how much the loop amplifies a disturbance (or an estimate's
        error) at its worst frequency; 1 / Ms is the loop's shortest distance to -1.
    """

    gains: AxisGains
    spectral_radius: float
    settling_time_s: float
    gain_margin: float
    phase_margin_deg: float
    delay_margin_s: float
    reference_lead_s2: float
    poles: np.ndarray
    sensitivity_peak: float = 1.0

    def meets(self, spec: MarginSpec) -> bool:
        """Whether the loop is stable (every pole inside the unit circle) and keeps every margin of ``spec``."""
        return (self.spectral_radius < 1.0 and self.gain_margin >= spec.gain_margin
                and self.phase_margin_deg >= spec.phase_margin_deg and self.delay_margin_s >= spec.delay_margin_s
                and self.sensitivity_peak <= spec.sensitivity_peak)  # fmt: skip


#: The design's bound on the sensitivity peak Ms (``MarginSpec.sensitivity_peak``): 1.6, inside
#: the range Astrom and Hagglund give for robust loops (1.2-2.0) and what Skogestad's SIMC rules
#: give. Gain margin 2 and phase margin 45 deg alone allowed Ms 2.02 on PX4 SIH's loop (+6 dB at
#: 8 rad/s), and the PX4 hold rang there at 5-7 deg of tilt on the estimator's errors
#: (docs/controller-design.md, "The sensitivity peak").
SENSITIVITY_PEAK = 1.6


@dataclass(frozen=True)
class MarginSpec:
    """What the design must keep (the usual robustness targets of a cascaded flight loop).

    Attributes
    ----------
    gain_margin : float
        At least this factor (2 = 6 dB).
    phase_margin_deg : float
    delay_margin_s : float
        Extra latency the loop must tolerate on top of the modelled one (s).
    sensitivity_peak : float
        At most this Ms = max |1 / (1 + L)| (docs/controller-design.md, "The sensitivity peak").
    """

    gain_margin: float = 2.0
    phase_margin_deg: float = 45.0
    delay_margin_s: float = 0.05
    sensitivity_peak: float = SENSITIVITY_PEAK


def _sensitivity_peak(loop: np.ndarray) -> np.ndarray:
    """Ms = max |1 / (1 + L)| along the last axis (L in the negative feedback form)."""
    return np.max(1.0 / np.maximum(np.abs(1.0 + loop), 1e-300), axis=-1)


def _frequencies(to: float, count: int = 1500) -> np.ndarray:
    return np.geomspace(1e-3, math.pi / to * 0.9999, count)


def _margins(loop: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gain margin, phase margin deg, delay margin s) of L(e^{jw To}) along the last axis.

    Gain margin: 1 / |L| where L crosses the negative real axis inside the unit circle (the
    smallest; inf if it never does). Phase margin: 180 deg + arg L where |L| crosses 1 (the smallest; 180 if |L| never
    reaches 1). Delay margin: phase margin / crossover frequency (the smallest).
    """
    mag = np.abs(loop)
    phase = np.angle(loop)  # in (-pi, pi]
    im = loop.imag
    # crossings of the negative real axis inside the unit circle (with an integral the loop also
    # crosses it far outside at low frequency: a lower gain margin, which a gain rise never reaches)
    cross_180 = (np.sign(im[..., :-1]) != np.sign(im[..., 1:])) & (loop.real[..., :-1] < 0) & (mag[..., :-1] < 1.0)
    gm = np.min(np.where(cross_180, 1.0 / np.maximum(mag[..., :-1], 1e-300), np.inf), axis=-1)
    cross_1 = (mag[..., :-1] - 1.0) * (mag[..., 1:] - 1.0) <= 0
    margins = np.degrees(np.pi + phase[..., :-1])
    margins = np.where(margins > 180.0, margins - 360.0, margins)
    pm = np.min(np.where(cross_1, margins, 180.0), axis=-1)
    dm = np.min(np.where(cross_1, np.radians(np.maximum(margins, 0.0)) / w[:-1], np.inf), axis=-1)
    return gm, pm, dm


def loop_response(plant: DiscretePlant, gains: AxisGains, sample_time_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(w rad/s, L(e^{jw To})): the loop broken at the plant input (negative feedback form)."""
    w = _frequencies(sample_time_s)
    z = np.exp(1j * w * sample_time_s)
    return w, -np.sum(_law_response(gains, z, sample_time_s, plant.drag_per_s) * _plant_response(plant, z), axis=-1)


def reference_response(plant: DiscretePlant, gains: AxisGains, sample_time_s: float, w: np.ndarray) -> np.ndarray:
    """T(e^{jw To}): position over reference at angular frequencies ``w`` (rad/s).

    The reference enters eq. 32 as ``w = (r(n+1) - k_pos r(n)) / To`` and the integral as r(n);
    with ``plant.lookahead_s`` both are taken that much ahead of the sample.
    """
    to = sample_time_s
    m, br = closed_loop(plant, gains, to)
    z = np.exp(1j * np.asarray(w, dtype=float) * to)
    size = m.shape[-1]
    k_pos = float(np.asarray(gains.k_pos))
    u = np.stack([(z - k_pos) / to, np.ones_like(z)], axis=-1)  # (w, r) per unit of r
    rhs = (br[None] @ u[:, :, None])  # (len(z), size, 1)
    x = np.linalg.solve(z[:, None, None] * np.eye(size)[None] - m[None], rhs)[..., 0]
    return x[:, 0] * np.exp(1j * np.asarray(w, dtype=float) * plant.lookahead_s)  # references taken that far ahead


def tracking_lead_s2(plant: DiscretePlant, gains: AxisGains, sample_time_s: float) -> float:
    """c2 of the reference response T = 1 + c2 s^2 + ... of the proportional loop (s^2).

    The law's eq. 32 hands the velocity on exactly (T'(0) = 0), so what is left of a smooth,
    slow reference's tracking error is c2 times its acceleration: handing the law
    ``r - c2 r''`` instead of ``r`` cancels it to second order (``[law] reference_lead_s2``).

    c2 is the loop's *without* its integral: an integral's zero sits a fraction q of the loop's
    rate below it, and the Taylor series of T about 0 then holds only below that zero, where
    c2 s^2 is negligible anyway; above it the loop is the proportional one. On PX4 SIH's designed
    loop (10 ms latency) the integral loop's own c2 (-0.015 s^2) leaves |T| at 1.055 at 1 rad/s (a
    2 m helix flown 0.11 m wide) and 1.12 at 1.5 rad/s; the proportional loop's (-0.067 s^2) keeps
    it within 1 % up to 1 rad/s (docs/controller-design.md, "Reference lead").
    """
    proportional = AxisGains(gains.k_pos, gains.k_vel, gains.lead)
    w = 0.01
    t = reference_response(plant, proportional, sample_time_s, np.array([w]))[0]
    return float(((t - 1.0) / (1j * w) ** 2).real)


def analyse_axis(plant: DiscretePlant, gains: AxisGains, sample_time_s: float) -> AxisAnalysis:
    """Poles, margins and reference response of one axis with the law's gains (module docstring)."""
    to = sample_time_s
    poles = np.linalg.eigvals(closed_loop_matrix(plant, gains, to))
    rho = float(np.max(np.abs(poles)))
    settle = to * math.log(0.02) / math.log(rho) if rho < 1.0 else math.inf
    w, loop = loop_response(plant, gains, to)
    gm, pm, dm = _margins(loop[None], w)
    return AxisAnalysis(gains, rho, settle, float(gm[0]), float(pm[0]), float(dm[0]),
                        tracking_lead_s2(plant, gains, to), poles, float(_sensitivity_peak(loop)))  # fmt: skip


@dataclass(frozen=True)
class EstimateErrorSpectra:
    """What an estimator's errors are, one horizontal axis: one-sided (cross-)spectral densities
    of the position error n_p (m^2/Hz), the velocity error n_v ((m/s)^2/Hz) and their cross
    spectrum E[conj(N_p) N_v] (m^2/s/Hz, complex: scipy.signal.csd's convention), at
    ``frequencies_hz``, as the law samples them (every To, so what lies above its Nyquist
    frequency is folded in). ``python bench/px4_estimator.py`` measures them for PX4 SIH's EKF2
    against SIH's truth."""

    frequencies_hz: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    cross: np.ndarray


@dataclass(frozen=True)
class NoiseResponse:
    """RMS of what an estimator's errors make of one axis (``noise_response``): the tilt the
    vehicle takes (deg) and the error of the estimate the law holds against its reference (m), and
    the tilt the position error alone and the velocity error alone would give (deg)."""

    tilt_rms_deg: float
    estimate_error_rms_m: float
    tilt_from_position_deg: float
    tilt_from_velocity_deg: float


def velocity_read_transfer(sample_time_s: float, w: np.ndarray, velocity_from_position_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The error of the velocity the law reads per unit of position error and per unit of velocity
    error, at ``w`` (rad/s): ``C (1 - z^-1) / To`` and ``1 - C (1 + z^-1) / 2`` with ``C = K / (1 -
    (1 - K) z^-1)``, ``K = To / (T + To)`` (``offboard.controller.velocity.ConsistentVelocity``
    with T = ``velocity_from_position_s``; 0: none, the velocity as measured)."""
    to = sample_time_s
    z = np.exp(1j * np.asarray(w, dtype=float) * to)
    k = to / (velocity_from_position_s + to) if velocity_from_position_s > 0.0 else 0.0
    c = k / (1.0 - (1.0 - k) / z)
    return c * (1.0 - 1.0 / z) / to, 1.0 - c * (1.0 + 1.0 / z) / 2.0


def noise_transfer(plant: DiscretePlant, gains: AxisGains, sample_time_s: float, w: np.ndarray,
                   velocity_from_position_s: float = 0.0) -> dict[str, np.ndarray]:  # fmt: skip
    """The closed loop's frequency responses from the estimate's errors to the tilt (rad per m,
    rad per m/s) and to the estimate's own error against its reference (per m, per m/s), at ``w``
    (rad/s): keys ``tilt_p``, ``tilt_v``, ``error_p``, ``error_v``.

    The law reads p + n_p and the velocity its filter makes of v + n_v (``[law]
    velocity_from_position_s`` = T, ``offboard.controller.velocity``; 0: v + n_v as measured)::

        v_read = v + n_v + C(z) ((1 - z^-1) / To n_p - (1 + z^-1) / 2 n_v),  C = K / (1 - (1 - K) z^-1),  K = To / (T + To)

    (the filter hands on the true state unchanged: its correction is the estimates' inconsistency,
    which their errors alone make). The errors enter where the law reads its input, so with a
    predicted plant their prediction over the latency is left out (Mx ~ I for a latency far below
    the loop's time constants: 11 ms on PX4 SITL's loopback). The estimate's error is p + n_p - r.
    """
    to = sample_time_s
    m, _ = closed_loop(plant, gains, to)
    law = law_state_space(gains, to, drag_per_s=plant.drag_per_s)
    n = plant.phi.shape[0]
    size = m.shape[-1]
    noise_in = np.concatenate([plant.gamma @ law["d"], law["b"]], axis=0)  # (size, 3) per unit of (p, v, tilt) read
    z = np.exp(1j * np.asarray(w, dtype=float) * to)
    v_per_p, v_per_v = velocity_read_transfer(to, w, velocity_from_position_s)
    zero = np.zeros_like(z)
    read_p = np.stack([np.ones_like(z), v_per_p, zero], axis=-1)  # per unit n_p: the (p, v, tilt) read
    read_v = np.stack([zero, v_per_v, zero], axis=-1)  # per unit n_v
    resolvent = z[:, None, None] * np.eye(size)[None] - m[None]
    x = np.linalg.solve(resolvent, noise_in[None] @ np.stack([read_p, read_v], axis=-1))  # (len(w), size, 2)
    tilt = np.einsum("i,wij->wj", plant.c[2], x[:, :n])
    pos = np.einsum("i,wij->wj", plant.c[0], x[:, :n])
    return {"tilt_p": tilt[:, 0], "tilt_v": tilt[:, 1], "error_p": pos[:, 0] + 1.0, "error_v": pos[:, 1]}


def noise_response(plant: DiscretePlant, gains: AxisGains, sample_time_s: float, spectra: EstimateErrorSpectra,
                   velocity_from_position_s: float = 0.0) -> NoiseResponse:  # fmt: skip
    """The RMS tilt and estimate error that errors of ``spectra`` make of the closed loop
    (``noise_transfer``): the integral over frequency of |H_p|^2 S_pp + |H_v|^2 S_vv + 2 Re(conj(H_p)
    H_v S_pv), S_pv = E[conj(N_p) N_v] (the bins between 0 Hz and the law's Nyquist frequency, both
    left out)."""
    f = np.asarray(spectra.frequencies_hz, dtype=float)
    keep = (f > 0.0) & (f < 0.5 / sample_time_s)
    f = f[keep]
    spp, svv, spv = (np.asarray(a)[keep] for a in (spectra.position, spectra.velocity, spectra.cross))
    h = noise_transfer(plant, gains, sample_time_s, 2.0 * math.pi * f, velocity_from_position_s)
    df = float(np.mean(np.diff(f))) if len(f) > 1 else 0.0

    def rms(hp: np.ndarray, hv: np.ndarray, with_p: bool = True, with_v: bool = True) -> float:
        density = (with_p * np.abs(hp) ** 2 * spp + with_v * np.abs(hv) ** 2 * svv
                   + (with_p and with_v) * 2.0 * np.real(np.conj(hp) * hv * spv))  # fmt: skip
        return math.sqrt(max(float(np.sum(density)) * df, 0.0))

    return NoiseResponse(math.degrees(rms(h["tilt_p"], h["tilt_v"])), rms(h["error_p"], h["error_v"]),
                         math.degrees(rms(h["tilt_p"], h["tilt_v"], with_v=False)),
                         math.degrees(rms(h["tilt_p"], h["tilt_v"], with_p=False)))  # fmt: skip


def pd_analysis(plant: DiscretePlant, k_pos_s2: float, k_vel_s: float, sample_time_s: float) -> tuple[float, float, float, float]:
    """(|pole| max, gain margin, phase margin deg, delay margin s) of a static PD on one axis,
    ``a_sp = -k_pos p - k_vel v`` sampled every To (the form of SE(3)'s position loop, Lee eq.
    15, without its feed-forward), on the same discretised plant as the law: how a baseline's
    gains sit against the design's margins through the same attitude loop."""
    to = sample_time_s
    k = np.array([[-k_pos_s2, -k_vel_s, 0.0]])
    rho = float(np.max(np.abs(np.linalg.eigvals(plant.phi + plant.gamma @ k @ plant.c))))
    w = _frequencies(to)
    z = np.exp(1j * w * to)
    loop = -(_plant_response(plant, z) @ k[0])
    gm, pm, dm = _margins(loop[None], w)
    return rho, float(gm[0]), float(pm[0]), float(dm[0])


@dataclass(frozen=True)
class Design:
    """Gains for every axis of the law, with the analysis that chose them.

    Attributes
    ----------
    sample_time_s : float
    north, east, up : AxisAnalysis
        North with the pitch loop, east with the roll loop, up with the thrust lag.
    reference_lead_s2 : (float, float)
        c2 of the horizontal and vertical reference responses (``tracking_lead_s2``).
    spec : MarginSpec
    model : InnerLoopModel
    """

    sample_time_s: float
    north: AxisAnalysis
    east: AxisAnalysis
    up: AxisAnalysis
    reference_lead_s2: tuple[float, float]
    spec: MarginSpec
    model: InnerLoopModel

    @property
    def horizontal(self) -> AxisGains:
        """The gains of the horizontal axes (north's; east's are the same)."""
        return self.north.gains

    @property
    def vertical(self) -> AxisGains:
        """The gains of the vertical axis."""
        return self.up.gains


def rate_plants(model: InnerLoopModel, sample_time_s: float) -> tuple[DiscretePlant, DiscretePlant]:
    """(north, east) discrete plants flown by body rates (``rate_axis_plant``): input omega_sp."""
    drag = model.drag_per_s

    def plant(loop: TiltLoop) -> DiscretePlant:
        return discretise(*rate_axis_plant(loop, drag_per_s=drag), sample_time_s, model.latency_s, tilt_state=TILT_STATE,
                          drag_per_s=drag)  # fmt: skip

    return plant(model.pitch), plant(model.roll)


def axis_plants(model: InnerLoopModel, sample_time_s: float) -> tuple[DiscretePlant, DiscretePlant, DiscretePlant]:
    """(north, east, up) discrete plants of a model at a sample time: input the acceleration
    command; through the autopilot's attitude loop, or with ``model.angle_gains`` through the
    law's own angle stage and the autopilot's rate loop (``rate_output_plant``)."""
    drag = model.drag_per_s
    if model.predict and model.observe and model.angle_gains is None:  # predicted, the rate loops observed
        north, east = (observed_plant(*tilt_axis_plant(loop, drag_per_s=drag), sample_time_s, model.latency_s, drag_per_s=drag,
                                      memory_s=model.observer_memory_at(sample_time_s)) for loop in (model.pitch, model.roll))  # fmt: skip
        up = predicted_plant(*vertical_plant(model.thrust_time_constant_s, drag), sample_time_s, model.latency_s, VERTICAL_MEASURED,
                             drag_per_s=drag)  # fmt: skip
        return north, east, up
    if model.predict and model.angle_gains is None:  # the law fed the state predicted over the latency
        north, east = (predicted_plant(*tilt_axis_plant(loop, drag_per_s=drag), sample_time_s, model.latency_s, HORIZONTAL_MEASURED,
                                       tilt_state=TILT_STATE, drag_per_s=drag) for loop in (model.pitch, model.roll))  # fmt: skip
        up = predicted_plant(*vertical_plant(model.thrust_time_constant_s, drag), sample_time_s, model.latency_s, VERTICAL_MEASURED,
                             drag_per_s=drag)  # fmt: skip
        return north, east, up
    if model.angle_gains is None:
        north = discretise(*tilt_axis_plant(model.pitch, drag_per_s=drag), sample_time_s, model.latency_s, tilt_state=2, drag_per_s=drag)
        east = discretise(*tilt_axis_plant(model.roll, drag_per_s=drag), sample_time_s, model.latency_s, tilt_state=2, drag_per_s=drag)
    else:
        north, east = (rate_output_plant(p, model.angle_gains, sample_time_s) for p in rate_plants(model, sample_time_s))
    up = discretise(*vertical_plant(model.thrust_time_constant_s, drag), sample_time_s, model.latency_s, drag_per_s=drag)
    return north, east, up


def _search(plants: tuple[DiscretePlant, ...], gains: AxisGains, to: float, spec: MarginSpec) -> np.ndarray:
    """The spectral radius of each candidate (1-D arrays in ``gains``), inf where ``spec`` is not
    met on every plant."""
    kp, kv, lead, ki, kiv = gains.arrays()
    if kp.size > 1024:  # in chunks: the frequency responses are (candidates, frequencies, 3) complex
        return np.concatenate([_search(plants, AxisGains(kp[i:i + 1024], kv[i:i + 1024], lead[i:i + 1024], ki[i:i + 1024],
                                                         kiv[i:i + 1024]), to, spec)
                               for i in range(0, kp.size, 1024)])  # fmt: skip
    rho = np.zeros(kp.shape)
    for plant in plants:
        rho = np.maximum(rho, np.max(np.abs(np.linalg.eigvals(closed_loop_matrix(plant, gains, to))), axis=-1))
    # the margins only where the loop is stable (an unstable candidate is out whatever its margins):
    # each candidate's frequency response is its own, so the subset's are the batch's to the bit, as
    # long as the law has the same states (law_state_space: an integral state if any candidate has one)
    stable = np.flatnonzero(rho < 1.0)
    if (bool(np.any(ki[stable] > 0.0)), bool(np.any(kiv[stable] > 0.0))) != (bool(np.any(ki > 0.0)), bool(np.any(kiv > 0.0))):
        stable = np.arange(kp.size)
    out = np.full(kp.shape, np.inf)
    if stable.size == 0:
        return out
    kp, kv, lead, ki, kiv = kp[stable], kv[stable], lead[stable], ki[stable], kiv[stable]
    w = _frequencies(to, 600)
    z = np.exp(1j * w * to)
    ok = np.ones(kp.shape, dtype=bool)
    law = _law_response(AxisGains(kp, kv, lead, ki, kiv), z, to)  # (candidates, w, 3)
    f = 1.0 + lead[:, None]  # the believed drag's delta v(n) is a static term of K (law_state_space's d)
    for plant in plants:
        with_drag = law.copy()
        with_drag[..., 1] += f * plant.drag_per_s
        loop = -np.sum(with_drag * _plant_response(plant, z)[None], axis=-1)
        gm, pm, dm = _margins(loop, w)
        ok &= (gm >= spec.gain_margin) & (pm >= spec.phase_margin_deg) & (dm >= spec.delay_margin_s)
        ok &= _sensitivity_peak(loop) <= spec.sensitivity_peak
    out[stable] = np.where(ok & (rho[stable] < 1.0), rho[stable], np.inf)
    return out


#: The closed-loop rates searched for each of k_pos and k_vel (1/s): k = exp(-rate To), so the
#: search means the same at any sample time (Table I's kx1 0.78 at 50 ms is 5.0 /s).
RATE_GRID_PER_S = np.geomspace(0.2, 40.0, 24)
#: The tilt leads searched (``[law] tilt_lead``) on the horizontal axes.
LEAD_GRID = np.round(np.arange(0.0, 3.01, 0.5), 2)
#: The integral gains searched (``[law] integral_gain_per_s``, 1/s), as fractions of the
#: position loop's own rate (1 - k_pos) / To: an integral that slow leaves the margins nearly as
#: they were and removes the steady error of a constant disturbance (wind, an estimator's tilt
#: bias, a mass error).
INTEGRAL_FRACTIONS = (0.1, 0.2, 0.3)
#: The velocity integral gains searched (``[law] velocity_integral_gain_per_s2``, 1/s^2), as
#: ``q rv^2`` with rv = (1 - k_vel) / To the velocity loop's own rate: the PI zero at q rv, a
#: fraction q of the loop's bandwidth (the usual placement for a PI speed loop, which leaves
#: its phase nearly as it was at the crossover). The largest the margins allow is taken; the
#: law holds the integral over a step's transient (``law_step``), where it would wind up.
VELOCITY_INTEGRAL_FRACTIONS = (0.05, 0.1, 0.2, 0.3)


def search_gains(plants: tuple[DiscretePlant, ...], sample_time_s: float, spec: MarginSpec, *,
                 leads: np.ndarray = LEAD_GRID, integral: bool = False, velocity_integral: bool = False,
                 rates_per_s: np.ndarray = RATE_GRID_PER_S) -> AxisGains:  # fmt: skip
    """The fastest law that meets ``spec`` on every plant given (one set shared by the axes).

    "Fastest": the smallest spectral radius of the loop without its integral. With ``integral``
    (``INTEGRAL_FRACTIONS``) or ``velocity_integral`` (``VELOCITY_INTEGRAL_FRACTIONS``): the
    largest integral fraction that some candidate keeps ``spec`` with, then the fastest of those
    candidates. (The fastest first and then its largest fraction made the design jump with the
    latency: on sitl-plant's loop the fastest proportional loop kept only q = 0.05 at 60 ms and
    0.1 at 110 ms, and the integral's mode then took 34 s and 16 s to 2 % where at 100 ms it takes
    3.8 s.) A grid of rates and leads, then a finer grid of rates around the best.

    Raises
    ------
    ValueError
        No candidate meets the margins (the inner loop is too slow for these margins).
    """
    to = sample_time_s
    plants = distinct_plants(plants)
    rates = np.asarray(rates_per_s, dtype=float)
    leads = np.asarray(leads, dtype=float)
    if integral and velocity_integral:
        raise ValueError("design one integral: the position or the velocity one")
    fractions = sorted(VELOCITY_INTEGRAL_FRACTIONS if velocity_integral else INTEGRAL_FRACTIONS, reverse=True) \
        if integral or velocity_integral else []  # fmt: skip

    def pick(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> AxisGains | None:
        # rounded as a controller file writes them (4 decimals), so the margins checked are the
        # margins of the gains written
        kp, kv = np.round(np.exp(-a * to), 4), np.round(np.exp(-b * to), 4)
        rho = _search(plants, AxisGains(kp, kv, c), to, spec)
        order = [i for i in np.argsort(rho) if np.isfinite(rho[i])][:64]
        if not order:
            return None
        def verified(cands: list[AxisGains]) -> AxisGains | None:
            # the search's coarser frequency grid can pass a candidate just short of the spec:
            # the first that the full analysis (analyse_axis) passes on every plant
            return next((g for g in cands if all(analyse_axis(pl, g, to).meets(spec) for pl in plants)), None)

        if not fractions:
            return verified([AxisGains(kp[i], kv[i], c[i]) for i in order])
        # the largest integral fraction some candidate keeps the margins with, then the fastest
        # (proportional loop) of those candidates
        idx = np.flatnonzero(np.isfinite(rho))
        for q in fractions:
            if velocity_integral:
                ki, kiv = np.zeros(idx.size), np.round(q * ((1.0 - kv[idx]) / to) ** 2, 4)
            else:
                ki, kiv = np.round(q * (1.0 - kp[idx]) / to, 4), np.zeros(idx.size)
            ok = np.isfinite(_search(plants, AxisGains(kp[idx], kv[idx], c[idx], ki, kiv), to, spec))
            ranked = [j for j in np.argsort(rho[idx], kind="stable") if ok[j]][:64]
            found = verified([AxisGains(kp[idx[j]], kv[idx[j]], c[idx[j]], ki[j], kiv[j]) for j in ranked])
            if found is not None:
                return found
        return None

    a, b, c = (g.ravel() for g in np.meshgrid(rates, rates, leads, indexing="ij"))
    coarse = pick(a, b, c)
    if coarse is None:
        raise ValueError(
            f"no gains with closed-loop rates in ({rates[0]:g}, {rates[-1]:g}) /s keep gain margin {spec.gain_margin:g}, "
            f"phase margin {spec.phase_margin_deg:g} deg, delay margin {spec.delay_margin_s:g} s and sensitivity peak "
            f"{spec.sensitivity_peak:g} at To {to:g} s"
        )
    step = float(np.log(rates[1] / rates[0]))
    fine = np.exp(np.linspace(-step, step, 7))
    lead_step = float(leads[1] - leads[0]) / 2 if leads.size > 1 else 0.0
    fine_leads = np.unique(np.maximum(float(coarse.lead) + np.array([-lead_step, 0.0, lead_step]), 0.0))
    ra, rb = -math.log(float(coarse.k_pos)) / to, -math.log(float(coarse.k_vel)) / to
    a2, b2, c2 = (g.ravel() for g in np.meshgrid(ra * fine, rb * fine, fine_leads, indexing="ij"))
    best = pick(a2, b2, c2) or coarse
    # as written in a controller file: 4 decimals
    return AxisGains(round(float(best.k_pos), 4), round(float(best.k_vel), 4), float(best.lead),
                     round(float(best.integral_per_s), 4), round(float(best.velocity_integral_per_s2), 4))  # fmt: skip


def angle_stage_plants(model: InnerLoopModel, sample_time_s: float) -> tuple[DiscretePlant, DiscretePlant]:
    """(pitch, roll) as the law's angle stage sees them (``angle_stage_plant``)."""
    pitch, roll = rate_plants(model, sample_time_s)
    return angle_stage_plant(pitch, sample_time_s), angle_stage_plant(roll, sample_time_s)


def design_angle_gains(model: InnerLoopModel, sample_time_s: float, spec: MarginSpec) -> AxisGains:
    """(kx7, kx8) = (kx9, kx10) for a body-rate output: the fastest angle stage that keeps
    ``spec`` on both tilt axes flown by the autopilot's rate loop (``search_gains`` on
    ``angle_stage_plants``; no lead, no integral)."""
    return search_gains(angle_stage_plants(model, sample_time_s), sample_time_s, spec, leads=np.zeros(1))


def design_gains(model: InnerLoopModel, sample_time_s: float = 0.05, spec: MarginSpec | None = None, *,
                 tilt_lead: bool = True, integral: bool = False, velocity_integral: bool = False,
                 body_rates: bool = False) -> Design:  # fmt: skip
    """The fastest law (gains, and the tilt lead and integral action where allowed) that keeps
    ``spec`` on every axis of ``model`` (module docstring).

    The position integral (``[law] integral_gain_per_s``) is one gain for all axes: the vertical
    axis is designed with the one the horizontal design chose. The velocity integral has its own
    vertical gain (``[law] vertical_velocity_integral_gain_per_s2``, as PX4 has MPC_XY_VEL_I_ACC
    and MPC_Z_VEL_I_ACC), designed with the vertical loop (``_search_vertical``): shared, the
    horizontal one was a twentieth of the vertical loop's own rate squared there, and its slow
    pole (2 % in 14-15 s) set how long a vertical error took to go. Both integrals are off by
    default here; ``offboard tune`` and ``offboard fly`` design the velocity integral
    (docs/controller-design.md: the position integral, added to eq. 32's desired speed, is cut by
    the speed bounds exactly when a disturbance needs it most).

    With ``body_rates`` the law closes the attitude loop itself (``--output rates``): its angle
    gains are designed first (``design_angle_gains``, into ``model.angle_gains``), then the
    position and velocity gains on the loop they close, without a tilt lead (it leads the
    attitude setpoint only, which a rate setpoint does not carry).
    """
    spec = spec or MarginSpec()
    to = sample_time_s
    if body_rates:
        model = replace(model, angle_gains=design_angle_gains(replace(model, angle_gains=None), to, spec))
        tilt_lead = False
    north_plant, east_plant, up_plant = axis_plants(model, to)
    h = search_gains((north_plant, east_plant), to, spec, leads=LEAD_GRID if tilt_lead else np.zeros(1), integral=integral,
                     velocity_integral=velocity_integral)  # fmt: skip
    v = _search_vertical(up_plant, to, spec, float(h.integral_per_s), velocity_integral=velocity_integral)
    north, east, up = analyse_axis(north_plant, h, to), analyse_axis(east_plant, h, to), analyse_axis(up_plant, v, to)
    reference_lead = (0.5 * (north.reference_lead_s2 + east.reference_lead_s2), up.reference_lead_s2)
    return Design(to, north, east, up, reference_lead, spec, model)


def step_hold_s(design: Design) -> float:
    """How long the velocity integral holds after a reference step at most (``[law]
    velocity_integral_hold_s``): the slowest axis's 2 % settling time without the integral (the
    proportional loop a step's transient is flown by), rounded up to the sample time."""
    to = design.sample_time_s
    north, _, up = axis_plants(design.model, to)
    times = [analyse_axis(plant, AxisGains(a.gains.k_pos, a.gains.k_vel, a.gains.lead), to).settling_time_s
             for plant, a in ((north, design.north), (up, design.up))]  # fmt: skip
    return math.ceil(max(times) / to) * to


def _search_vertical(plant: DiscretePlant, to: float, spec: MarginSpec, ki: float, *, velocity_integral: bool = False,
                     rates_per_s: np.ndarray = RATE_GRID_PER_S) -> AxisGains:  # fmt: skip
    """The vertical axis's (k_pos, k_vel) with the position integral gain ``ki`` fixed (shared
    with the horizontal axes) and, with ``velocity_integral``, its own velocity integral.

    As ``search_gains``: the fastest loop without its integrals that keeps the margins with them;
    with ``velocity_integral``, first the largest fraction q of ``VELOCITY_INTEGRAL_FRACTIONS``
    (ki = q rv^2, rv = (1 - k_vel) / To) that some candidate keeps them with. Sharing the
    horizontal axes' integral, the vertical one was q = 0.05 of the vertical loop's rate squared,
    and its PI zero at 0.27 /s was the loop's slowest pole (2 % in 14 s on sitl-plant's loop,
    15 s on PX4 SIH's); designed with the vertical loop it settles in about 2 s with the same
    margins."""
    rates = np.asarray(rates_per_s, dtype=float)
    a, b = (g.ravel() for g in np.meshgrid(rates, rates, indexing="ij"))
    step = float(np.log(rates[1] / rates[0]))
    fine = np.exp(np.linspace(-step, step, 7))

    def candidates(a: np.ndarray, b: np.ndarray, q: float) -> AxisGains:
        kp, kv = np.round(np.exp(-a * to), 4), np.round(np.exp(-b * to), 4)
        return AxisGains(kp, kv, np.zeros_like(kp), np.full_like(kp, ki), np.round(q * ((1.0 - kv) / to) ** 2, 4))

    def rank(cand: AxisGains) -> np.ndarray:
        # the fastest loop without its integrals (slow by design) that keeps the margins with them
        kp, kv, _, _, _ = cand.arrays()
        ok = np.isfinite(_search((plant,), cand, to, spec))
        return np.where(ok, _search((plant,), AxisGains(kp, kv), to, MarginSpec(0.0, -math.inf, 0.0)), np.inf)

    for q in sorted(VELOCITY_INTEGRAL_FRACTIONS, reverse=True) if velocity_integral else [0.0]:
        cand = candidates(a, b, q)
        rho = rank(cand)
        if not np.isfinite(rho).any():
            continue
        best = int(np.argmin(rho))
        a2, b2 = (g.ravel() for g in np.meshgrid(a[best] * fine, b[best] * fine, indexing="ij"))
        cand2 = candidates(a2, b2, q)
        rho2 = rank(cand2)
        kp2, kv2, _, _, kiv2 = cand2.arrays()
        for i in [int(i) for i in np.argsort(rho2) if np.isfinite(rho2[i])]:
            # the first the full analysis passes too (the search's frequency grid is coarser)
            g = AxisGains(float(kp2[i]), float(kv2[i]), 0.0, ki, float(kiv2[i]))
            if analyse_axis(plant, g, to).meets(spec):
                return g
        kp, kv, _, _, kiv = cand.arrays()
        return AxisGains(float(kp[best]), float(kv[best]), 0.0, ki, float(kiv[best]))
    raise ValueError(f"no vertical gains keep the margins at To {to:g} s with integral gain {ki:g} /s")


# --- designs near a design: what offboard tune --search flies ------------------------------------

#: ``offboard tune --search``: the factors on the designed horizontal loop's position and velocity
#: rates (k = exp(-rate To)), the steps of its tilt lead, and the factors on the velocity integral
#: (shared by the axes), whose combinations are the designs the search may fly.
NEAR_RATE_FACTORS = (0.8, 1.0, 1.25)
NEAR_LEAD_STEPS = (-0.25, 0.0, 0.25)
NEAR_INTEGRAL_FACTORS = (0.5, 1.0, 2.0)


def with_gains(design: Design, horizontal: AxisGains, vertical: AxisGains) -> Design:
    """``design`` with other gains, every axis analysed again (the same model and margins asked)."""
    to = design.sample_time_s
    north_plant, east_plant, up_plant = axis_plants(design.model, to)
    north, east, up = (analyse_axis(north_plant, horizontal, to), analyse_axis(east_plant, horizontal, to),
                       analyse_axis(up_plant, vertical, to))  # fmt: skip
    reference_lead = (0.5 * (north.reference_lead_s2 + east.reference_lead_s2), up.reference_lead_s2)
    return Design(to, north, east, up, reference_lead, design.spec, design.model)


def nearby_designs(design: Design, limit: int = 12) -> list[Design]:
    """Designs near ``design`` that keep its margins, for a search by flying them.

    Every combination of ``NEAR_RATE_FACTORS`` on the horizontal position and velocity rates,
    ``NEAR_LEAD_STEPS`` on the tilt lead (not below 0) and ``NEAR_INTEGRAL_FACTORS`` on the
    horizontal velocity integral (the vertical axis keeping its gains and its own integral), rounded as a
    controller file writes them and analysed in full; kept where every axis meets ``design.spec``.
    ``design`` itself first, then the others nearest first (one factor changed, then two ...; of
    as many changes, the faster horizontal loop first: the smaller spectral radius of its
    proportional part, as ``search_gains`` ranks), at most ``limit`` in all.
    """
    to = design.sample_time_s
    h, v = design.horizontal, design.vertical
    rate_pos, rate_vel = -math.log(float(h.k_pos)) / to, -math.log(float(h.k_vel)) / to
    seen = {(float(h.k_pos), float(h.k_vel), float(h.lead), float(h.velocity_integral_per_s2))}
    near: list[tuple[int, float, Design]] = []
    north_plant, _, _ = axis_plants(design.model, to)
    for fp in NEAR_RATE_FACTORS:
        for fv in NEAR_RATE_FACTORS:
            for step in NEAR_LEAD_STEPS:
                for fi in NEAR_INTEGRAL_FACTORS:
                    kp, kv = round(math.exp(-rate_pos * fp * to), 4), round(math.exp(-rate_vel * fv * to), 4)
                    lead, kiv = max(0.0, float(h.lead) + step), round(float(h.velocity_integral_per_s2) * fi, 4)
                    if (kp, kv, lead, kiv) in seen:
                        continue
                    seen.add((kp, kv, lead, kiv))
                    candidate = with_gains(design, AxisGains(kp, kv, lead, float(h.integral_per_s), kiv), v)
                    axes = (candidate.north, candidate.east, candidate.up)
                    if all(a.meets(design.spec) for a in axes):
                        changes = (fp != 1.0) + (fv != 1.0) + (lead != float(h.lead)) + (fi != 1.0)
                        speed = analyse_axis(north_plant, AxisGains(kp, kv, lead), to).spectral_radius
                        near.append((changes, speed, candidate))
    near.sort(key=lambda item: item[:2])
    return [design, *(d for _, _, d in near[: max(0, limit - 1)])]
