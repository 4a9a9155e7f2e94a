"""The loop's fits (calib_core.closed_loop.fitting): Gauss-Newton steps that reach the
least-squares solution, and hand over to the trust region where a full step cannot be
taken."""
import numpy as np
import pytest

from calib_core.closed_loop.fitting import _gauss_newton, grouped_differences
from calib_core.errors import CalibrationError


def _linear_problem(seed: int):
    rng = np.random.default_rng(seed)
    design = rng.normal(size=(60, 5)) * np.array([1.0, 1e3, 1e-3, 10.0, 1.0])   # mixed units
    truth = rng.normal(size=5)
    observed = design @ truth + rng.normal(0.0, 1e-3, 60)
    return design, observed


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_linear_fit_settles_at_the_least_squares_solution(seed):
    design, observed = _linear_problem(seed)
    fun = lambda x: design @ x - observed                       # noqa: E731
    jac = lambda x, f0=None: design                             # noqa: E731
    x0 = np.zeros(5)
    x, r, J = _gauss_newton(fun, jac, x0, fun(x0))
    expected = np.linalg.lstsq(design, observed, rcond=None)[0]
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(J, design)


def test_a_large_mostly_empty_jacobian_is_sparse_and_solves_as_a_dense_one(monkeypatch):
    """200 blocks of 2 parameters, each seen by its own 6 rows, and 2 parameters every row
    sees (a camera's views and intrinsics): 402 columns, 2 % full. The Jacobian comes as a
    sparse matrix, and the fit lands where the dense route lands on the same problem (the
    sparse route off: SPARSE_ABOVE_COLUMNS beyond its columns), at the least-squares
    solution (to the forward differences' own error)."""
    from scipy import sparse
    from calib_core.closed_loop import fitting
    rng = np.random.default_rng(7)
    blocks = 200
    rows, columns = 6 * blocks, 2 * blocks + 2
    design = np.zeros((rows, columns))
    for k in range(blocks):
        design[6 * k:6 * k + 6, 2 * k:2 * k + 2] = rng.normal(size=(6, 2))
    design[:, -2:] = rng.normal(size=(rows, 2)) * [1e3, 1e-3]
    observed = design @ rng.normal(size=columns) + rng.normal(0.0, 1e-3, rows)
    fun = lambda x: design @ x - observed                       # noqa: E731
    x0 = np.zeros(columns)
    solved = {}
    for route, above in (('sparse', fitting.SPARSE_ABOVE_COLUMNS), ('dense', columns)):
        monkeypatch.setattr(fitting, 'SPARSE_ABOVE_COLUMNS', above)
        jac = grouped_differences(fun, design != 0)
        assert sparse.issparse(jac(x0)) == (route == 'sparse')
        x, _, J = _gauss_newton(fun, jac, x0, fun(x0))
        solved[route] = x, J.toarray() if sparse.issparse(J) else J
    # The design, to the forward differences' rounding (residuals of 1e3 over 1.5e-8 steps).
    np.testing.assert_allclose(solved['sparse'][1], design, atol=1e-4)
    # In each parameter's standard deviation: the same to the steps' stopping tolerance
    # (the normal equations summed in another order), at the least-squares solution.
    sigma = 1e-3 * np.sqrt(np.diag(np.linalg.inv(design.T @ design)))
    assert np.max(np.abs(solved['sparse'][0] - solved['dense'][0]) / sigma) < 1e-2
    expected = np.linalg.lstsq(design, observed, rcond=None)[0]
    assert np.max(np.abs(solved['sparse'][0] - expected) / sigma) < 1e-2


def test_a_nonlinear_fit_by_grouped_differences_settles_at_the_minimum():
    """A sinusoid's amplitude, phase and period, started near them: the steps settle where
    the gradient vanishes, the trust region's minimum."""
    from scipy.optimize import least_squares
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 10.0, 200)
    y = 1.3 * np.sin(2 * np.pi * t / 2.1 + 0.4) + rng.normal(0.0, 0.05, 200)
    fun = lambda p: p[0] * np.sin(2 * np.pi * t / p[2] + p[1]) - y     # noqa: E731
    x0 = np.array([1.0, 0.3, 2.08])
    jac = grouped_differences(fun, np.ones((200, 3), bool))
    x, r, _ = _gauss_newton(fun, jac, x0, fun(x0))
    tight = least_squares(fun, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(x, tight, rtol=1e-7)


def test_a_step_the_machine_cannot_evaluate_hands_over_to_the_trust_region():
    """A full step that lands where the residuals cannot be computed (as a camera point
    behind the lens raises) returns None: the caller solves with the trust region."""
    def fun(x):
        if abs(x[0]) > 2:
            raise CalibrationError('a target point lies behind the camera')
        return np.array([x[0] - 10.0, 0.1 * x[0]])
    jac = lambda x, f0=None: np.array([[1.0], [0.1]])          # noqa: E731
    x0 = np.zeros(1)
    assert _gauss_newton(fun, jac, x0, fun(x0)) is None


def test_a_step_that_raises_the_sum_of_squares_hands_over():
    """A wrong Jacobian (sign flipped) sends the full step uphill: None, not a worse fit."""
    fun = lambda x: x - 3.0                                     # noqa: E731
    jac = lambda x, f0=None: -np.eye(1)                        # noqa: E731
    x0 = np.zeros(1)
    assert _gauss_newton(fun, jac, x0, fun(x0)) is None


def test_a_step_that_overshoots_is_halved_until_it_lowers_the_sum_of_squares():
    """arctan from x = 2: the full Gauss-Newton step lands at -3.5, farther from the root
    than the start; halved, it falls, and the steps settle at the root."""
    fun = lambda x: np.arctan(x)                                # noqa: E731
    jac = lambda x, f0=None: np.array([[1.0 / (1.0 + x[0] ** 2)]])  # noqa: E731
    x0 = np.array([2.0])
    assert abs(np.arctan(x0[0] - (1 + 4) * np.arctan(2.0))) > abs(np.arctan(2.0))
    x, r, _ = _gauss_newton(fun, jac, x0, fun(x0))
    assert abs(x[0]) < 1e-6
