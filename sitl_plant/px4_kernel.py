"""PX4's attitude P and rate PID fused with the rigid body's RK4: one compiled call per period.

``Px4Loop`` (``inner_loops``) is the reference, in Python. In the attitude and rates modes on the
rigid body, what it does between two setpoints is arithmetic on the state alone: every
``every`` physics steps read the quaternion and body rates, compute the rate setpoint
(``Px4Loop.attitude_rates``) and the normalised torque (``Px4Loop.rate_torque``), mix, and hold
that for the steps in between. ``advance_px4`` runs exactly that, with the very same operations
in the same order (so the same floating-point results), together with the physics kernels of
``dynamics.batch``, and hands the loop's state (integrators, previous rates, step counter, last
output) back to the ``Px4Loop``. Compiled with numba when ``dynamics.batch`` is; otherwise it is
plain Python and nobody calls it (``FastRigidBodySim`` is only used with numba).

No sockets, files or clocks: a pure function of arrays.
"""

from __future__ import annotations

import math

import numpy as np

from sitl_plant.dynamics import batch, rigid_body
from sitl_plant.dynamics.batch import _jit, _speeds_for, physics_scratch, physics_step
from sitl_plant.dynamics.rigid_body import STATE_SIZE

I_FACTOR_RATE = math.radians(400.0)  # as inner_loops._I_FACTOR_RATE (PX4 RateControl)


@_jit
def _qmul(aw, ax, ay, az, bw, bx, by, bz):  # noqa: ANN001, ANN202
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@_jit
def _qnormalize(w, x, y, z):  # noqa: ANN001, ANN202
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


@_jit
def _dcm_z(w, x, y, z):  # noqa: ANN001, ANN202
    return 2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)


@_jit
def _quat_between(s0, s1, s2, d0, d1, d2):  # noqa: ANN001, ANN202
    """``offboard.model.attitude.quat_between``."""
    cx = s1 * d2 - s2 * d1
    cy = s2 * d0 - s0 * d2
    cz = s0 * d1 - s1 * d0
    dot = s0 * d0 + s1 * d1 + s2 * d2
    if math.sqrt(cx * cx + cy * cy + cz * cz) < 1e-5 and dot < 0:
        a0, a1, a2 = abs(s0), abs(s1), abs(s2)
        if a0 < a1 and a0 < a2:
            e0, e1, e2 = 1.0, 0.0, 0.0
        elif a1 < a2:
            e0, e1, e2 = 0.0, 1.0, 0.0
        else:
            e0, e1, e2 = 0.0, 0.0, 1.0
        cx = s1 * e2 - s2 * e1
        cy = s2 * e0 - s0 * e2
        cz = s0 * e1 - s1 * e0
        return _qnormalize(0.0, cx, cy, cz)
    return _qnormalize(dot + 1.0, cx, cy, cz)


@_jit
def _clip(v, lo, hi):  # noqa: ANN001, ANN202
    """Python's ``min(max(v, lo), hi)``."""
    m = lo if lo > v else v
    return hi if hi < m else m


@_jit
def attitude_rates(q, q_sp, yaw_w, att_p, yaw_ff, rate_max, out):  # noqa: ANN001, ANN202
    """``Px4Loop.attitude_rates`` into ``out``."""
    ez = _dcm_z(q[0], q[1], q[2], q[3])
    ezd = _dcm_z(q_sp[0], q_sp[1], q_sp[2], q_sp[3])
    r = _quat_between(ez[0], ez[1], ez[2], ezd[0], ezd[1], ezd[2])
    if abs(r[1]) > 1 - 1e-5 or abs(r[2]) > 1 - 1e-5:
        r = (q_sp[0], q_sp[1], q_sp[2], q_sp[3])
    else:
        r = _qmul(r[0], r[1], r[2], r[3], q[0], q[1], q[2], q[3])
    m = _qmul(r[0], -r[1], -r[2], -r[3], q_sp[0], q_sp[1], q_sp[2], q_sp[3])
    if m[0] < 0:
        m = (-m[0], -m[1], -m[2], -m[3])
    w0 = _clip(m[0], -1.0, 1.0)
    w3 = _clip(m[3], -1.0, 1.0)
    qd = _qmul(r[0], r[1], r[2], r[3], math.cos(yaw_w * math.acos(w0)), 0.0, 0.0, math.sin(yaw_w * math.asin(w3)))
    qe = _qmul(q[0], -q[1], -q[2], -q[3], qd[0], qd[1], qd[2], qd[3])
    sign = 2.0 if qe[0] >= 0 else -2.0
    r0 = sign * qe[1] * att_p[0]
    r1 = sign * qe[2] * att_p[1]
    r2 = sign * qe[3] * att_p[2]
    if yaw_ff != 0.0:
        zb = _dcm_z(q[0], -q[1], -q[2], -q[3])
        r0 = r0 + zb[0] * yaw_ff
        r1 = r1 + zb[1] * yaw_ff
        r2 = r2 + zb[2] * yaw_ff
    out[0] = _clip(r0, -rate_max[0], rate_max[0])
    out[1] = _clip(r1, -rate_max[1], rate_max[1])
    out[2] = _clip(r2, -rate_max[2], rate_max[2])


