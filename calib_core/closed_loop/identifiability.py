"""What the rows can determine: enough residuals for a model's parameter count, a
candidate's term against its own uncertainty and the Jacobian's rank, and the noise
from repeated settings (pure error) when there are enough of them."""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop.fitting import Fit


def minimum_residuals(parameter_count: int) -> int:
    """Residuals needed to test a model with ``parameter_count`` parameters: twice as many,
    and at least 10 degrees of freedom left."""
    return max(2 * parameter_count, parameter_count + 10)


MAX_TERM_UNCERTAINTY = 0.5
"""An effect's term is undetermined when its standard deviation (RMS over the rows) is
more than this share of the term's own RMS."""


def _term_spread(prepared, values: np.ndarray, covariance: np.ndarray, context: dict):
    """RMS of an effect's term over the rows and the RMS of its standard deviation
    (first-order propagation of the parameters' covariance)."""
    term = prepared.term(values, context).ravel()
    sensitivity = np.empty((term.size, len(values)))
    for j in range(len(values)):
        step = 1e-6 * max(abs(values[j]), 1e-9)
        shifted = np.array(values, float)
        shifted[j] += step
        sensitivity[:, j] = (prepared.term(shifted, context).ravel() - term) / step
    variance = np.sum((sensitivity @ covariance) * sensitivity, axis=1)
    return float(np.sqrt(np.mean(term ** 2))), float(np.sqrt(np.mean(variance)))


def undetermined_reason(machine, current: Fit, entry: dict, rows) -> str | None:
    """Why the candidate scored in ``entry`` (by :func:`.trial.try_candidate` on ``rows``) is not
    identifiable from the data, or None.

    The noise is the one its F-test used. Three checks: its parameters add as many
    independent directions to the joint fit's Jacobian as the model gains parameters
    (else they are not separable from the model's); the term they make is known to better
    than :data:`MAX_TERM_UNCERTAINTY` of its size (the covariance is the joint fit's, so
    correlation with the base model counts); and a fitted period is known to 10 %.
    """
    extended, extra = entry['fit'], entry['extra']
    k = len(extended.effects) - 1
    prepared, values = extended.effects[k], extended.values[k]
    columns = extended.effect_slice(k)
    gained = extended.rank - current.rank
    if gained < extra:
        return (f'its parameters are not separable from the model\'s: they add {gained} '
                f'of {extra} independent directions to the fit')
    covariance = extended.covariance(entry['noise'])[columns, columns]
    size, spread = _term_spread(prepared, values, covariance,
                                machine.context(extended.base, rows))
    if not spread <= MAX_TERM_UNCERTAINTY * size:
        return (f'undetermined: its term (RMS {size:.3g}) has a standard deviation of '
                f'{spread:.3g}: correlated with the base model, or too few distinct '
                f'positions')
    sigma = np.sqrt(np.clip(np.diag(covariance), 0, None))
    ranges = prepared.notes.get('resolvable_periods_m', {})
    for name, value, s in zip(prepared.names, values, sigma):
        if not name.startswith('period_'):
            continue
        if not s <= 0.1 * abs(value):
            return f'period not determined: {name} = {value:.4g} +- {s:.2g} m'
        shortest, longest = ranges.get(name[len('period_'):], (0.0, np.inf))
        if not 0.95 * shortest <= abs(value) <= 1.05 * longest:
            return (f'the fitted period ({abs(value) * 1e3:.4g} mm) left the periods the '
                    f'positions resolve ({shortest * 1e3:.4g} to {longest * 1e3:.4g} mm): '
                    f'an alias of a shorter period or a trend, not determined')
    return None


MIN_PURE_ERROR_DOF = 10


def pure_error_variance(machine, extended: Fit, train, extra: int, residual_dof: int):
    """The noise variance for a candidate's F-test and its degrees of freedom: from the
    scatter of the extended model's residuals within replicate groups (pure error) when
    the machine has them and they leave :data:`MIN_PURE_ERROR_DOF`, else from the
    residuals. The candidate's own parameters are taken off the pure error's degrees of
    freedom, since an effect that varies within a group (a transient) absorbs some of it."""
    groups = machine.replicates()
    residual_variance = extended.rss / max(residual_dof, 1)
    if groups is None:
        return residual_variance, residual_dof
    labels = groups[train]
    r = extended.residuals
    within, cells = 0.0, 0
    for label in np.unique(labels):
        block = r[labels == label]
        within += float(np.sum((block - block.mean(axis=0)) ** 2))
        cells += 1
    dof = r.size - cells * r.shape[1] - extra
    if dof < MIN_PURE_ERROR_DOF:
        return residual_variance, residual_dof
    return within / dof, dof
