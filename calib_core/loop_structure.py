"""Structure left in the closed loop's residuals that no effect explained.

Every channel's residual is tested against every covariate, by the kind of covariate:

- a categorical one (block, setup, run, cycle) or one with two values: a step per level;
- a quantity (position, time, temperature, load, image radius): a cubic trend;
- a position: also a sinusoid at the highest peak of a fine periodogram over the periods
  the distinct positions resolve, its frequency refined to the peak;
- a position with a direction of approach: a reversal that changes with position
  (direction times a cubic in position), the interaction one covariate at a time misses.

Each is an extra-sum-of-squares F-test, Bonferroni-corrected over the periods scanned and
over every test made; the size reported is the RMS of the fitted structure.
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre
from scipy import stats
from scipy.optimize import minimize_scalar
from scipy.signal import lombscargle

from calib_core.effects import CATEGORICAL_COVARIATES, resolvable_periods


def _scaled(z: np.ndarray) -> np.ndarray:
    return 2 * (z - z.min()) / np.ptp(z) - 1


def _periodic_basis(z: np.ndarray, r: np.ndarray):
    """(basis, trials, period) of the sinusoid at the refined periodogram peak, or None."""
    shortest, longest, _ = resolvable_periods(z)
    if shortest >= longest or len(np.unique(z)) < 8:
        return None
    span = float(np.ptp(z))
    f_low, f_high = 1 / longest, 1 / shortest
    freqs = np.linspace(f_low, f_high, int(min(20000, max(400, 20 * (f_high - f_low) * span))))
    power = lombscargle(z, r, 2 * np.pi * freqs, floating_mean=True)
    best = int(np.argmax(power))
    step = freqs[1] - freqs[0]

    def negative_power(f):
        return -float(np.ravel(lombscargle(z, r, np.array([2 * np.pi * f]), floating_mean=True))[0])

    refined = minimize_scalar(negative_power, method='bounded',
                              bounds=(max(f_low, freqs[best] - step), min(f_high, freqs[best] + step)))
    omega = 2 * np.pi * refined.x
    basis = np.column_stack([np.cos(omega * z), np.sin(omega * z)])
    return basis, max((f_high - f_low) * span, 1.0), 1 / refined.x


def _candidates(name: str, z: np.ndarray, r: np.ndarray, covariates: dict, channel: str):
    """(kind, basis, trials, detail) of the structures to test ``r`` for against ``z``."""
    levels = np.unique(z)
    if name in CATEGORICAL_COVARIATES or len(levels) == 2:
        yield 'step', np.column_stack([z == level for level in levels[1:]]).astype(float), 1.0, {}
        return
    degree = min(3, len(levels) - 1)
    yield 'trend', legendre.legvander(_scaled(z), degree)[:, 1:], 1.0, {}
    if not name.startswith('position'):
        return
    periodic = _periodic_basis(z, r)
    if periodic is not None:
        basis, trials, period = periodic
        yield 'periodic', basis, trials, {'period': float(period)}
    direction = covariates.get(name.replace('position', 'direction', 1))
    if direction is not None and len(np.unique(direction)) == 2:
        yield ('reversal changing with position',
               direction[:, None] * legendre.legvander(_scaled(z), degree), 1.0, {})


def structure_tests(channels, residuals: np.ndarray, covariates: dict, alpha: float) -> list:
    """Structure left in channel ``residuals`` (n, C) against ``covariates`` (name -> (n,)).

    Returns
    -------
    list of dict
        The significant structures, most significant first: covariate, component, kind,
        p_value (corrected), structure_rms and residual_rms (residual units), and the
        period (m) of a periodic one.
    """
    n = len(residuals)
    tests = []
    for name, z in covariates.items():
        if len(np.unique(z)) < 2:
            continue
        for j, component in enumerate(channels):
            r = residuals[:, j] - residuals[:, j].mean()
            for kind, basis, trials, detail in _candidates(name, z, r, covariates, component):
                basis = basis - basis.mean(axis=0)
                fitted = basis @ np.linalg.lstsq(basis, r, rcond=None)[0]
                rss1 = float(np.sum((r - fitted) ** 2))
                p = np.linalg.matrix_rank(basis)
                dof = n - p - 1
                if dof <= 0 or rss1 <= 0 or p == 0:
                    continue
                f_stat = (float(r @ r) - rss1) / p / (rss1 / dof)
                tests.append(dict(detail, covariate=name, component=f'residual_{component}',
                                  kind=kind,
                                  p_value=min(1.0, float(stats.f.sf(f_stat, p, dof)) * trials),
                                  structure_rms=float(np.sqrt(np.mean(fitted ** 2))),
                                  residual_rms=float(np.sqrt(np.mean(r ** 2)))))
    count = max(len(tests), 1)
    found = [dict(t, p_value=min(1.0, t['p_value'] * count)) for t in tests
             if t['p_value'] * count < alpha]
    return sorted(found, key=lambda t: t['p_value'])
