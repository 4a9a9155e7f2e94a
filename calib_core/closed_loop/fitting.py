"""Fitting a machine's base model jointly with a set of effects, evaluating it on other
rows, hold-out splits and K-fold cross-validation."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import sparse
from scipy.linalg import cho_solve

from calib_core.errors import InvalidInputError, MachineAlignmentError
from calib_core.parameters import ParameterSet
from calib_core.closed_loop.model import MachineModel


@dataclass
class Fit:
    base: ParameterSet
    effects: list
    values: list          # one array per effect
    residuals: np.ndarray  # (n, k) on the rows fitted
    jacobian: np.ndarray

    @property
    def rss(self) -> float:
        return float(np.sum(self.residuals ** 2))

    @cached_property
    def rank(self) -> int:
        """Numerical rank of the Jacobian with its columns scaled to unit norm: its singular
        values over 1e-8 of the largest (one SVD, once per fit: the current model's rank is
        asked for every candidate tried against it)."""
        norms = np.linalg.norm(self.jacobian, axis=0)
        scaled = self.jacobian[:, norms > 0] / norms[norms > 0]
        if scaled.size == 0:
            return 0
        singular = np.linalg.svd(scaled, compute_uv=False)
        return int(np.count_nonzero(singular > 1e-8 * singular[0]))

    @property
    def parameter_count(self) -> int:
        return len(self.base.free_names) + sum(len(v) for v in self.values)

    def covariance(self, noise_variance: float | None = None) -> np.ndarray:
        """Parameter covariance; the noise variance defaults to the residuals'."""
        if noise_variance is None:
            noise_variance = self.rss / max(self.residuals.size - self.parameter_count, 1)
        return np.linalg.pinv(self.jacobian.T @ self.jacobian) * noise_variance

    def std_devs(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance()), 0, None))

    def effect_slice(self, k: int) -> slice:
        """Where effect ``k``'s parameters sit in the fit's vector."""
        start = len(self.base.free_names) + sum(len(v) for v in self.values[:k])
        return slice(start, start + len(self.values[k]))

    def names(self) -> list:
        return [e.effect.name for e in self.effects]


def _delta(machine, effects, values, context, count) -> np.ndarray:
    delta = np.zeros((count, len(machine.channels)))
    for effect, v in zip(effects, values):
        delta = delta + effect.term(v, context)
    return delta


def model_residuals(machine: MachineModel, base: ParameterSet, effects: list, values: list,
               rows: np.ndarray, in_channels: bool = False) -> np.ndarray:
    """Residuals of the base model plus ``effects`` on ``rows``: (n, k), or (n, C)
    expressed in the channels."""
    context = machine.context(base, rows)
    delta = _delta(machine, effects, values, context, len(rows))
    method = machine.channel_residuals if in_channels else machine.residuals
    return method(base, delta, rows, context)


def evaluate(machine: MachineModel, fit: Fit, rows: np.ndarray) -> np.ndarray:
    """Residuals (n, k) of a fitted model on any rows."""
    return model_residuals(machine, fit.base, fit.effects, fit.values, rows)


def refit(machine: MachineModel, fit: Fit, rows: np.ndarray, effects: bool = True) -> Fit:
    """``fit``'s model (its base and, with ``effects``, its effects) fitted again on ``rows``."""
    if effects:
        return fit_model(machine, fit.base, fit.effects, fit.values, rows)
    return fit_model(machine, machine.initial(), [], [], rows)


def residuals_by_channel(machine, fit: Fit, rows) -> np.ndarray:
    return model_residuals(machine, fit.base, fit.effects, fit.values, rows, in_channels=True)


SPARSE_ABOVE_COLUMNS = 150
"""A Jacobian of more columns than this whose pattern is at most SPARSE_DENSITY full is
handed over as a sparse matrix, whose normal equations cost what its nonzeros do: a
camera of 60 views (364 parameters) had spent 10 of its loop's 22 s forming dense ones."""
SPARSE_DENSITY = 0.25


