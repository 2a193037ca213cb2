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

import numpy as np

_FORM = {"castillo": (2, -1.0), "printed": (2, 1.0), "zyx": (0, -1.0)}


def _angle_and_sign(form: str) -> tuple[int, float]:
    try:
        return _FORM[form]
    except KeyError:
        raise ValueError(f"unknown Euler-rate form {form!r}; expected one of {sorted(_FORM)}") from None


def euler_rate_matrix(eta: np.ndarray, form: str = "castillo") -> np.ndarray:
    """W_eta of eq. 4: body angular velocity ``omega = W_eta @ eta_dot`` (eq. 3)."""
    index, sign = _angle_and_sign(form)
    theta = eta[1]
    a = eta[index]
    st, ct = np.sin(theta), np.cos(theta)
    sa, ca = np.sin(a), np.cos(a)
    return np.array([[1.0, 0.0, -st], [0.0, ca, ct * sa], [0.0, sign * sa, ct * ca]])


def euler_rate_matrix_partials(eta: np.ndarray, form: str = "castillo") -> np.ndarray:
    """dW/d eta_k for k = phi, theta, psi, stacked as shape (3, 3, 3) [k, row, col]."""
    index, sign = _angle_and_sign(form)
    theta = eta[1]
    a = eta[index]
    st, ct = np.sin(theta), np.cos(theta)
    sa, ca = np.sin(a), np.cos(a)
    partials = np.zeros((3, 3, 3))
    partials[1] = [[0.0, 0.0, -ct], [0.0, 0.0, -st * sa], [0.0, 0.0, -st * ca]]
    partials[index] += [[0.0, 0.0, 0.0], [0.0, -sa, ct * ca], [0.0, sign * ca, -ct * sa]]
    return partials


def generalized_inertia(eta: np.ndarray, inertia: np.ndarray, form: str = "castillo") -> np.ndarray:
    """J(eta) = W_eta^T I W_eta (eq. 5)."""
    w = euler_rate_matrix(eta, form)
    return w.T @ inertia @ w


def coriolis_vector(
    eta: np.ndarray, eta_dot: np.ndarray, inertia: np.ndarray, form: str = "castillo"
) -> np.ndarray:
    """C(eta, eta_dot) eta_dot of eq. 14, computed from dJ/d eta (not assumed zero)."""
    w = euler_rate_matrix(eta, form)
    dw = euler_rate_matrix_partials(eta, form)
    iw = inertia @ w
    # dJ/d eta_k = dW_k^T I W + W^T I dW_k, shape (3, 3, 3)
    dj = np.einsum("kji,jl->kil", dw, iw)
    dj = dj + np.transpose(dj, (0, 2, 1))
    j_dot = np.einsum("kil,k->il", dj, eta_dot)
    grad = 0.5 * np.einsum("i,kil,l->k", eta_dot, dj, eta_dot)
    return j_dot @ eta_dot - grad


def real_torques(
    eta: np.ndarray,
    eta_dot: np.ndarray,
    tau_tilde: np.ndarray,
    inertia: np.ndarray,
    form: str = "castillo",
) -> np.ndarray:
    """The generalised torques of eq. 16: ``tau = C(eta, eta_dot) eta_dot + J(eta) tau_tilde``."""
    return coriolis_vector(eta, eta_dot, inertia, form) + generalized_inertia(eta, inertia, form) @ tau_tilde


def euler_acceleration(
    eta: np.ndarray,
    eta_dot: np.ndarray,
    tau: np.ndarray,
    inertia: np.ndarray,
    form: str = "castillo",
) -> np.ndarray:
    """eta_ddot from eq. 13: ``J^-1 (tau - C eta_dot)``."""
    j = generalized_inertia(eta, inertia, form)
    return np.linalg.solve(j, tau - coriolis_vector(eta, eta_dot, inertia, form))


def rotational_lagrangian(eta: np.ndarray, eta_dot: np.ndarray, inertia: np.ndarray, form: str = "castillo") -> float:
    """T_rot = 1/2 eta_dot^T J eta_dot (eq. 6), for tests of eq. 14 from first principles."""
    return 0.5 * float(eta_dot @ generalized_inertia(eta, inertia, form) @ eta_dot)
