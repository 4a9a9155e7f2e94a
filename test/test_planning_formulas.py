"""The planner's formulas against brute force and first principles (issue 53): the
exchange's design against the best of every subset of a small candidate set, ``whiten``
against J^T N^-1 J, the sandwich covariance against a Monte-Carlo of the fit, and the
predicted error against the errors of fits to simulated data."""
from itertools import combinations

import numpy as np
import pytest

from calib_core.planning import (
    exchange, information, predicted_errors, sandwich_covariance, whiten)


def _problem(seed: int, m: int = 9, r: int = 2, p: int = 3, w: int = 5):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(m, r, p)), rng.normal(size=(w, 2, p))


def _criterion(jacobians, subset, criterion, working):
    a = information(jacobians, subset)
    if criterion == 'D':
        return -np.linalg.slogdet(a)[1]
    weight = np.einsum('wqp,wqs->ps', working, working) / len(working)
    return float(np.trace(weight @ np.linalg.inv(a)))


@pytest.mark.parametrize('criterion', ['I', 'D'])
@pytest.mark.parametrize('seed', range(6))
def test_the_exchange_finds_the_best_subset(criterion, seed):
    """9 candidates of 2 rows, 3 parameters, 4 chosen: 126 subsets, every one scored by
    the criterion's definition; the exchange's design is the best (its value too)."""
    jacobians, working = _problem(seed)
    best = min(combinations(range(9), 4),
               key=lambda s: _criterion(jacobians, s, criterion, working))
    value = _criterion(jacobians, best, criterion, working)
    design = exchange(jacobians, 4, criterion, working)
    assert design.value == pytest.approx(_criterion(jacobians, design.chosen, criterion,
                                                    working), rel=1e-9)
    assert design.value == pytest.approx(value, rel=1e-9)
    assert sorted(design.chosen) == list(best)


def test_whitened_rows_carry_the_noise_weighted_information():
    """sum_k (L_k^-1 J_k)^T (L_k^-1 J_k) = sum_k J_k^T N_k^-1 J_k for correlated noise."""
    rng = np.random.default_rng(4)
    rows = rng.normal(size=(6, 3, 4))
    factors = rng.normal(size=(6, 3, 3))
    noise = factors @ np.swapaxes(factors, 1, 2) + 0.5 * np.eye(3)
    expected = sum(j.T @ np.linalg.inv(n) @ j for j, n in zip(rows, noise))
    assert information(whiten(rows, noise), np.arange(6)) == pytest.approx(expected, rel=1e-10)


def test_the_sandwich_covariance_is_the_fits_scatter():
    """Ordinary least squares on rows whose noise is correlated within a measurement: the
    covariance of 4000 simulated fits equals the sandwich within its Monte-Carlo error
    (2 % on the diagonal here), and the predicted error at working poses equals the
    scatter of the fitted models' predictions there; the naive (J^T J)^-1 sigma^2 is
    clearly off."""
    rng = np.random.default_rng(8)
    rows = rng.normal(size=(20, 3, 4))
    factors = rng.normal(size=(20, 3, 3)) * np.array([1.0, 0.2, 3.0])[:, None]
    noise = factors @ np.swapaxes(factors, 1, 2)
    working = rng.normal(size=(7, 2, 4))
    design = rows.reshape(-1, 4)
    draws = np.einsum('kij,nkj->nki', np.linalg.cholesky(noise),
                      rng.normal(size=(4000, 20, 3))).reshape(4000, -1)
    estimates = np.linalg.lstsq(design, draws.T, rcond=None)[0].T
    empirical = np.cov(estimates.T)
    sandwich = sandwich_covariance(rows, noise)
    assert np.diag(empirical) == pytest.approx(np.diag(sandwich), rel=0.06)
    assert empirical == pytest.approx(sandwich, abs=0.06 * np.max(np.diag(sandwich)))
    naive = np.linalg.inv(design.T @ design) * np.trace(noise.sum(axis=0)) / design.shape[0]
    assert not np.allclose(np.diag(naive), np.diag(sandwich), rtol=0.2)
    predicted = predicted_errors(sandwich, working)
    scatter = np.einsum('wqp,np->nwq', working, estimates).std(axis=0)
    assert scatter == pytest.approx(predicted, rel=0.06)


@pytest.mark.parametrize('criterion', ['I', 'D'])
@pytest.mark.parametrize('seed', range(4))
def test_every_exchange_ends_where_no_single_swap_helps(criterion, seed):
    """Started from the five least informative candidates, the exchange's sweeps end where
    swapping any one chosen candidate for any other does not improve the criterion: every
    slot, the last included, was revisited until none helped."""
    from calib_core.planning import _swaps, _working_weight
    jacobians, working = _problem(seed, m=12)
    weakest = [int(k) for k in np.argsort(np.einsum('mrp,mrp->m', jacobians, jacobians))[:5]]
    design = _swaps(jacobians, list(weakest), information(jacobians, weakest), criterion,
                    _working_weight(criterion, working), 20)
    chosen = [int(k) for k in design.chosen]
    assert design.value == pytest.approx(_criterion(jacobians, chosen, criterion, working),
                                         rel=1e-9)
    for slot in range(5):
        for other in set(range(12)) - set(chosen):
            swapped = chosen[:slot] + [other] + chosen[slot + 1:]
            assert _criterion(jacobians, swapped, criterion, working) >= design.value * (
                1 - 1e-9) - 1e-12
