"""Nothing a peer sends can make a calibrator run for days or exhaust it (issue 54, part):
a plan's counts are bounded, a request is refused before parsing when it is long, uses
YAML aliases or repeats a key, and a refusal quotes only a short prefix of the value."""
import time
import tracemalloc

import pytest

from calib_core.checks import BRIEF, MAX_COUNT, whole_number
from calib_core.errors import InvalidInputError
from calib_core.nodes.calibrator import parse_plan
from grid_calib.core.procedure import GridPlan
from platform_calib.core.procedure import PlatformPlan
from printer_alignment.core.vision_procedure import VisionPlan

# 314 bytes: nine nested aliases of nine, 43 million strings when expanded
ALIAS_BOMB = ('a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + ''.join(
    f'{n}: &{n} [{", ".join([f"*{p}"] * 9)}]\n' for p, n in zip('abcdefg', 'bcdefgh'))
    + 'nx: *h\n')


def test_an_alias_bomb_is_refused_at_once_in_bounded_memory():
    tracemalloc.start()
    start = time.perf_counter()
    with pytest.raises(InvalidInputError, match='aliases') as refused:
        parse_plan(ALIAS_BOMB)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.perf_counter() - start < 1.0 and peak < 10e6
    assert len(str(refused.value)) < 200


@pytest.mark.parametrize('text, named', [
    ('nx: 3\nnx: 4\n', 'nx given twice'),
    ('nx: [' + ', '.join(['1'] * 20000) + ']\n', 'more than the 16384'),
    ('- 1\n- 2\n', 'must be a YAML mapping'),
])
def test_a_request_is_refused_before_anything_is_built(text, named):
    with pytest.raises(InvalidInputError, match=named):
        parse_plan(text)


def test_plan_counts_are_bounded_with_the_bound_in_the_message():
    with pytest.raises(InvalidInputError, match=f'nx x ny = 4000000 positions, more than the '
                                                f'{MAX_COUNT}'):
        VisionPlan(nx=2000, ny=2000)
    with pytest.raises(InvalidInputError, match=f'from 2 to {MAX_COUNT}'):
        VisionPlan(nx=10 ** 12)
    with pytest.raises(InvalidInputError, match='more than the'):
        GridPlan(half=100)
    with pytest.raises(InvalidInputError, match=f'to {MAX_COUNT}'):
        PlatformPlan(poses=1_000_000)
    VisionPlan(nx=50, ny=40)       # 2000 positions: a long run, allowed


def test_a_refusal_quotes_a_short_prefix_of_a_long_value():
    with pytest.raises(InvalidInputError) as refused:
        whole_number(list(range(10 ** 6)), 'nx', 2)
    assert len(str(refused.value)) < BRIEF + 120
    assert 'characters)' in str(refused.value)