def grouped_differences(fun, sparsity: np.ndarray):
    """A Jacobian callable for ``fun`` by forward differences, stepping together the
    columns whose nonzero rows (``sparsity``, (m, n) bool) do not overlap (Curtis, Powell and
    Reid's grouping, greedy). Each step is solved exactly (normal equations or SVD), which
    converges in far fewer iterations than an iterative sparse solver (LSMR) on the
    camera's few hundred parameters; the Jacobian is dense, or a scipy.sparse CSR matrix
    where it is large and mostly empty (SPARSE_ABOVE_COLUMNS, SPARSE_DENSITY). The
    caller may pass ``f0``, the residuals at x it already has."""
    sparsity = np.asarray(sparsity, bool)
    count = sparsity.shape[1]
    # Columns that share a row cannot be stepped together (the product taken sparse: a
    # camera's pattern is mostly empty).
    pattern = sparse.csc_matrix(sparsity, dtype=np.float32)
    overlap = (pattern.T @ pattern).toarray() > 0
    conflicts = np.zeros((0, count), bool)     # per group: the columns it cannot take
    group_of = np.empty(count, int)
    for column in range(count):
        free = np.flatnonzero(~conflicts[:, column])
        if free.size:
            group_of[column] = free[0]
            conflicts[free[0]] |= overlap[column]
        else:
            group_of[column] = len(conflicts)
            conflicts = np.vstack([conflicts, overlap[column]])
    # Per group, the (row, column) entries it fills, in one index each.
    entries = []
    for group in range(len(conflicts)):
        members = np.flatnonzero(group_of == group)
        rows, columns = np.nonzero(sparsity[:, members])
        entries.append((members, rows, members[columns]))
    shape = sparsity.shape
    as_sparse = (count > SPARSE_ABOVE_COLUMNS
                 and np.count_nonzero(sparsity) <= SPARSE_DENSITY * sparsity.size)
    if as_sparse:
        # The entries in the order of a CSR matrix's, once: each Jacobian then only fills
        # its values.
        every_row = np.concatenate([rows for _, rows, _ in entries])
        every_column = np.concatenate([columns for _, _, columns in entries])
        order = np.lexsort((every_column, every_row))
        indptr = np.searchsorted(every_row[order], np.arange(shape[0] + 1))
        indices = every_column[order]

    def jacobian(x, f0=None):
        f0 = fun(x) if f0 is None else f0
        # The step scipy's '2-point' takes: sqrt(machine epsilon) relative, at least absolute.
        step = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x))
        values = []
        for members, rows, columns in entries:
            moved = x.copy()
            moved[members] += step[members]
            change = fun(moved) - f0
            values.append(change[rows] / (moved - x)[columns])
        if as_sparse:
            return sparse.csr_matrix((np.concatenate(values)[order], indices, indptr), shape)
        out = np.zeros(shape)
        for (_, rows, columns), value in zip(entries, values):
            out[rows, columns] = value
        return out
    return jacobian


