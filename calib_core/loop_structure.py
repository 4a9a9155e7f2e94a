"""Structure left in the closed loop's residuals that no effect explained.

Every channel's residual is tested against every covariate, by the kind of covariate:

- a categorical one (block, setup, run, cycle) or one with two values: a step per level;
- a quantity (position, time, temperature, load, image radius): a cubic trend;
- a position: also a sinusoid at the highest peak of a fine periodogram over the periods
  the distinct positions resolve, its frequency refined to the peak;
- a position with a direction of approach: a reversal that changes with position
  (direction times a cubic in position), the interaction one covariate at a time misses.
  Its p-value beyond the cubic trend is kept beside (``p_beyond_trend``): the loop tries
  the reversal candidates on the first, a wide screen; the report names the structure
  only where the second holds too (a real turntable's 227 um trend, its data mostly of
  one direction, had been named a second time as a reversal changing with position,
  which its reversal candidate then did not find).

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


def _same_covariate(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``b`` is ``a`` scaled (by either sign) and shifted, to 1e-3 of its range."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape or not (np.ptp(a) > 0 and np.ptp(b) > 0):
        return False
    scaled_a, scaled_b = _scaled(a), _scaled(b)
    return bool(min(np.max(np.abs(scaled_a - scaled_b)), np.max(np.abs(scaled_a + scaled_b)))
                < 1e-3)


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
    """(kind, basis, beyond, trials, detail) of the structures to test ``r`` for against
    ``z``; ``beyond``: a basis the structure is also tested beyond (None: none)."""
    levels = np.unique(z)
    if name in CATEGORICAL_COVARIATES or len(levels) == 2:
        yield ('step', np.column_stack([z == level for level in levels[1:]]).astype(float),
               None, 1.0, {})
        return
    degree = min(3, len(levels) - 1)
    trend = legendre.legvander(_scaled(z), degree)[:, 1:]
    yield 'trend', trend, None, 1.0, {}
    if not name.startswith('position'):
        return
    periodic = _periodic_basis(z, r)
    if periodic is not None:
        basis, trials, period = periodic
        yield 'periodic', basis, None, trials, {'period': float(period)}
    direction = covariates.get(name.replace('position', 'direction', 1))
    if direction is not None and len(np.unique(direction)) == 2:
        yield ('reversal changing with position',
               direction[:, None] * legendre.legvander(_scaled(z), degree), trend, 1.0, {})


def _f_test(r: np.ndarray, basis: np.ndarray, given: np.ndarray | None):
    """(p-value, fitted structure (n,)) of ``basis`` explaining ``r`` beyond ``given``
    (None: beyond the mean alone), both centred here; None where the test has no degrees
    of freedom."""
    n = len(r)
    basis = basis - basis.mean(axis=0)
    before = np.zeros_like(r)
    given_rank = 0
    if given is not None:
        given = given - given.mean(axis=0)
        before = given @ np.linalg.lstsq(given, r, rcond=None)[0]
        given_rank = np.linalg.matrix_rank(given)
        basis = np.column_stack([given, basis])
    full = basis @ np.linalg.lstsq(basis, r, rcond=None)[0]
    rss0, rss1 = float(np.sum((r - before) ** 2)), float(np.sum((r - full) ** 2))
    rank = np.linalg.matrix_rank(basis)
    p, dof = rank - given_rank, n - rank - 1
    if dof <= 0 or rss1 <= 0 or p <= 0:
        return None
    f_stat = (rss0 - rss1) / p / (rss1 / dof)
    return float(special.fdtrc(p, dof, f_stat)), full - before


def structure_tests(channels, residuals: np.ndarray, covariates: dict, alpha: float) -> list:
    """Structure left in channel ``residuals`` (n, C) against ``covariates`` (name -> (n,)).

    Returns
    -------
    list of dict
        The significant structures, most significant first: covariate, component, kind,
        p_value (corrected), structure_rms and residual_rms (residual units), the period
        (m) of a periodic one, and ``same_as``: the other covariates with the same values
        (a rotary axis's position and angle), tested once.
    """
    tests = []
    # A covariate that is another scaled and shifted, to a thousandth of its range (a
    # rotary axis's commanded places and its encoder's readings), is one test, under the
    # name that gets the most kinds of test (a position's): counted twice, it had doubled
    # both the report's lines and the correction.
    kept: dict = {}
    for name in sorted(covariates, key=lambda key: not key.startswith('position')):
        z = covariates[name]
        twin = next((k for k in kept if _same_covariate(covariates[k], z)), None)
        if twin is None:
            kept[name] = []
        else:
            kept[twin].append(name)
    for name, aliases in kept.items():
        z = covariates[name]
        if len(np.unique(z)) < 2:
            continue
        for j, component in enumerate(channels):
            r = residuals[:, j] - residuals[:, j].mean()
            for kind, basis, beyond, trials, detail in _candidates(name, z, r, covariates,
                                                                   component):
                tested = _f_test(r, basis, None)
                if tested is None:
                    continue
                p_value, fitted = tested
                if beyond is not None:
                    partial = _f_test(r, basis, beyond)
                    detail['p_beyond_trend'] = 1.0 if partial is None else partial[0] * trials
                tests.append(dict(detail, covariate=name, component=f'residual_{component}',
                                  kind=kind, **({'same_as': aliases} if aliases else {}),
                                  p_value=min(1.0, p_value * trials),
                                  structure_rms=float(np.sqrt(np.mean(fitted ** 2))),
                                  residual_rms=float(np.sqrt(np.mean(r ** 2)))))
    count = max(len(tests), 1)
    found = [dict(t, p_value=min(1.0, t['p_value'] * count),
                  **({'p_beyond_trend': min(1.0, t['p_beyond_trend'] * count)}
                     if 'p_beyond_trend' in t else {}))
             for t in tests if t['p_value'] * count < alpha]
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
