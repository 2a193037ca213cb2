"""The batched engine: N flights of a sweep stepped together, each equal to its one-vehicle flight.

Per control sample, for every flight still flying at once:

- the measurement: the true state of each rigid body (``RigidBodyModel.vehicle_state``'s
  Euler angles from the normalised quaternion) and the Euler rates by eq. 3 with the
  controller's W_eta (``offboard.model.euler_lagrange.euler_rates_from_body_rates``), as numpy arrays over the batch;
- the law: ``law_step`` itself on numpy batches (``NUMPY_OPS``), each flight with its own
  believed mass, gravity and gains (arrays in the parameters it reads);
- the vehicle: the paper's inner loop (tau~ held, eq. 16 at the physics rate with the believed
  inertia), the mixer, RK4 at the physics step and the ground, by
  ``sitl_plant.dynamics.batch.advance_many`` (compiled and spread over the cores with numba),
  each flight with its own vehicle, wind and latency;
- the paper's accelerometer noise (``PaperAccelNoise``: 5 % on the accelerations, integrated
  into speed and position), each flight drawing from its own seeded stream as the one-vehicle
  path does.

The one-vehicle path (``offboard.inprocess.simulate``, ``flight.fly_one``) stays the reference:
the batch gives the same flight to rounding (tests/unit/offboard/test_sweep_batch.py asserts
1e-9 m on a sample of flights). Flights the batch does not fly (the paper's model, the ``px4``
and ``held-torque`` drives, the ``imu`` sensor model: ``unsupported``) are flown by ``fly_one``, so a
sweep's rows never depend on the engine.

Flights are batched in groups that share what the law branches on (sample time, limits,
options, the integral gain, the latency and the physics step); within a group only numbers
differ.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import cast

import numpy as np

from offboard.controller.law import NUMPY_OPS, LawMemory, law_step
from offboard.controller.params import GAIN_NAMES, ControllerGains
from offboard.controller.velocity import ConsistentVelocity
from offboard.frames import tracking_reference
from offboard.metrics import lost, lost_reason
from offboard.model.euler_lagrange import EulerRateForm
from offboard.record import FlightStatus
from offboard.sweep.flight import Series, fly_one, row_of
from offboard.sweep.spec import FlightSetup, FlightSpec, SweepSpec, scenario_of
from offboard.trajectory.base import ReferencePairs
from sitl_plant.dynamics.batch import _EULER_FORMS, advance_many, param_vector
from sitl_plant.dynamics.rigid_body import STATE_SIZE, RigidBodyModel
from sitl_plant.dynamics.sensors import CleanSensors, PaperAccelNoise, sensors_from_spec
from sitl_plant.dynamics.wind import wind_from_spec

#: ``advance_many``'s mode for the paper's tau~: 2, eq. 16 with no trigonometric call, as the
#: one-vehicle kernel (``FastRigidBodySim``) computes it too (1: with the angles' sines and cosines;
#: the same flights to rounding, slower).
TAU_MODE = 2
_BELIEF_FIELDS = ("mass_kg", "gravity_m_s2", "inertia_kg_m2", "arm_length_m", "drag_to_thrust_m")


def unsupported(setup: FlightSetup) -> str:
    """Why the batch does not fly this flight ('' when it does)."""
    sc = setup.scenario
    if sc.model != "rigid-body":
        return f"model {sc.model}"
    if sc.drive != "inner-loop":
        return f"drive {sc.drive}"
    if not isinstance(sensors_from_spec(sc.sensors, sc.seed), (CleanSensors, PaperAccelNoise)):
        return f"sensors {sc.sensors}"
    return ""


def _group_key(setup: FlightSetup) -> tuple:
    sc = setup.scenario
    c = replace(sc.controller, gains=ControllerGains(), **{f: getattr(ControllerParamsDefaults, f) for f in _BELIEF_FIELDS})
    late = int(round(setup.latency_s / sc.physics_dt_s))
    return (c, sc.physics_dt_s, sc.flight_duration_s, sc.ground, late)


class ControllerParamsDefaults:
    """The believed numbers a group's key sets to fixed values: flights that differ only in what they
    believe share one batch."""

    mass_kg = 0.5
    gravity_m_s2 = 9.81
    inertia_kg_m2 = (3.8e-3, 3.8e-3, 7.1e-3)
    arm_length_m = 0.24
    drag_to_thrust_m = 0.016


def fly_batch(spec: SweepSpec, fls: list[FlightSpec]) -> list[dict]:
    """The rows of flights ``fls`` (in their order), batched where ``unsupported`` allows."""
    setups = [scenario_of(spec, fl) for fl in fls]
    rows: list[dict | None] = [None] * len(fls)
    groups: dict[tuple, list[int]] = {}
    for k, setup in enumerate(setups):
        if unsupported(setup):
            rows[k] = fly_one(spec, fls[k])[0]
        else:
            groups.setdefault(_group_key(setup), []).append(k)
    for members in groups.values():
        for k, series in zip(members, fly_group([setups[k] for k in members])):
            rows[k] = row_of(series, spec.base.trajectory.phases(), spec.base.flight_duration_s, spec.converged_m)
    return rows  # type: ignore[return-value]


def _truth(x: np.ndarray) -> tuple[np.ndarray, ...]:
    """Euler angles (ZYX, rad) of each row of ``x`` as ``RigidBodyModel.vehicle_state`` gives them."""
    qw, qx, qy, qz = x[:, 6], x[:, 7], x[:, 8], x[:, 9]
    norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, a, b, c = qw / norm, qx / norm, qy / norm, qz / norm
    roll = np.arctan2(2.0 * (w * a + b * c), 1.0 - 2.0 * (a * a + b * b))
    pitch = np.arcsin(np.clip(2.0 * (w * b - c * a), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * c + a * b), 1.0 - 2.0 * (b * b + c * c))
    return roll, pitch, yaw


def _euler_rates(euler: tuple[np.ndarray, ...], rates: np.ndarray, form: EulerRateForm) -> tuple[np.ndarray, ...]:
    """``offboard.model.euler_lagrange.euler_rates_from_body_rates`` over the batch (eq. 3 solved in closed form)."""
    index, k = _EULER_FORMS[form]
    theta, a = euler[1], euler[int(index)]
    st, ct = np.sin(theta), np.cos(theta)
    sa, ca = np.sin(a), np.cos(a)
    ct_sa, k_sa, ct_ca = ct * sa, k * sa, ct * ca
    det = ca * ct_ca - ct_sa * k_sa
    p, q, r = rates[:, 0], rates[:, 1], rates[:, 2]
    theta_dot = (ct_ca * q - ct_sa * r) / det
    psi_dot = (ca * r - k_sa * q) / det
    return p - (-st) * psi_dot, theta_dot, psi_dot


def fly_group(setups: list[FlightSetup]) -> list[Series]:
    """Fly flights that share a group key (``_group_key``) together; one ``Series`` each."""
    first = setups[0].scenario
    ctl = first.controller
    n = len(setups)
    to, dt = ctl.sample_time_s, first.physics_dt_s
    n_physics = int(round(to / dt))
    n_late = int(round(setups[0].latency_s / dt))
    duration = first.flight_duration_s
    samples = int(round(duration / to))
    trajectory = first.trajectory
    ground = first.ground

    # the law's parameters, the believed numbers as arrays over the batch
    beliefs = [s.scenario.controller for s in setups]
    gains = SimpleNamespace(**{g: np.array([getattr(b.gains, g) for b in beliefs]) for g in GAIN_NAMES})
    params = SimpleNamespace(**{f.name: getattr(ctl, f.name) for f in ctl.__dataclass_fields__.values()})
    params.gains = gains
    params.mass_kg = np.array([b.mass_kg for b in beliefs])
    params.gravity_m_s2 = np.array([b.gravity_m_s2 for b in beliefs])
    believed = np.ascontiguousarray([b.inertia_kg_m2 for b in beliefs], dtype=float)
    form = ctl.euler_rate_form
    lead = ctl.reference_lead_s2
    # [law] velocity_from_position_s: PaperController's filter, elementwise over the batch
    consistent = (ConsistentVelocity(ctl.velocity_from_position_s, to, identify=ctl.velocity_from_position_identify)
                  if ctl.velocity_from_position_s > 0 else None)  # fmt: skip

    # the vehicles
    x = np.empty((n, STATE_SIZE))
    p = np.empty((n, 14))
    on_ground = np.zeros(n, dtype=bool)
    winds = []
    for i, s in enumerate(setups):
        sc = s.scenario
        pos0 = np.array(sc.initial_pos_ned_m, dtype=float)
        x[i] = RigidBodyModel(sc.vehicle).initial_state(pos0, sc.initial_yaw_rad)
        p[i] = param_vector(sc.vehicle)
        on_ground[i] = ground and bool(pos0[2] >= 0.0)
        winds.append(None if sc.wind == "none" else wind_from_spec(sc.wind, sc.seed))
    xdot = np.zeros((n, STATE_SIZE))
    for j, s_ in enumerate(setups):  # VehicleSim's mean derivative before the first step
        if not on_ground[j]:
            xdot[j] = RigidBodyModel(s_.scenario.vehicle).derivative(x[j], 0.0, np.zeros(3), np.zeros(3))
    meters = [sensors_from_spec(s_.scenario.sensors, s_.scenario.seed) for s_ in setups]
    noisy = np.array([isinstance(m, PaperAccelNoise) for m in meters])
    fraction = np.array([m.fraction if isinstance(m, PaperAccelNoise) else 0.0 for m in meters])
    # each flight's normals, drawn as PaperAccelNoise.measure draws them: 3 a sample, in order
    normals = np.zeros((n, samples + 1, 3))
    for j, meter in enumerate(meters):
        if isinstance(meter, PaperAccelNoise):
            normals[j] = meter.normals(samples + 1)
    vel_error, pos_error = np.zeros((n, 3)), np.zeros((n, 3))
    previous_vel, previous_time = x[:, 3:6].copy(), 0.0
    cmd = np.zeros((n, 4))
    wind_buf = np.zeros((n, n_physics, 3))
    windy = [i for i, w in enumerate(winds) if w is not None]
    steps_done = 0

    def draw_winds(count: int) -> np.ndarray:
        """Each windy flight's wind at the next ``count`` physics steps' times, one call a flight."""
        out = wind_buf[:, :count]
        times = np.arange(steps_done, steps_done + count) * dt  # VehicleSim's time: steps * dt
        for i in windy:
            if active[i]:
                w = winds[i]
                many = getattr(w, "velocity_ned_many", None)
                if many is not None:
                    out[i] = many(times)
                else:
                    for j in range(count):
                        out[i, j] = w.velocity_ned(float(times[j]), x[i, 0:3])  # type: ignore[union-attr]
        return np.ascontiguousarray(out)

    rec_pos = np.full((n, samples + 1, 3), np.nan)
    rec_euler = np.full((n, samples + 1, 3), np.nan)
    rec_thrust = np.full((n, samples + 1), np.nan)
    rec_ref = np.zeros((samples + 1, 3))
    rows = np.zeros(n, dtype=int)
    status = [FlightStatus.COMPLETE] * n
    detail = [""] * n
    active = np.ones(n, dtype=bool)
    memory: LawMemory | None = None
    prev_thrust, prev_tau, prev_mode = np.zeros(n), np.zeros((n, 3)), 0
    t_s = np.arange(samples + 1) * to

    references = ReferencePairs(trajectory, to)
    with np.errstate(all="ignore"):
        for k in range(samples + 1):
            t = k * to
            ref_n, ref_n1 = references.pair(t)
            rec_ref[k] = ref_n.pos_ned_m
            euler = _truth(x)
            rates = _euler_rates(euler, x[:, 10:13], form)
            pos, vel = x[:, 0:3], x[:, 3:6]
            if noisy.any():  # PaperAccelNoise.measure over the batch
                time_s = (k * n_physics) * dt  # VehicleSim's time: steps * dt
                if k == 0:
                    noise = fraction[:, None] * np.abs(xdot[:, 3:6]) * normals[:, 0]
                else:
                    step = time_s - previous_time
                    mean_acc = (vel - previous_vel) / step
                    noise = fraction[:, None] * np.abs(mean_acc) * normals[:, k]
                    new_vel_error = vel_error + noise * step
                    pos_error = pos_error + 0.5 * step * (vel_error + new_vel_error)
                    vel_error = new_vel_error
                previous_vel, previous_time = vel.copy(), time_s
                pos = np.where(noisy[:, None], pos + pos_error, pos)
                vel = np.where(noisy[:, None], vel + vel_error, vel)
            if consistent is not None:
                vel = consistent.update(pos, vel)
            state = (pos[:, 0], vel[:, 0], pos[:, 1], vel[:, 1], -pos[:, 2], -vel[:, 2], euler[0], rates[0], euler[1],
                     rates[1], euler[2], rates[2])  # fmt: skip
            if memory is None:  # the law's numbers are arrays over the batch here (NUMPY_OPS)
                memory = LawMemory.from_state(cast(tuple[float, ...], state))
            out, new_memory = law_step(params, memory, state, tracking_reference(ref_n, lead),  # type: ignore[arg-type]
                                       tracking_reference(ref_n1, lead), NUMPY_OPS)  # fmt: skip
            memory = LawMemory(*(cast(float, np.where(active, new, old)) for new, old in zip(new_memory, memory)))
            # simulate's check, on the truth before the row is written
            finite = np.all(np.isfinite(x), axis=1)
            for i in np.nonzero(active & lost(finite, euler[0], euler[1], x[:, 0:3]))[0].tolist():
                why = lost_reason(bool(finite[i]), float(euler[0][i]), float(euler[1][i]), x[i, 0:3], "simulated")
                status[i], detail[i] = FlightStatus.DIVERGED, f"at t = {t:.2f} s: {why}"
                active[i] = False
            rec_pos[active, k] = x[active, 0:3]
            rec_euler[active, k] = np.stack(euler, axis=1)[active]
            thrust = np.asarray(out.thrust_n, dtype=float) * np.ones(n)
            tau = np.stack([np.asarray(v, dtype=float) * np.ones(n) for v in out.tau_tilde], axis=1)
            rec_thrust[active, k] = thrust[active]
            rows[active] = k + 1
            bad = active & ~(np.isfinite(thrust) & np.all(np.isfinite(tau), axis=1) & np.isfinite(out.roll_ref_rad)
                             & np.isfinite(out.pitch_ref_rad))  # fmt: skip
            for i in np.nonzero(bad)[0].tolist():
                status[i], detail[i] = FlightStatus.NAN_COMMAND, f"at t = {t:.2f} s the controller's output is not finite"
                active[i] = False
            if k == samples or not active.any():
                break
            if n_late:  # the previous command until this one arrives (simulate's latency_s)
                advance_many(x, active, n_late, dt, prev_thrust, prev_tau, believed, form, p, draw_winds(n_late), ground,
                             xdot, cmd, on_ground, mode=prev_mode)  # fmt: skip
                steps_done += n_late
            rest = n_physics - n_late
            advance_many(x, active, rest, dt, thrust, np.ascontiguousarray(tau), believed, form, p, draw_winds(rest),
                         ground, xdot, cmd, on_ground, mode=TAU_MODE)  # fmt: skip
            steps_done += rest
            prev_thrust, prev_tau, prev_mode = thrust, np.ascontiguousarray(tau), TAU_MODE
    return [
        Series(t_s[: rows[i]], rec_pos[i, : rows[i]], rec_ref[: rows[i]], rec_euler[i, : rows[i]], rec_thrust[i, : rows[i]],
               status[i], detail[i])  # fmt: skip
        for i in range(n)
    ]
