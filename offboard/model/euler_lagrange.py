"""The rotational Euler-Lagrange model of the paper (eq. 3-6, 13-17).

Generalised coordinates eta = (phi, theta, psi); ``omega = W_eta @ eta_dot`` (eq. 3),
``J = W_eta^T I W_eta`` (eq. 5), and

    J eta_ddot + C(eta, eta_dot) eta_dot = tau                      (eq. 13, 15)
    C eta_dot = J_dot eta_dot - 1/2 d/d eta (eta_dot^T J eta_dot)    (eq. 14)
    tau = C eta_dot + J tau_tilde   =>   eta_ddot = tau_tilde        (eq. 16, 17)

The Coriolis term is computed for real from the analytic derivatives of W_eta.

W_eta comes in three forms (``form``), all ``[[1, 0, -s_theta], [0, c_a, c_theta s_a],
[0, sign * s_a, c_theta c_a]]`` with angle ``a`` and ``sign``:

- ``castillo``: a = psi, sign = -1 (the model the paper cites; det = cos theta);
- ``printed``: a = psi, sign = +1 (eq. 4 as printed; det = cos theta cos 2 psi, singular at pi/4);
- ``zyx``: a = phi, sign = -1 (a rigid body's ZYX Euler-rate map).

All functions are pure and take plain arrays; shapes are (3,) for vectors and (3, 3) for
matrices.
"""

from __future__ import annotations

import enum
import math

from collections.abc import Sequence

import numpy as np

#: Three angles, rates or torques: an array, or a tuple where the hot path avoids building one.
Vec3Like = Sequence[float] | np.ndarray



class EulerRateForm(enum.StrEnum):
    """Which W_eta (eq. 4) maps Euler rates to body rates (module docstring)."""

    CASTILLO = "castillo"
    PRINTED = "printed"
    ZYX = "zyx"


#: Each form's W_eta as (the angle its off-diagonal terms use: 0 phi, 2 psi; their sign): the one
#: table the numpy maps here and the compiled kernels (``sitl_plant.dynamics.batch``) read.
EULER_FORM_TERMS: dict[EulerRateForm, tuple[int, float]] = {
    EulerRateForm.CASTILLO: (2, -1.0),
    EulerRateForm.PRINTED: (2, 1.0),
    EulerRateForm.ZYX: (0, -1.0),
}


def _angle_and_sign(form: EulerRateForm) -> tuple[int, float]:
    try:
        return EULER_FORM_TERMS[form]
    except KeyError:
        raise ValueError(f"unknown Euler-rate form {form!r}; expected one of {sorted(f.value for f in EulerRateForm)}") from None


def euler_rate_matrix(eta: np.ndarray, form: EulerRateForm = EulerRateForm.CASTILLO) -> np.ndarray:
    """W_eta of eq. 4: body angular velocity ``omega = W_eta @ eta_dot`` (eq. 3)."""
    index, sign = _angle_and_sign(form)
    theta = eta[1]
    a = eta[index]
    st, ct = np.sin(theta), np.cos(theta)
    sa, ca = np.sin(a), np.cos(a)
    return np.array([[1.0, 0.0, -st], [0.0, ca, ct * sa], [0.0, sign * sa, ct * ca]])


def _w_terms(eta: Vec3Like, form: EulerRateForm) -> tuple[float, float, float, float, float]:
    """(sin theta, cos theta, sin a, cos a, sign) of W_eta (eq. 4) at ``eta``, as floats: the
    scalar maps below need only these, and math on floats is what makes them cheap per sample."""
    index, sign = _angle_and_sign(form)
    theta, a = float(eta[1]), float(eta[index])
    return math.sin(theta), math.cos(theta), math.sin(a), math.cos(a), sign


