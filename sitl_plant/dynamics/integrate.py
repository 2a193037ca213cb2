"""Fixed-step integration, kept apart from the models it integrates."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def rk4_step(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, dt_s: float) -> np.ndarray:
    """One classical Runge-Kutta step of ``x_dot = f(x)`` with inputs held over the step."""
    k1 = f(x)
    k2 = f(x + 0.5 * dt_s * k1)
    k3 = f(x + 0.5 * dt_s * k2)
    k4 = f(x + dt_s * k3)
    return x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def steps_per_period(period_s: float, physics_dt_s: float) -> int:
    """The integer number of physics steps in a control period; refuses a non-integer ratio."""
    if physics_dt_s <= 0 or period_s <= 0:
        raise ValueError(f"periods must be > 0, got control {period_s} s and physics {physics_dt_s} s")
    ratio = period_s / physics_dt_s
    steps = round(ratio)
    if steps < 1 or abs(ratio - steps) > 1e-9 * max(1.0, ratio):
        raise ValueError(
            f"the control period ({period_s} s) must be an integer multiple of the physics step "
            f"({physics_dt_s} s); the ratio is {ratio:.6g}"
        )
    return steps
