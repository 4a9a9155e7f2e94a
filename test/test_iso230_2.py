"""ISO 230-2 figures checked against values worked by hand from the standard's formulas
(issue 53), not against the code's own output: a small run, 2 targets x 2 directions x
3 cycles, deviations chosen so the arithmetic is exact.

Deviations (um), per target and direction, cycles 1-3:

    target 0 mm, up:    1, 3, 2   mean  2, s = 1
    target 0 mm, down: -2,-4,-3   mean -3, s = 1
    target 100 mm, up:  5, 5, 8   mean  6, s = sqrt(3)
    target 100 mm, down:0, 2, 4   mean  2, s = 2

Worked (ISO 230-2:2014, section 2):

    up:   E = 6 - 2 = 4; R = max 4 s = 4 sqrt 3; A = max(x + 2s) - min(x - 2s)
          = (6 + 2 sqrt 3) - (2 - 2) = 6 + 2 sqrt 3
    down: E = 2 - (-3) = 5; R = max(4, 8) = 8; A = (2 + 4) - (-3 - 2) = 11
    B_i = 2 - (-3) = 5 and 6 - 2 = 4: B = 5, B_mean = 4.5
    bidirectional E = 6 - (-3) = 9; M = range((2 - 3) / 2, (6 + 2) / 2) = 4.5
    R_i = max(2 s_up + 2 s_down + |B_i|, 4 s_up, 4 s_down) = 9 and 8 + 2 sqrt 3: R = 8 + 2 sqrt 3
    bidirectional A = (6 + 2 sqrt 3) - (-3 - 2) = 11 + 2 sqrt 3
"""
import numpy as np
import pytest

from calib_core.errors import InvalidInputError
from calib_core.iso230_2 import figures, format_figures

UM = 1e-6
ROOT3 = np.sqrt(3.0)
CELLS = {(0.0, 1): [1, 3, 2], (0.0, -1): [-2, -4, -3],
         (0.1, 1): [5, 5, 8], (0.1, -1): [0, 2, 4]}


def _run(order=None):
    """Rows in the order a bidirectional run takes them (cycle by cycle, up then down)."""
    rows = [(target, direction, CELLS[target, direction][cycle])
            for cycle in range(3) for direction in (1, -1)
            for target in ((0.0, 0.1) if direction == 1 else (0.1, 0.0))]
    if order is not None:
        rows = [rows[i] for i in order]
    target, direction, deviation = (np.array(column, float) for column in zip(*rows))
    return target, deviation * UM, direction


HAND = {
    'up': {'E': 4, 'R': 4 * ROOT3, 'A': 6 + 2 * ROOT3},
    'down': {'E': 5, 'R': 8, 'A': 11},
    'bidirectional': {'B': 5, 'B_mean': 4.5, 'E': 9, 'M': 4.5, 'R': 8 + 2 * ROOT3,
                      'A': 11 + 2 * ROOT3},
}


@pytest.mark.parametrize('section, name', [(s, n) for s, v in HAND.items() for n in v])
def test_each_figure_equals_the_hand_worked_value(section, name):
    result = figures(*_run())
    assert result[section][name] == pytest.approx(HAND[section][name] * UM, rel=1e-12, abs=0)


def test_the_per_target_values_and_the_order_of_the_rows_do_not_matter():
    shuffled = np.random.default_rng(2).permutation(12)
    result = figures(*_run(shuffled))
    per = result['per_target']
    assert per['target'] == [0.0, 0.1]
    assert np.allclose(per['mean_up'], np.array([2, 6]) * UM, rtol=1e-12)
    assert np.allclose(per['mean_down'], np.array([-3, 2]) * UM, rtol=1e-12)
    assert np.allclose(per['s_up'], np.array([1, ROOT3]) * UM, rtol=1e-12)
    assert np.allclose(per['s_down'], np.array([1, 2]) * UM, rtol=1e-12)
    assert np.allclose(per['B'], np.array([5, 4]) * UM, rtol=1e-12)
    assert np.allclose(per['R'], np.array([9, 8 + 2 * ROOT3]) * UM, rtol=1e-12)
    assert result['bidirectional']['A'] == pytest.approx((11 + 2 * ROOT3) * UM, rel=1e-12)


def test_the_reversal_keeps_its_sign():
    """B_i = up - down: a carriage that stops short going up (negative) has a negative
    mean reversal; B, the largest magnitude, stays positive."""
    target, deviation, direction = _run()
    result = figures(target, -deviation, direction)
    assert result['bidirectional']['B_mean'] == pytest.approx(-4.5 * UM, rel=1e-12)
    assert result['bidirectional']['B'] == pytest.approx(5 * UM, rel=1e-12)


def test_one_direction_or_one_cycle_gives_no_figure_it_cannot():
    target, deviation, direction = _run()
    up = direction == 1
    only_up = figures(target[up], deviation[up], direction[up])
    assert only_up['down'] is None and only_up['bidirectional']['B'] is None
    assert only_up['up']['A'] == pytest.approx((6 + 2 * ROOT3) * UM, rel=1e-12)
    first = np.arange(12) < 4      # the first cycle only
    once = figures(target[first], deviation[first], direction[first])
    assert once['up']['R'] is None and once['bidirectional']['R'] is None
    # B_i of the first cycle: 1 - (-2) = 3 and 5 - 0 = 5
    assert once['bidirectional']['B'] == pytest.approx(5 * UM, rel=1e-12)
    with pytest.raises(InvalidInputError):
        figures([], [], [])


def test_the_printed_table_is_in_micrometres_in_the_standard_order():
    lines = format_figures('as measured', figures(*_run()))
    assert lines[0].split() == ['ISO', '230-2,', 'as', 'measured', '(um):', 'A', 'B', 'E',
                                'M', 'R']
    values = [float(v) for v in lines[1].split()[1:]]
    assert values == pytest.approx([11 + 2 * ROOT3, 5, 9, 4.5, 8 + 2 * ROOT3], abs=0.006)
    up = lines[2].split()
    assert up[0] == 'up' and float(up[1]) == pytest.approx(6 + 2 * ROOT3, abs=0.006)
