"""The closed loop's robust scale and outlier rows (calib_core.closed_loop.outliers):
checked against the true noise sigma over many seeds, for machines that report one error
per row (a norm) and one per component (a platform chain, a hexapod leg)."""
import numpy as np
import pytest

from calib_core.closed_loop.outliers import find_outliers, robust_scale, whitened_limit

SIGMA = 9.82e-6   # m, the platform case of issue 30
TOLERANCE = {'median scale / sigma': 0.03, 'single-seed scale / sigma': 0.2}


class PerComponent:
    """Errors per component, like the platform's chains."""

    @staticmethod
    def row_errors(residuals):
        return np.abs(residuals).ravel()


class PerRow:
    """Errors as the norm per row, like the gantry or the rotary target."""

    @staticmethod
    def row_errors(residuals):
        return np.linalg.norm(residuals, axis=1)


def test_limit_is_five_sigma_for_one_component_and_same_tail_for_more():
    assert whitened_limit(1) == pytest.approx(5.0, rel=1e-9)
    assert 5.0 < whitened_limit(2) < whitened_limit(6)


@pytest.mark.parametrize('machine,width', [(PerComponent, 3), (PerRow, 2), (PerRow, 6)])
def test_clean_normal_residuals_scale_matches_sigma_and_no_outlier_over_100_seeds(machine, width):
    ratios, flagged = [], 0
    for seed in range(100):
        residuals = np.random.default_rng(seed).normal(0, SIGMA, (200, width))
        result = find_outliers(machine, residuals, {}, min_effect=0.0)
        ratios.append(result['robust_sigma'] / SIGMA)
        flagged += result['count']
    assert np.median(ratios) == pytest.approx(1.0, abs=TOLERANCE['median scale / sigma'])
    assert np.all(np.abs(np.array(ratios) - 1) < TOLERANCE['single-seed scale / sigma'])
    assert flagged == 0


def test_scale_from_absolute_errors_would_be_too_small():
    # Why the scale is taken from signed residuals: the same estimator on |r| gives 0.6 sigma.
    r = np.random.default_rng(1).normal(0, SIGMA, 100_000)
    assert robust_scale(np.abs(r)[:, None])[0] / SIGMA == pytest.approx(0.60, abs=0.02)
    assert robust_scale(r[:, None])[0] / SIGMA == pytest.approx(1.0, abs=0.02)


def test_gross_errors_are_named_worst_first_with_their_covariates():
    rng = np.random.default_rng(3)
    residuals = rng.normal(0, SIGMA, (150, 3))
    residuals[17, 1] += 12 * SIGMA
    residuals[90, 2] -= 8 * SIGMA
    position = np.arange(150.0)
    result = find_outliers(PerComponent, residuals, {'position': position}, min_effect=0.0)
    assert [row['row'] for row in result['rows']] == [17, 90]
    assert result['rows'][0]['covariates']['position'] == 17.0
    assert result['count'] == 2


def test_columns_of_different_scales_are_whitened_each_by_its_own():
    # A rotary target: positions in m (sigma 10 um) and orientations x 0.1 m (sigma 1 um).
    rng = np.random.default_rng(4)
    residuals = np.column_stack([rng.normal(0, 10e-6, (300, 3)), rng.normal(0, 1e-6, (300, 3))])
    residuals[5, 4] += 9e-6    # 9 of its own sigma, under the position columns' spread
    result = find_outliers(PerRow, residuals, {}, min_effect=0.0)
    assert result['robust_sigma_by_component'][0] == pytest.approx(10e-6, rel=0.15)
    assert result['robust_sigma_by_component'][4] == pytest.approx(1e-6, rel=0.15)
    assert [row['row'] for row in result['rows']] == [5]


def test_errors_below_the_minimum_effect_are_never_outliers():
    residuals = np.random.default_rng(5).normal(0, 1e-9, (100, 2))
    residuals[3] += 20e-9
    assert find_outliers(PerRow, residuals, {}, min_effect=50e-9)['count'] == 0
    assert find_outliers(PerRow, residuals, {}, min_effect=0.0)['count'] == 1
