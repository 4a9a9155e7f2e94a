"""Identification by nonlinear least squares with parameter covariance and an
identifiability check, on top of scipy.optimize.least_squares."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

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
    # Imported here: scipy.optimize costs 0.4 s, and a command's --help should not wait.
    from scipy.optimize import least_squares
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
