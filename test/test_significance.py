"""The loop's significance tests calibrated by simulation (issue 53): on pure noise, over a
few hundred seeds, each claims at most its nominal rate (within its binomial band), and
the per-channel Wald test claims about its nominal rate (Bonferroni over independent
channels is nearly exact); the outliers' scale is centred, so an offset column has no
outliers."""
from types import SimpleNamespace

import numpy as np
import pytest

from calib_core.closed_loop.channels import channel_p_values
from calib_core.closed_loop.outliers import find_outliers
from calib_core.loop_structure import structure_tests

SEEDS = 400


def _band(rate: float, runs: int) -> float:
    """Three binomial standard deviations of a rate over ``runs``."""
    return 3 * np.sqrt(rate * (1 - rate) / runs)


def test_the_per_channel_wald_test_claims_its_nominal_rate_on_noise():
    """Three channels of two parameters each in a linear fit of pure noise: any channel
    below alpha = 0.1 in 0.1 of the runs (0.097 expected for independent channels)."""
    prepared = SimpleNamespace(trials_of=lambda channel: 1.0)
    groups = {'a': [0, 1], 'b': [2, 3], 'c': [4, 5]}
    claims = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        design = rng.normal(size=(40, 6))
        y = rng.normal(size=40)
        values, rss = np.linalg.lstsq(design, y, rcond=None)[:2]
        dof = 40 - 6
        covariance = np.linalg.inv(design.T @ design) * float(rss[0]) / dof
        p = channel_p_values(prepared, groups, values, covariance, dof)
        claims += min(p.values()) < 0.1
    rate = claims / SEEDS
    assert abs(rate - 0.097) < _band(0.097, SEEDS), rate


def test_the_structure_tests_claim_at_most_their_rate_on_noise():
    """A channel of pure noise against two positions, time and a cycle (six tests, two
    with periodograms): any structure claimed at alpha = 0.05 in at most 5 % of 300 runs,
    within the binomial band (it was 9.7 % with two channels before the periodogram
    search counted its alternatives in full)."""
    runs, claims = 300, 0
    for seed in range(runs):
        rng = np.random.default_rng(1000 + seed)
        n = 100
        covariates = {'position_a': rng.uniform(0, 0.1, n), 'position_b': rng.uniform(0, 0.1, n),
                      'time': np.arange(n) * 5.0, 'cycle': np.repeat(np.arange(5), n // 5)}
        found = structure_tests(('a',), rng.normal(0, 1e-6, (n, 1)), covariates, 0.05)
        claims += bool(found)
    assert claims / runs <= 0.05 + _band(0.05, runs), claims


def test_a_column_with_an_offset_has_no_outliers():
    """Residuals offset by 50 sigma in one component (a base the loop did not centre):
    the robust scale and z-scores are about the median, so nothing is flagged; a 9-sigma
    row is."""
    rng = np.random.default_rng(3)
    r = rng.normal(0, 1e-6, (200, 2))
    r[:, 1] += 50e-6
    machine = SimpleNamespace(row_errors=lambda residuals: np.linalg.norm(residuals, axis=1))
    assert find_outliers(machine, r, {}, 0.0)['count'] == 0
    r[17, 0] += 9e-6
    found = find_outliers(machine, r, {}, 0.0)
    assert [row['row'] for row in found['rows']] == [17]
    assert found['robust_sigma'] == pytest.approx(1e-6, rel=0.15)


def test_a_periodogram_search_claims_at_most_its_share_on_noise():
    """One channel against one position (a trend and a period tested, alpha shared): a
    period claimed in at most alpha / 2 = 2.5 % of 400 pure-noise runs (it was 7.8 %
    when the search counted one alternative per resolution element)."""
    claims = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(5000 + seed)
        found = structure_tests(('a',), rng.normal(0, 1e-6, (100, 1)),
                                {'position_a': rng.uniform(0, 0.1, 100)}, 0.05)
        claims += any(item['kind'] == 'periodic' for item in found)
    assert claims / SEEDS <= 0.025 + _band(0.025, SEEDS), claims


def test_the_rotary_order_screen_is_the_f_test_worked_here():
    """The first order's p-value of select_orders against the extra-sum-of-squares F-test
    written out: a constant against a constant plus one order (2 terms), n - 3 residual
    degrees of freedom, times the 3 orders scanned."""
    from scipy import stats
    from calib_core.effects.rotary import select_orders
    rng = np.random.default_rng(4)
    angle = np.repeat(np.linspace(0, 2 * np.pi, 16, endpoint=False), 3)
    target = 2e-6 * np.cos(2 * angle + 0.3) + rng.normal(0, 3e-6, angle.size)

    def rss(columns):
        design = np.column_stack([np.ones_like(angle)] + columns)
        fitted = design @ np.linalg.lstsq(design, target, rcond=None)[0]
        return float(np.sum((target - fitted) ** 2))
    rss0 = rss([])
    best = min(rss([np.cos(k * angle), np.sin(k * angle)]) for k in (1, 2, 3))
    n = angle.size
    f_stat = (rss0 - best) / 2 / (best / (n - 3))
    expected = min(1.0, stats.f.sf(f_stat, 2, n - 3) * 3)
    _, first = select_orders(angle, target[:, None], [1, 2, 3], 3)
    assert first == pytest.approx(expected, rel=1e-9)


def test_the_rotary_order_screen_claims_at_most_its_rate_on_noise():
    """16 places round a turn, 3 readings each, pure noise, orders 1-7 scanned: the first
    order passes the 0.05 screen in at most 5 % of 400 runs (within the binomial band)."""
    from calib_core.effects.rotary import select_orders
    angle = np.repeat(np.linspace(0, 2 * np.pi, 16, endpoint=False), 3)
    claims = 0
    for seed in range(SEEDS):
        noise = np.random.default_rng(9000 + seed).normal(0, 1e-6, (angle.size, 1))
        claims += select_orders(angle, noise, range(1, 8), 7)[1] < 0.05
    assert claims / SEEDS <= 0.05 + _band(0.05, SEEDS), claims


def test_channel_p_values_are_the_wald_test_worked_here():
    """Two channels: a (two parameters, its period searched over 4 alternatives) and b (one
    parameter). Each p-value is the F tail of theta^T B^-1 theta / q on (q, dof), times
    the channel's searches and the 2 channels."""
    from scipy import stats
    prepared = SimpleNamespace(trials_of=lambda channel: {'a': 4.0, 'b': 1.0}[channel])
    values = np.array([3e-6, -1e-6, 2e-6])
    covariance = np.array([[1e-12, 0.2e-12, 0], [0.2e-12, 2e-12, 0], [0, 0, 0.5e-12]])
    p = channel_p_values(prepared, {'a': [0, 1], 'b': [2]}, values, covariance, 30)
    block = covariance[:2, :2]
    wald_a = values[:2] @ np.linalg.inv(block) @ values[:2] / 2
    wald_b = values[2] ** 2 / covariance[2, 2]
    assert p['a'] == pytest.approx(min(1.0, stats.f.sf(wald_a, 2, 30) * 4 * 2), rel=1e-9)
    assert p['b'] == pytest.approx(min(1.0, stats.f.sf(wald_b, 1, 30) * 1 * 2), rel=1e-9)