def _solve_w_transposed(
    st: float, ct: float, sa: float, ca: float, sign: float, det: float, y: Vec3Like
) -> tuple[float, float, float]:
    """z with ``W_eta^T z = y`` in closed form (W's first column is (1, 0, 0); ``det`` = det W,
    non-zero): the body torque of a generalised torque, eq. 13's W^-T."""
    y1, y2, y3 = float(y[0]), float(y[1]), float(y[2])
    y3p = y3 + st * y1
    return y1, (ct * ca * y2 - sign * sa * y3p) / det, (ca * y3p - ct * sa * y2) / det


def _rows(eta, eta_dot, form):
    """W's rows w_r, their time derivatives w_r_dot, and g[r][k] = (dw_r/d eta_k) . eta_dot.

    With ``J = sum_r I_r w_r w_r^T`` (eq. 5 for a diagonal I) both J and the Coriolis term of
    eq. 14 reduce to a few scalar products, which is what makes them cheap enough for the
    physics step and the control loop.
    """
    index, sign = _angle_and_sign(form)
    theta = float(eta[1])
    a = float(eta[index])
    st, ct = math.sin(theta), math.cos(theta)
    sa, ca = math.sin(a), math.cos(a)
    theta_dot, psi_dot = float(eta_dot[1]), float(eta_dot[2])
    a_dot = float(eta_dot[index])
    rows = ((1.0, 0.0, -st), (0.0, ca, ct * sa), (0.0, sign * sa, ct * ca))
    rows_dot = (
        (0.0, 0.0, -ct * theta_dot),
        (0.0, -sa * a_dot, -st * sa * theta_dot + ct * ca * a_dot),
        (0.0, sign * ca * a_dot, -st * ca * theta_dot - ct * sa * a_dot),
    )
    # g[r][k]: only k = theta and k = the W angle (phi or psi) are non-zero
    g = [[0.0, 0.0, 0.0] for _ in range(3)]
    g[0][1] = -ct * psi_dot
    g[1][1] = -st * sa * psi_dot
    g[2][1] = -st * ca * psi_dot
    g[1][index] += -sa * theta_dot + ct * ca * psi_dot
    g[2][index] += sign * ca * theta_dot - ct * sa * psi_dot
    return rows, rows_dot, g, (st, ct, sa, ca, sign)


def generalized_inertia(eta: np.ndarray, inertia: np.ndarray, form: EulerRateForm = EulerRateForm.CASTILLO) -> np.ndarray:
    """J(eta) = W_eta^T I W_eta (eq. 5)."""
    w = euler_rate_matrix(eta, form)
    return w.T @ inertia @ w


def _coriolis(rows, rows_dot, g, eta_dot, moments) -> list[float]:
    e0, e1, e2 = float(eta_dot[0]), float(eta_dot[1]), float(eta_dot[2])
    out = [0.0, 0.0, 0.0]
    for r in range(3):
        i_r = moments[r]
        w, wd, gr = rows[r], rows_dot[r], g[r]
        omega = w[0] * e0 + w[1] * e1 + w[2] * e2
        wd_dot_eta = wd[0] * e0 + wd[1] * e1 + wd[2] * e2
        for k in range(3):
            out[k] += i_r * (wd[k] * omega + w[k] * wd_dot_eta - omega * gr[k])
    return out


def _moments(inertia: np.ndarray) -> tuple[float, float, float]:
    return float(inertia[0, 0]), float(inertia[1, 1]), float(inertia[2, 2])


def coriolis_vector(
    eta: np.ndarray, eta_dot: np.ndarray, inertia: np.ndarray, form: EulerRateForm = EulerRateForm.CASTILLO
) -> np.ndarray:
    """C(eta, eta_dot) eta_dot of eq. 14, computed from dJ/d eta (not assumed zero).

    ``C eta_dot = J_dot eta_dot - 1/2 d/d eta (eta_dot^T J eta_dot)`` with
    ``J_dot eta_dot = sum_r I_r (w_r_dot omega_r + w_r (w_r_dot . eta_dot))`` and
    ``1/2 d/d eta_k (eta_dot^T J eta_dot) = sum_r I_r omega_r g[r][k]``, omega_r = w_r . eta_dot.
    Only the diagonal of ``inertia`` is used (principal axes).
    """
    rows, rows_dot, g, _ = _rows(eta, eta_dot, form)
    return np.array(_coriolis(rows, rows_dot, g, eta_dot, _moments(inertia)))


