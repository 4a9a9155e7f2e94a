"""Rows no smooth effect describes (a start-up transient, a gross error): a robust scale
of the residuals and the rows far outside it.

The scale is per residual component, the normalised median absolute deviation of the
signed residuals about their median, 1.4826 MAD: for normal noise it estimates the
standard deviation (1.4826 = 1 / Phi^-1(3/4), the consistency factor; Rousseeuw and
Croux 1993), and a few gross errors barely move it. It is *not* taken from the row error
magnitudes (norms or absolute values): those are half-normal or chi-distributed, and
1.4826 times their MAD about their median is 0.60 sigma for an absolute value, which
flagged 3-sigma rows of clean data as 5-sigma outliers.

A row is an outlier when its whitened error (each component divided by its own scale)
has the probability of a 5-sigma normal deviation or less: ``|z| > 5`` for one
component, the same tail probability of the chi distribution for k components.
"""
from __future__ import annotations

import numpy as np
from scipy import special

MAD_CONSISTENCY = 1.4826
"""1 / Phi^-1(3/4): 1.4826 MAD estimates a normal distribution's standard deviation."""

OUTLIER_SIGMAS = 5.0
# A stratum (a camera's view) is named when at least this share of its rows, and at least
# STRATUM_MIN_ROWS of them, are outliers: its data disagree with the rest as a whole.
STRATUM_SHARE, STRATUM_MIN_ROWS = 0.25, 3
OUTLIER_TAIL = float(2 * special.ndtr(-OUTLIER_SIGMAS))   # two-sided, 5.7e-7


def robust_scale(residuals: np.ndarray) -> np.ndarray:
    """1.4826 MAD of each column of ``residuals`` (n, k) about its median, same unit."""
    r = np.asarray(residuals, float)
    centre = np.median(r, axis=0)
    return MAD_CONSISTENCY * np.median(np.abs(r - centre), axis=0)


def whitened_limit(components: int) -> float:
    """Limit on the norm of ``components`` whitened residuals with the tail probability
    of a :data:`OUTLIER_SIGMAS` normal deviation (5.0 for one component)."""
    return float(np.sqrt(special.chdtri(components, OUTLIER_TAIL)))


def find_outliers(machine, residuals: np.ndarray, covariates: dict, min_effect: float) -> dict:
    """Rows of ``residuals`` (N, k) far outside their robust scale, for the report.

    A machine's ``row_errors`` gives one error per row (a norm) or one per component (a
    hexapod leg, a platform chain); the test follows it: the whitened norm of the row's
    components, or each whitened component alone. An error below ``min_effect`` is never
    called an outlier.

    Returns
    -------
    dict
        ``robust_sigma`` (RMS over the components of their robust scales, residual unit),
        ``robust_sigma_by_component``, ``limit_sigmas`` (the whitened limit),
        ``limit`` (that limit times ``robust_sigma``, residual unit), ``count`` and up to
        20 ``rows`` (row, its error, its covariates, and its stratum's label where the
        machine names its strata), the worst first; where it does, ``strata``: each
        stratum most of whose rows disagree (see STRATUM_SHARE), with its ``label``, its
        ``outliers`` and its ``rows``, the most first.
    """
    r = np.asarray(residuals, float)
    errors = machine.row_errors(r)
    scale = robust_scale(r)
    scale = np.where(scale > 0, scale, np.finfo(float).tiny)
    z = (r - np.median(r, axis=0)) / scale
    per_row = max(len(errors) // len(r), 1)
    if per_row == 1:
        statistic, components = np.linalg.norm(z, axis=1), r.shape[1]
    else:
        statistic, components = np.abs(z).ravel(), 1
    limit_sigmas = whitened_limit(components)
    flagged = np.flatnonzero((statistic > limit_sigmas) & (errors > min_effect))
    flagged = flagged[np.argsort(-errors[flagged])]
    worst = {}
    for i in flagged:
        worst.setdefault(int(i) // per_row, float(errors[i]))
    sigma = float(np.sqrt(np.mean(scale ** 2)))
    found = {'robust_sigma': sigma, 'robust_sigma_by_component': scale.tolist(),
             'limit_sigmas': limit_sigmas, 'limit': max(limit_sigmas * sigma, min_effect),
             'rows': [{'row': row, 'error': error,
                       'covariates': {k: float(v[row]) for k, v in covariates.items()}}
                      for row, error in list(worst.items())[:20]],
             'count': len(worst)}
    name = getattr(machine, 'stratum_name', '')    # MachineModel's; '' for any other
    if name:
        strata = np.asarray(machine.strata())
        for entry in found['rows']:
            entry[name] = machine.stratum_label(int(strata[entry['row']]))
        labels, sizes = np.unique(strata, return_counts=True)
        counts = np.array([np.count_nonzero(strata[list(worst)] == s) for s in labels]) \
            if worst else np.zeros(len(labels), int)
        named = np.flatnonzero((counts >= STRATUM_MIN_ROWS) & (counts >= STRATUM_SHARE * sizes))
        found['strata'] = [{'label': machine.stratum_label(int(labels[i])),
                            'outliers': int(counts[i]), 'rows': int(sizes[i])}
                           for i in named[np.argsort(-counts[named], kind='stable')]]
        found['stratum_name'] = name
    return found