def fit_model(machine: MachineModel, base: ParameterSet, effects: list, values: list,
         rows: np.ndarray) -> Fit:
    """Joint least squares of the base model and ``effects`` on ``rows``."""
    sizes = [len(v) for v in values]
    nb = len(base.free_names)
    start = np.concatenate([base.free_vector()] + [np.asarray(v, float) for v in values])
    free = np.ones(len(start), bool)
    if any(e.determined is not None for e in effects):
        context, offset = machine.context(base, rows), nb
        for effect, size in zip(effects, sizes):
            if effect.determined is not None:
                free[offset:offset + size] = effect.determined(context)
            offset += size
    x0 = start[free]

    def unpack(x):
        full = start.copy()
        full[free] = x
        parts, offset = [], nb
        for s in sizes:
            parts.append(full[offset:offset + s])
            offset += s
        return base.with_free_vector(full[:nb]), parts

    # A linearised machine's context does not depend on the base, and its Jacobian is a
    # product of stored matrices: no finite differences over the machine.
    analytic = hasattr(machine, 'jacobian')
    fixed_context = machine.context(base, rows) if analytic else None

    def fun(x):
        b, parts = unpack(x)
        if not analytic:
            return model_residuals(machine, b, effects, parts, rows).ravel()
        delta = _delta(machine, effects, parts, fixed_context, len(rows))
        return machine.residuals(b, delta, rows, fixed_context).ravel()

    def analytic_jacobian(x, f0=None):
        _, parts = unpack(x)
        return machine.jacobian(effects, parts, rows, fixed_context)[:, free]

    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise InvalidInputError('residuals are not finite (NaN or infinite values in the data?)')
    if analytic:
        jac = analytic_jacobian
    else:
        # Effects may touch every residual; the base's pattern, where the machine gives
        # one, groups its differences.
        sparsity = machine.base_sparsity(base, rows)
        if sparsity is None:
            sparsity = np.ones((len(r0), nb), bool)
        dense = np.ones((sparsity.shape[0], len(start) - nb), bool)
        jac = grouped_differences(fun, np.hstack([sparsity, dense])[:, free])
    solved = _gauss_newton(fun, jac, x0, r0)
    if solved is None:
        # Imported here: scipy.optimize costs 0.4 s, and a command's --help should not wait.
        from scipy.optimize import least_squares
        solution = least_squares(fun, x0, jac=jac, method='trf', x_scale='jac')
        solved = solution.x, solution.fun, solution.jac
    x, residuals, solved_jacobian = solved
    if sparse.issparse(solved_jacobian):
        solved_jacobian = solved_jacobian.toarray()
    b, parts = unpack(x)
    # Held parameters get zero columns: the rows say nothing about them.
    jacobian = np.zeros((solved_jacobian.shape[0], len(start)))
    jacobian[:, free] = solved_jacobian
    return Fit(b, list(effects), parts, residuals.reshape(len(rows), -1), jacobian)


GAUSS_NEWTON_ITERATIONS = 30
"""Gauss-Newton steps tried before the trust-region solver takes over."""
GAUSS_NEWTON_HALVINGS = 4
"""Times a step that raises the sum of squares is halved before the trust region takes over."""
GAUSS_NEWTON_TOLERANCE = 1e-10
"""Relative fall of the sum of squares below which a full step has converged."""


def _gauss_newton(fun, jac, x0: np.ndarray, r0: np.ndarray):
    """Gauss-Newton steps from ``x0`` (``jac(x, f0)``: the Jacobian at x, given
    fun(x) = f0): the loop's fits are linear in every parameter but an effect's period or a
    rigid body's angles, and start at or next to their solution, so most settle in two to
    four steps, each a fraction of a trust-region step's cost (:func:`_gauss_newton_step`).
    A step that raises the sum of squares is halved (a period far from its best value
    bends the valley), up to GAUSS_NEWTON_HALVINGS times.

    Returns (x, residuals, Jacobian at the last step) once a full step lowers the sum of
    squares by less than GAUSS_NEWTON_TOLERANCE of it, or two full steps' falls, shrinking
    by their ratio, predict the next one below it (a camera without its distortion in
    the model settled in 6 steps, now 5, to the same printed digits); or None when no
    halving of a step lowers it, a step lands where the machine cannot be evaluated (a
    camera point behind the lens) or the steps do not settle: the caller then solves with
    a trust region."""
    x, r = x0, r0
    cost = float(r @ r)
    last_fall = None     # the previous full step's fall of the sum of squares
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        J = jac(x, r)
        step = _gauss_newton_step(J, r)
        for halving in range(GAUSS_NEWTON_HALVINGS + 1):
            moved = x + step
            try:
                r_moved = fun(moved)
            except (MachineAlignmentError, ArithmeticError, np.linalg.LinAlgError):
                return None
            cost_moved = float(r_moved @ r_moved)
            if np.isfinite(cost_moved) and cost_moved <= cost * (1 + GAUSS_NEWTON_TOLERANCE):
                break
            step = step / 2
        else:
            return None
        # Only a full step's small fall says the minimum is reached; a halved one may be
        # small because the step was cut.
        fall = cost - cost_moved
        # Where the model bends (a large residual), the steps' falls shrink by a steady
        # ratio: two full steps' falls predict the next one's, and a predicted fall below
        # the tolerance spares the step that would only confirm it.
        settled = halving == 0 and (
            fall <= GAUSS_NEWTON_TOLERANCE * cost
            or (last_fall is not None
                and fall * fall <= GAUSS_NEWTON_TOLERANCE * cost * last_fall))
        last_fall = fall if halving == 0 else None
        x, r, cost = moved, r_moved, cost_moved
        if settled:
            return x, r, J
    return None


