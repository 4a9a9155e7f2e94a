"""Identification by nonlinear least squares with parameter covariance and an
identifiability check, on top of scipy.optimize.least_squares."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.parameters import ParameterSet


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    parameters : ParameterSet
        Estimated parameters (fixed ones unchanged).
    std_devs : dict
        1-sigma standard deviation of each free parameter, in its unit, from the
        Jacobian at the solution scaled by the residual variance.
    covariance : ndarray, shape (n_free, n_free)
    residuals : ndarray, shape (n_residuals,)
        Residuals at the solution, in the residual function's unit.
    condition_number : float
        Of the column-scaled Jacobian; large values mean nearly dependent parameters.
    """

    parameters: ParameterSet
    std_devs: dict
    covariance: np.ndarray
    residuals: np.ndarray
    condition_number: float

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals ** 2)))


def check_identifiability(jacobian: np.ndarray, names: list[str],
                           max_condition: float = 1e10) -> float:
    """Condition number of the column-scaled Jacobian (shape (n_residuals, n_free)).

    Raises
    ------
    CalibrationError
        Naming the parameter(s) no measurement moves, or the pair the data cannot
        separate (the largest components of the weakest singular direction).
    """
    scale = np.linalg.norm(jacobian, axis=0)
    dead = [n for n, s in zip(names, scale) if s == 0]
    if dead:
        raise CalibrationError(f'the data do not depend on parameter(s) {", ".join(dead)}: '
                               'no measurement moves them')
    _, singular, vt = np.linalg.svd(jacobian / scale, full_matrices=False)
    condition = float(singular[0] / max(singular[-1], 1e-300))
    if condition > max_condition:
        weakest = np.argsort(-np.abs(vt[-1]))[:2]
        raise CalibrationError(
            'the data cannot separate parameters '
            f'{" and ".join(names[i] for i in weakest)} (condition number {condition:.3g}); '
            'add measurements that move them differently')
    return condition


def fit(residual_fn: Callable[[ParameterSet], np.ndarray], initial: ParameterSet,
        max_condition: float = 1e10,
        jacobian_fn: Callable[[ParameterSet], np.ndarray] | None = None) -> FitResult:
    """Minimise the sum of squares of ``residual_fn(parameters)`` over the free parameters.

    ``jacobian_fn(parameters)``, if given, returns the derivative of the residuals with
    respect to the free parameters, shape (n_residuals, n_free); otherwise scipy
    differentiates numerically.

    Raises
    ------
    CalibrationError
        If there are fewer residuals than free parameters, or the data cannot separate a
        parameter (the message names it), or residuals are not finite.
    """
    x0 = initial.free_vector()
    names = initial.free_names

    def fun(x):
        r = np.asarray(residual_fn(initial.with_free_vector(x)), dtype=float).ravel()
        return r

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise InvalidInputError('residuals are not finite at the initial parameters '
                                '(NaN or infinite values in the data?)')
    if r0.size < x0.size:
        raise CalibrationError(f'{r0.size} residuals cannot determine {x0.size} parameters '
                               f'({", ".join(names)})')
    derivative = '2-point' if jacobian_fn is None else (
        lambda x: np.asarray(jacobian_fn(initial.with_free_vector(x)), dtype=float))
    solution = least_squares(fun, x0, jac=derivative, method='trf', x_scale='jac')
    jac = solution.jac
    condition = check_identifiability(jac, names, max_condition)
    residuals = solution.fun
    dof = max(residuals.size - x0.size, 1)
    sigma2 = float(residuals @ residuals) / dof
    cov = np.linalg.pinv(jac.T @ jac) * sigma2
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    return FitResult(parameters=initial.with_free_vector(solution.x),
                     std_devs=dict(zip(names, std.tolist())), covariance=cov,
                     residuals=residuals, condition_number=condition)


