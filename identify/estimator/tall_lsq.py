"""Levenberg–Marquardt on the normal equations, for tall least-squares problems (pure numpy).

A long continuous session gives the line fit and the DH refinement Jacobians of about a million residuals and
30 parameters. scipy's ``least_squares(method="lm")`` (MINPACK) factors each one with an unblocked Householder QR
after copying it to Fortran order: over a second per iteration at that size. Here each iteration forms JᵀJ and Jᵀr
with one BLAS product each and solves the damped p × p system, so the cost is the Jacobian's own.

The fixed point is the same: the iteration stops where the gradient Jᵀr, formed from the full Jacobian, has no
step left worth taking. Squaring the condition number only makes the steps less exact, not the optimum; the
eigen-decomposition of the scaled normal matrix treats directions below rounding as absent (a minimum-norm step).

Stopping rule, the statistical one of :func:`identify.estimator.poe.converged_tolerance`: a step is the last when it
moves the parameters by less than ``STOP_SIGMAS`` standard deviations, ``Δxᵀ JᵀJ Δx ≤ STOP_SIGMAS² s²`` with ``s²`` the
residuals' variance per degree of freedom; such a step is taken without another evaluation (the linear model is
exact to far below it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

TALL_ENTRIES = 5_000_000  # Jacobian entries (40 MB) from which the normal equations replace MINPACK's QR
EIGEN_FLOOR = 1e-15  # relative eigenvalue of the scaled normal matrix below which a direction counts as absent


def is_tall(residuals: int, parameters: int) -> bool:
    """Whether a problem of this size is solved here rather than by MINPACK."""
    return residuals * parameters >= TALL_ENTRIES


def _damped_steps(normal: Array, gradient: Array) -> Callable[[float], Array]:
    """The map damping -> the step s minimising ‖J s + r‖² + damping ‖s‖², from the (scaled) normal matrix JᵀJ and
    gradient Jᵀr: one eigen-decomposition serves every damping."""
    values, vectors = np.linalg.eigh(normal)
    values = np.maximum(values, 0.0)
    present = values > EIGEN_FLOOR * values[-1]
    along = vectors[:, present].T @ gradient

    def step(damping: float) -> Array:
        return -vectors[:, present] @ (along / (values[present] + damping))
    return step


def solve_tall(fun: Callable[[Array], Array], jac: Callable[[Array], Array], x0: Array, stop_sigmas: float,
               max_jacobians: int = 100) -> Array:
    """Least-squares minimum of ``‖fun(x)‖²`` from ``x0``; ``jac(x)`` (M, p) is the Jacobian of ``fun(x)`` (M,).

    Levenberg–Marquardt with the columns scaled to unit norm (scipy's ``x_scale="jac"``), pure Gauss–Newton steps
    while they lower the cost, the damping rule of Nielsen (1999) when they do not. Stops as the module docstring
    says, or after ``max_jacobians`` Jacobians."""
    x = np.array(x0, dtype=float)
    r = fun(x)
    cost = float(r @ r)
    dof = max(len(r) - len(x), 1)
    damping, growth = 0.0, 2.0
    for _ in range(max_jacobians):
        j = jac(x)
        normal, gradient = j.T @ j, j.T @ r
        del j
        scale = np.sqrt(np.maximum(np.diag(normal), 1e-300))
        steps = _damped_steps(normal / np.outer(scale, scale), gradient / scale)
        newton = steps(0.0) / scale
        if float(newton @ normal @ newton) <= stop_sigmas**2 * cost / dof:  # ‖J Δx‖² against s²
            return x + newton
        while True:
            step = newton if damping == 0.0 else steps(damping) / scale
            predicted = -(2.0 * float(gradient @ step) + float(step @ normal @ step))  # the linear model's decrease
            trial = fun(x + step)
            trial_cost = float(trial @ trial)
            ratio = (cost - trial_cost) / predicted if predicted > 0 else -1.0
            if ratio > 1e-4:
                x, r, cost = x + step, trial, trial_cost
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                growth = 2.0
                break
            damping = 1e-3 if damping == 0.0 else damping * growth
            growth *= 2.0
            if damping > 1e12:  # no step lowers the cost: at the minimum to rounding
                return x
    return x