def _gauss_newton_step(J, r: np.ndarray) -> np.ndarray:
    """The step minimising |J step + r| (J dense, or scipy.sparse whose normal equations
    are formed sparse), on the columns scaled to unit norm: by the normal
    equations' Cholesky factor (a tenth of an SVD's time on the camera's 1500 x 130) where
    the factor's diagonal shows no nearly dependent columns (its smallest at least 1e-6 of
    its largest), else by an SVD (the minimum-norm step, which leaves a gauge's free
    direction alone). An inexact step costs an iteration, not accuracy: the steps stop
    where the gradient vanishes, whatever solved them."""
    if sparse.issparse(J):
        scale = np.sqrt(np.asarray(J.multiply(J).sum(axis=0)).ravel())
        scale[scale == 0] = 1.0
        scaled = J @ sparse.diags(1.0 / scale)
        normal = (scaled.T @ scaled).toarray()
    else:
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        scaled = J / scale
        normal = scaled.T @ scaled
    try:
        factor = np.linalg.cholesky(normal)
    except np.linalg.LinAlgError:
        factor = None
    if factor is not None and np.min(np.diag(factor)) > 1e-6 * np.max(np.diag(factor)):
        gradient = scaled.T @ r
        step = -cho_solve((factor, True), gradient, check_finite=False)
    else:
        dense = scaled.toarray() if sparse.issparse(scaled) else scaled
        step = np.linalg.lstsq(dense, -r, rcond=None)[0]
    return step / scale


def without_effects(fit: Fit, names) -> tuple[list, list]:
    """``fit``'s effects and values, less those named."""
    kept = [k for k, e in enumerate(fit.effects) if e.effect.name not in names]
    return [fit.effects[k] for k in kept], [fit.values[k] for k in kept]


def holdout_split(labels: np.ndarray, parts: int, rng) -> np.ndarray:
    """A part number per row, balanced within each label."""
    out = np.empty(len(labels), dtype=int)
    for label in np.unique(labels):
        index = np.flatnonzero(labels == label)
        out[rng.permutation(index)] = np.arange(len(index)) % parts
    return out


def cross_validated_rms(machine, fit: Fit, rows, folds) -> float:
    """RMS of the residuals each fold gets from a model fitted to the other folds."""
    total, count = 0.0, 0
    for k in np.unique(folds):
        train, test = rows[folds != k], rows[folds == k]
        refit = fit_model(machine, fit.base, fit.effects, fit.values, train)
        r = evaluate(machine, refit, test)
        total += float(np.sum(r ** 2))
        count += r.size
    return float(np.sqrt(total / count))


def error_summary(machine, residuals: np.ndarray) -> dict:
    errors = machine.row_errors(residuals)
    return {'rms': float(np.sqrt(np.mean(errors ** 2))), 'max': float(np.max(errors))}


def heldout_errors(machine, splits: list, effects: list, values: list, start: Fit) -> dict:
    """Held-out errors over ``splits`` of the model with ``effects``, refitted on each
    split's fitting rows: ``sum_of_squares`` of the residuals, their ``count``, and per
    split the sum of squares (``sums``) and the largest row error (``maxima``)."""
    total, count, maxima, sums = 0.0, 0, [], []
    for split in splits:
        fit = fit_model(machine, start.base, effects, values, split.train)
        r = evaluate(machine, fit, np.flatnonzero(split.holdout))
        sums.append(float(np.sum(r ** 2)))
        total += sums[-1]
        count += r.size
        maxima.append(float(np.max(machine.row_errors(r))))
    return {'sum_of_squares': total, 'count': count, 'maxima': maxima, 'sums': sums}