def real_torques(
    eta: Vec3Like,
    eta_dot: Vec3Like,
    tau_tilde: Vec3Like,
    inertia: np.ndarray,
    form: EulerRateForm = EulerRateForm.CASTILLO,
) -> np.ndarray:
    """The generalised torques of eq. 16: ``tau = C(eta, eta_dot) eta_dot + J(eta) tau_tilde``."""
    index, sign = _angle_and_sign(form)
    theta, a = float(eta[1]), float(eta[index])
    return np.array(real_torques_terms(
        math.sin(theta), math.cos(theta), math.sin(a), math.cos(a), float(eta_dot[0]), float(eta_dot[1]),
        float(eta_dot[2]), float(tau_tilde[0]), float(tau_tilde[1]), float(tau_tilde[2]),
        float(inertia[0, 0]), float(inertia[1, 1]), float(inertia[2, 2]), index, sign,
    ))  # fmt: skip


def real_torques_terms(
    st: float, ct: float, sa: float, ca: float, d0: float, d1: float, d2: float, t0: float, t1: float, t2: float,
    i0: float, i1: float, i2: float, index: int, sign: float,
) -> tuple[float, float, float]:
    """Eq. 16, ``C(eta, eta_dot) eta_dot + J(eta) tau~``, on floats: ``real_torques`` given the sine
    and cosine of theta (``st``, ``ct``) and of the W_eta angle (``sa``, ``ca``), eta_dot
    (``d0..d2``), tau~ (``t0..t2``), the principal moments (``i0..i2``) and the form's terms
    (``index``: the angle, 0 phi or 2 psi; ``sign``; ``EULER_FORM_TERMS``).

    Written out, no arrays: the law's per-sample form, and what ``sitl_plant.dynamics.batch``
    compiles for eq. 16 at every physics step. The sums run in ``_rows``/``_coriolis``'s order
    (``coriolis_vector`` and ``generalized_inertia`` give the same to rounding)."""
    a_dot = d0 if index == 0 else d2
    theta_dot, psi_dot = d1, d2
    # rows w_r of W, their derivatives, and g[r][k] (``_rows``)
    w00, w01, w02 = 1.0, 0.0, -st
    w10, w11, w12 = 0.0, ca, ct * sa
    w20, w21, w22 = 0.0, sign * sa, ct * ca
    v00, v01, v02 = 0.0, 0.0, -ct * theta_dot
    v10, v11, v12 = 0.0, -sa * a_dot, -st * sa * theta_dot + ct * ca * a_dot
    v20, v21, v22 = 0.0, sign * ca * a_dot, -st * ca * theta_dot - ct * sa * a_dot
    g00, g01, g02 = 0.0, -ct * psi_dot, 0.0
    g10, g11, g12 = 0.0, -st * sa * psi_dot, 0.0
    g20, g21, g22 = 0.0, -st * ca * psi_dot, 0.0
    extra1 = -sa * theta_dot + ct * ca * psi_dot
    extra2 = sign * ca * theta_dot - ct * sa * psi_dot
    if index == 0:
        g10 += extra1
        g20 += extra2
    else:
        g12 += extra1
        g22 += extra2
    c0 = c1 = c2 = 0.0
    # r = 0, 1, 2 in the reference's order of accumulation
    om = w00 * d0 + w01 * d1 + w02 * d2
    wd = v00 * d0 + v01 * d1 + v02 * d2
    c0 += i0 * (v00 * om + w00 * wd - om * g00)
    c1 += i0 * (v01 * om + w01 * wd - om * g01)
    c2 += i0 * (v02 * om + w02 * wd - om * g02)
    om = w10 * d0 + w11 * d1 + w12 * d2
    wd = v10 * d0 + v11 * d1 + v12 * d2
    c0 += i1 * (v10 * om + w10 * wd - om * g10)
    c1 += i1 * (v11 * om + w11 * wd - om * g11)
    c2 += i1 * (v12 * om + w12 * wd - om * g12)
    om = w20 * d0 + w21 * d1 + w22 * d2
    wd = v20 * d0 + v21 * d1 + v22 * d2
    c0 += i2 * (v20 * om + w20 * wd - om * g20)
    c1 += i2 * (v21 * om + w21 * wd - om * g21)
    c2 += i2 * (v22 * om + w22 * wd - om * g22)
    s = i0 * (w00 * t0 + w01 * t1 + w02 * t2)
    c0 += s * w00
    c1 += s * w01
    c2 += s * w02
    s = i1 * (w10 * t0 + w11 * t1 + w12 * t2)
    c0 += s * w10
    c1 += s * w11
    c2 += s * w12
    s = i2 * (w20 * t0 + w21 * t1 + w22 * t2)
    c0 += s * w20
    c1 += s * w21
    c2 += s * w22
    return c0, c1, c2