def batched_levenberg_marquardt(model, observed, valid, x, tolerance, max_iterations=100):
    """Least squares of ``model(x) - observed`` by Levenberg-Marquardt (Marquardt's
    diagonal scaling), for a stack of independent problems solved side by side.

    scipy.optimize.least_squares solves one problem per call, and its fixed cost per
    call (argument checks, MINPACK's QR of the full n x p Jacobian) was most of the
    detector's time; here every step solves the p x p normal equations of all problems
    at once. Each problem keeps its own damping and stops on its own: when the cost
    fell by less than ``tolerance`` relatively, the step, scaled by the Jacobian's
    column norms as MINPACK does, is below ``tolerance`` of x, or the residual is
    orthogonal to the Jacobian.

    Parameters
    ----------
    model : callable
        ``model(x, rows)`` returns the values (k, n) and the Jacobian (k, p, n) of the
        problems ``rows`` (k,) at their parameters ``x`` (k, p).
    observed : ndarray, shape (m, n)
    valid : ndarray of bool, shape (m, n)
        False on the padding that brings every problem to n values.
    x : ndarray, shape (m, p)
        Starting parameters.
    tolerance : ndarray, shape (m,)

    Returns
    -------
    x : ndarray, shape (m, p)
    residuals : ndarray, shape (m, n)
        Zero on the padding.
    normal : ndarray, shape (m, p, p)
        The normal matrix J^T J at x.
    converged : ndarray of bool, shape (m,)
    """
    weight = valid.astype(np.float64)

    def evaluate(x, rows):
        """Residuals, normal matrices, gradients J^T r and costs of the problems ``rows``
        at ``x``; the Jacobians themselves are not kept, to save copying them."""
        # A diverging trial overflows; its cost is then not finite and the step refused.
        with np.errstate(over='ignore', invalid='ignore'):
            values, jac = model(x, rows)
            residuals = values - observed[rows]
            residuals *= weight[rows]
            jac *= weight[rows, None, :]
            return (residuals, jac @ jac.transpose(0, 2, 1), (jac @ residuals[..., None])[..., 0],
                    np.einsum('mn,mn->m', residuals, residuals))

    x = x.copy()
    residuals, normal, gradient, cost = evaluate(x, np.arange(len(x)))
    damping = np.full(len(x), 1e-3)
    steps = np.zeros(len(x), dtype=int)
    converged = np.zeros(len(x), dtype=bool)
    active = np.ones(len(x), dtype=bool)
    diagonal = np.eye(x.shape[1], dtype=bool)
    while active.any():
        rows = np.flatnonzero(active)
        scale = np.maximum(normal[rows][:, diagonal], 1e-300)
        # At the optimum the residual is orthogonal to every Jacobian column (MINPACK's
        # gtol); checked first, because there rounding may keep any step from lowering
        # the cost.
        orthogonal = (np.max(np.abs(gradient[rows]) / np.sqrt(scale), axis=1)
                      <= 1e-10 * np.sqrt(np.maximum(cost[rows], 1e-300)))
        converged[rows[orthogonal]] = True
        active[rows[orthogonal]] = False
        rows, scale = rows[~orthogonal], scale[~orthogonal]
        if not rows.size:
            break
        damped = normal[rows]
        damped[:, diagonal] += damping[rows, None] * scale
        try:
            step = np.linalg.solve(damped, -gradient[rows][..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -(np.linalg.pinv(damped) @ gradient[rows][..., None])[..., 0]
        finite = np.all(np.isfinite(step), axis=1)
        trial = x[rows] + np.where(finite[:, None], step, 0.0)
        residuals_new, normal_new, gradient_new, cost_new = evaluate(trial, rows)
        better = finite & (cost_new <= cost[rows])
        # A step that raised the cost is tried again, shorter, from the same point.
        worse = rows[~better]
        damping[worse] *= 10.0
        active[worse[damping[worse] > 1e12]] = False
        taken = rows[better]
        decrease = cost[taken] - cost_new[better]
        column = np.sqrt(scale[better])
        x[taken], residuals[taken], normal[taken], gradient[taken], cost[taken] = (
            trial[better], residuals_new[better], normal_new[better], gradient_new[better],
            cost_new[better])
        damping[taken] = np.maximum(damping[taken] * 0.1, 1e-12)
        steps[taken] += 1
        small = ((decrease <= tolerance[taken] * cost[taken])
                 | (np.linalg.norm(column * step[better], axis=1)
                    <= tolerance[taken] * np.linalg.norm(column * x[taken], axis=1)))
        converged[taken[small]] = True
        active[taken[small | (steps[taken] >= max_iterations)]] = False
    return x, residuals, normal, converged