@_jit
def advance_px4(x, n_steps, dt, winds, ground, xdot, cmd, p, every, count, attitude, q_sp, rates_sp, yaw_ff,  # noqa: ANN001, ANN201
                thrust, held_thrust, yaw_w, gains, rate_max, tq_max, landed, rate_int, prev, has_prev, torque):  # fmt: skip
    """``n_steps`` physics steps flown by the PX4 attitude (``attitude``) or rate loop.

    ``gains`` rows: attitude P, rate P, rate I, rate D, integrator limits. ``torque`` (in: the
    held body torque, out: the last one), ``rate_int`` and ``prev`` (previous body rates, valid
    when ``has_prev``) are updated in place. ``held_thrust`` is flown until the loop next runs,
    then ``thrust``. Returns (resting on the ground, step counter, has_prev, thrust flown last).
    """
    k1, k2, k3, k4, tmp, nxt = physics_scratch()
    q = np.empty(4)
    sp = np.empty(3)
    loop_dt = dt * every
    resting = False
    out_thrust = held_thrust
    _speeds_for(out_thrust, torque[0], torque[1], torque[2], p, cmd)
    for step in range(n_steps):
        if count % every == 0:
            qq = _qnormalize(x[6], x[7], x[8], x[9])
            q[0], q[1], q[2], q[3] = qq[0], qq[1], qq[2], qq[3]
            rates0, rates1, rates2 = x[10], x[11], x[12]
            if attitude:
                attitude_rates(q, q_sp, yaw_w, gains[0], yaw_ff, rate_max, sp)
            else:
                sp[0], sp[1], sp[2] = rates_sp[0], rates_sp[1], rates_sp[2]
            if not has_prev:
                prev[0], prev[1], prev[2] = rates0, rates1, rates2
            for i in range(3):
                rate = rates0 if i == 0 else (rates1 if i == 1 else rates2)
                err = sp[i] - rate
                accel = (rate - prev[i]) / loop_dt
                u = gains[1, i] * err + rate_int[i] - gains[3, i] * accel
                if not landed and not ((u > 1.0 and err > 0) or (u < -1.0 and err < 0)):
                    i_factor = err / I_FACTOR_RATE
                    i_factor = max(0.0, 1.0 - i_factor * i_factor)
                    lim = gains[4, i]
                    rate_int[i] = _clip(rate_int[i] + i_factor * gains[2, i] * err * loop_dt, -lim, lim)
                torque[i] = _clip(u, -1.0, 1.0) * tq_max[i]
            prev[0], prev[1], prev[2] = rates0, rates1, rates2
            has_prev = True
            out_thrust = thrust
            _speeds_for(out_thrust, torque[0], torque[1], torque[2], p, cmd)
        count += 1
        resting = physics_step(x, cmd, winds[step], p, dt, ground, xdot, nxt, k1, k2, k3, k4, tmp)
    return resting, count, has_prev, out_thrust


def warm_up() -> None:
    """Load (or compile) the kernel now rather than at the first setpoint."""
    x = np.zeros(STATE_SIZE)
    x[6] = 1.0
    x[2] = -1.0
    from sitl_plant.dynamics.batch import param_vector
    from offboard.model.vehicle import VehicleParams

    advance_px4(x, 2, 1e-3, np.zeros((2, 3)), True, np.zeros(STATE_SIZE), np.zeros(4), param_vector(VehicleParams()),
                3, 0, True, np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.0, 1.0, 1.0, 0.5, np.ones((5, 3)),
                np.ones(3), np.ones(3), False, np.zeros(3), np.zeros(3), False, np.zeros(3))  # fmt: skip


def compiled_ready() -> bool:
    """Whether the plant's compiled kernels (rigid body, PX4 loop) can be loaded from numba's cache."""
    return batch.is_cached(batch._advance, advance_px4)


batch.drop_stale_cache(_qmul, (batch.__file__, rigid_body.__file__))  # batch's physics is built into these kernels


def compile_all() -> None:
    """Compile (first time, ~10 s) or load the plant's kernels; ``python -m sitl_plant.px4_kernel``."""
    batch.warm_up()
    warm_up()


if __name__ == "__main__":
    import time

    start = time.monotonic()
    compile_all()
    print(f"sitl-plant kernels ready ({'numba' if batch.NUMBA else 'no numba: interpreted'}) in {time.monotonic() - start:.1f} s")