def euler_acceleration(
    eta: np.ndarray,
    eta_dot: np.ndarray,
    tau: np.ndarray,
    inertia: np.ndarray,
    form: EulerRateForm = EulerRateForm.CASTILLO,
) -> np.ndarray:
    """eta_ddot from eq. 13: ``J^-1 (tau - C eta_dot) = W^-1 I^-1 W^-T (tau - C eta_dot)``.

    Raises ``ZeroDivisionError`` where W_eta is singular (theta = +-pi/2; psi = pi/4 for the
    printed eq. 4).
    """
    rows, rows_dot, g, (st, ct, sa, ca, sign) = _rows(eta, eta_dot, form)
    moments = _moments(inertia)
    c = _coriolis(rows, rows_dot, g, eta_dot, moments)
    y1, y2, y3 = float(tau[0]) - c[0], float(tau[1]) - c[1], float(tau[2]) - c[2]
    det = ct * (ca * ca - sign * sa * sa)  # det W
    z1, z2, z3 = _solve_w_transposed(st, ct, sa, ca, sign, det, (y1, y2, y3))  # body-axis torque
    b1, b2, b3 = z1 / moments[0], z2 / moments[1], z3 / moments[2]
    # eta_ddot = W^-1 b
    v2 = ct * (ca * b2 - sa * b3) / det
    v3 = (ca * b3 - sign * sa * b2) / det
    return np.array([b1 + st * v3, v2, v3])


def rotational_lagrangian(
    eta: np.ndarray, eta_dot: np.ndarray, inertia: np.ndarray, form: EulerRateForm = EulerRateForm.CASTILLO
) -> float:
    """T_rot = 1/2 eta_dot^T J eta_dot (eq. 6), for tests of eq. 14 from first principles."""
    return 0.5 * float(eta_dot @ generalized_inertia(eta, inertia, form) @ eta_dot)


# --- eq. 3 solved: Euler-angle rates of body rates, body torque of a generalised torque -------------


def body_rates_from_euler_rates(euler_rad: Vec3Like, euler_rate_rad_s: Vec3Like, form: EulerRateForm) -> np.ndarray:
    """omega = W_eta eta_dot (eq. 3), W_eta in ``form``'s terms (module docstring)."""
    st, ct, sa, ca, k = _w_terms(euler_rad, form)
    d_phi, d_theta, d_psi = float(euler_rate_rad_s[0]), float(euler_rate_rad_s[1]), float(euler_rate_rad_s[2])
    return np.array((d_phi - st * d_psi, ca * d_theta + ct * sa * d_psi, k * sa * d_theta + ct * ca * d_psi))


