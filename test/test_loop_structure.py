"""What the structure tests name (calib_core.loop_structure), on a rotary table's shape of
data: one covariate under two names (its commanded places and its encoder's readings) is
one finding, and a trend in data mostly of one direction is not also called a reversal
changing with position, while a reversal that changes with position is."""
import numpy as np

from calib_core.loop_structure import structure_tests

ALPHA = 1e-3


def _table(rng, n=120):
    """Places of a turn (rad), the encoder's readings of them (1e-6 rad of noise), and the
    direction: all +1 but every tenth row (a table turning one way)."""
    places = np.repeat(np.linspace(0, 2 * np.pi, 12, endpoint=False), n // 12)
    covariates = {'angle_c': places + rng.normal(0, 1e-6, n), 'position_c': places,
                  'direction_c': np.where(np.arange(n) % 10 == 0, -1.0, 1.0)}
    return places, covariates


def test_one_covariate_under_two_names_is_one_finding():
    rng = np.random.default_rng(7)
    places, covariates = _table(rng)
    residual = 20e-6 * (places / np.pi - 1) + rng.normal(0, 2e-6, len(places))
    found = structure_tests(('c',), residual[:, None], covariates, ALPHA)
    trends = [f for f in found if f['kind'] == 'trend']
    assert [(f['covariate'], f['same_as']) for f in trends] == [('position_c', ['angle_c'])]


def test_a_trend_is_not_called_a_reversal_and_a_reversal_is():
    """The wide screen the loop tries candidates on flags the trend as a reversal too
    (direction times a cubic spans a trend where the direction is mostly one); its
    p-value beyond the trend (``p_beyond_trend``, which the report's filter reads) is 1.
    A backlash growing along the turn gets a small one."""
    rng = np.random.default_rng(8)
    places, covariates = _table(rng)
    noise = rng.normal(0, 2e-6, len(places))
    trend = 20e-6 * (places / np.pi - 1)
    found = structure_tests(('c',), (trend + noise)[:, None], covariates, ALPHA)
    reversal = [f for f in found if f['kind'] == 'reversal changing with position']
    assert reversal and all(f['p_beyond_trend'] >= ALPHA for f in reversal), found
    growing = covariates['direction_c'] * 10e-6 * places / (2 * np.pi)
    found = structure_tests(('c',), (growing + noise)[:, None], covariates, ALPHA)
    reversal = [f for f in found if f['kind'] == 'reversal changing with position']
    assert reversal and reversal[0]['p_beyond_trend'] < ALPHA, found
