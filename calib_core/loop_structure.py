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
from scipy import special

from calib_core.effects import CATEGORICAL_COVARIATES, resolvable_periods
from calib_core.effects.periodic import search_trials
from calib_core.periodogram import explained_power


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
    # Imported here: scipy.optimize costs a command's start-up 0.4 s, and only a
    # periodogram's refinement needs it.
    from scipy.optimize import minimize_scalar
    power = explained_power(z, r, freqs)
    best = int(np.argmax(power))
    step = freqs[1] - freqs[0]

    def negative_power(f):
        return -float(explained_power(z, r, [f])[0])

    refined = minimize_scalar(negative_power, method='bounded',
                              bounds=(max(f_low, freqs[best] - step), min(f_high, freqs[best] + step)))
    omega = 2 * np.pi * refined.x
    basis = np.column_stack([np.cos(omega * z), np.sin(omega * z)])
    return basis, search_trials(f_low, f_high, span), 1 / refined.x


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
                                  p_value=min(1.0, float(special.fdtrc(p, dof, f_stat)) * trials),
                                  structure_rms=float(np.sqrt(np.mean(fitted ** 2))),
                                  residual_rms=float(np.sqrt(np.mean(r ** 2)))))
    count = max(len(tests), 1)
    found = [dict(t, p_value=min(1.0, t['p_value'] * count)) for t in tests
             if t['p_value'] * count < alpha]
    return sorted(found, key=lambda t: t['p_value'])


def lack_of_fit(residuals: np.ndarray, groups: np.ndarray, parameter_count: int,
                alpha: float) -> dict | None:
    """The classic lack-of-fit test where settings were repeated (an ISO 230-2 target
    approached from one direction, cycle after cycle).

    ``residuals`` (n, k) of the fitted model on rows with replicate labels ``groups`` (n,).
    The scatter within the cells is pure error; the cells' mean residuals are what the
    model fails to describe. F = (SS_lack / (c k - p)) / (SS_pure / (n k - c k)), with c
    cells and p the model's parameters. Where the model fits (its effects explain the
    cell means), F is about 1, however sparse the targets.

    Returns
    -------
    dict or None
        When significant at ``alpha``: ``structure_rms`` (RMS of the cell means over the
        rows), ``pure_error_sigma`` (residual unit), ``cells``, ``p_value``; None when it
        is not, or the cells leave no degrees of freedom for the test.
    """
    r = np.asarray(residuals, float)
    labels, inverse = np.unique(groups, return_inverse=True)
    means = np.zeros((len(labels), r.shape[1]))
    np.add.at(means, inverse, r)
    counts = np.bincount(inverse, minlength=len(labels))[:, None]
    means /= counts
    pure = float(np.sum((r - means[inverse]) ** 2))
    lack = float(np.sum(counts * means ** 2))
    dof_pure = r.size - means.size
    dof_lack = means.size - parameter_count
    if dof_pure < 1 or dof_lack < 1 or pure <= 0:
        return None
    f_stat = (lack / dof_lack) / (pure / dof_pure)
    p_value = float(special.fdtrc(dof_lack, dof_pure, f_stat))
    if p_value >= alpha:
        return None
    return {'structure_rms': float(np.sqrt(lack / r.size)),
            'pure_error_sigma': float(np.sqrt(pure / dof_pure)),
            'cells': int(len(labels)), 'p_value': p_value}


_CAUSES = {
    'periodic': ('a cyclic error the library did not fit here (a lead screw\'s pitch error, '
                 'an encoder\'s interpolation error, a gear\'s tooth error)'),
    'trend': ('a smooth error the model lacks: against a position, a lead error, straightness '
              'or a geometric parameter; against time or temperature, a thermal drift; '
              'against a load, compliance or play'),
    'step': 'a change between set-ups, blocks or runs (a remount, a re-homed axis, a new warm-up)',
    'reversal changing with position': ('backlash or friction that changes along the travel '
                                        '(screw wear, preload)'),
    'lack of fit': ('errors at the settings measured that no effect in the library describes '
                    'at this sampling: a lead error finer than the target spacing, a cyclic '
                    'error aliased by the grid, a set-up change inside the run'),
}


def likely_causes(item: dict) -> str:
    """What could cause an unexplained structure, by its kind and covariate (a hint for the
    engineer, not a diagnosis: the data did not pick one)."""
    if item['covariate'].startswith('angle') or item.get('covariate_unit') == 'rad':
        return ('an error repeating with the rotary axis\'s angle that neither an angle error '
                'nor an error motion (radial, axial, tilt; ISO 230-7) of the orders tested '
                'explains: error motion of an order the angles do not resolve or too small '
                'to stand out from this noise, or the instrument\'s bias with the view angle')
    if item['covariate'] == 'image_radius':
        return 'lens distortion of higher order than modelled'
    return _CAUSES.get(item['kind'], 'not known')