def euler_rates_from_body_rates(euler_rad: np.ndarray, body_rate_frd_rad_s: np.ndarray, form: EulerRateForm) -> np.ndarray:
    """eta_dot = W_eta^-1 omega (eq. 3), solved in closed form (W's first column is (1, 0, 0)).

    With W = [[1, 0, -s_theta], [0, c_a, c_theta s_a], [0, k s_a, c_theta c_a]] (eq. 4, ``a`` and
    ``k`` set by ``form``) the lower 2x2 block gives the pitch and yaw rates and the first row the
    roll rate. Raises ``numpy.linalg.LinAlgError`` where W is singular, as ``numpy.linalg.solve``.
    """
    st, ct, sa, ca, k = _w_terms(euler_rad, form)
    p, q, r = float(body_rate_frd_rad_s[0]), float(body_rate_frd_rad_s[1]), float(body_rate_frd_rad_s[2])
    ct_sa, k_sa, ct_ca = ct * sa, k * sa, ct * ca
    det = ca * ct_ca - ct_sa * k_sa
    if det == 0.0:
        raise np.linalg.LinAlgError(f"W_eta ({form}) is singular at the Euler angles {tuple(euler_rad)}")
    theta_dot = (ct_ca * q - ct_sa * r) / det
    psi_dot = (ca * r - k_sa * q) / det
    return np.array((p + st * psi_dot, theta_dot, psi_dot))


def body_torque_from_generalized(tau_generalized_nm: np.ndarray, euler_rad: np.ndarray, form: EulerRateForm) -> np.ndarray:
    """Body FRD torque that exerts a generalised torque: ``solve(W_eta^T, tau_gen)`` in closed form.

    By virtual work ``tau_body . omega = tau_gen . eta_dot`` with ``omega = W_eta eta_dot``
    (eq. 3), so ``tau_gen = W_eta^T tau_body``.
    """
    st, ct, sa, ca, k = _w_terms(euler_rad, form)
    det = ct * (ca * ca - k * sa * sa)  # det W
    if det == 0.0:
        raise np.linalg.LinAlgError(f"W_eta ({form}) is singular at the Euler angles {tuple(euler_rad)}")
    return np.array(_solve_w_transposed(st, ct, sa, ca, k, det, tau_generalized_nm))


def zyx_euler_rates_from_body_rates(euler_rad: np.ndarray, body_rate_frd_rad_s: np.ndarray) -> np.ndarray:
    """ZYX Euler-angle rates from body rates: ``W_zyx^-1 omega`` (singular at pitch +-90 deg).

    ``euler_rates_from_body_rates(euler, omega, "zyx")`` in closed form, for the physics step: the
    same map (they agree to rounding, ~1e-16 relative), written with tan theta.
    """
    p, q, r = (float(v) for v in body_rate_frd_rad_s)
    return np.array(zyx_euler_rates_terms(float(euler_rad[0]), float(euler_rad[1]), p, q, r))


def zyx_euler_rates_terms(roll: float, pitch: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """``zyx_euler_rates_from_body_rates`` on floats: the ZYX Euler rates of the body rates (p, q, r)."""
    sr, cr = math.sin(roll), math.cos(roll)
    cp, tp = math.cos(pitch), math.tan(pitch)
    vertical = q * sr + r * cr
    return p + vertical * tp, q * cr - r * sr, vertical / cp


def zyx_body_torque_from_generalized(euler_rad: np.ndarray, tau_generalized: np.ndarray) -> np.ndarray:
    """Body FRD torque that exerts the generalised torque ``tau`` on the ZYX Euler angles.

    With ``omega = W_zyx eta_dot`` the virtual work is ``tau_body . W_zyx d eta``, so the
    generalised torque of eq. 13 is ``W_zyx^T tau_body``; this solves ``W_zyx^T tau_body = tau``:
    ``body_torque_from_generalized(tau, euler, "zyx")`` in closed form, for the physics step.
    """
    sr, cr = math.sin(euler_rad[0]), math.cos(euler_rad[0])
    sp, cp = math.sin(euler_rad[1]), math.cos(euler_rad[1])
    t1, t2, t3 = (float(v) for v in tau_generalized)
    # rows of W^T: (1, 0, 0), (0, cr, -sr), (-sp, cp sr, cp cr)
    vertical = (t3 + sp * t1) / cp  # = sr tau_y + cr tau_z
    return np.array([t1, cr * t2 + sr * vertical, -sr * t2 + cr * vertical])
