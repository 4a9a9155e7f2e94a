"""Mark detection in the scenes a camera at a machine sees (issue 55), on frames rendered
with exact centres by test/scenes.py: every dot found, nothing else, the centres within
1.1x the Cramer-Rao bound, on several seeds. The plate on a light table and in a round
field of view found no dot before each region too large to be a Mark was cut at a level
of its own."""
import numpy as np
import pytest

from calib_core.marks import detect_marks
from calib_core.sim.render import MarkShape
from machine_alignment.bench.vision import CONTRAST, cramer_rao
from calib_core.sim.scenes import BLUR, DOT, NOISE, PLATE, RADIUS, dot_plate, uneven_light

SEEDS = range(4)


def _within(errors: np.ndarray, bound: float) -> bool:
    """The centres' per-axis RMS within 1.1x ``bound``, allowing two standard errors of an
    RMS over n values (2 / sqrt(2 n)): 10 % for 96 dots (192 values)."""
    rms = np.sqrt(np.mean(errors ** 2))
    return rms < 1.1 * bound * (1 + 2 / np.sqrt(2 * errors.size)), (rms, bound)


def _bound(blur: float) -> float:
    """Per-axis Cramer-Rao bound (px) of one of the scenes' dots: the bench's, for their
    contrast (the bound scales with noise over contrast)."""
    return cramer_rao(MarkShape('circle', 100.0, 100.0, RADIUS), blur, NOISE) \
        * abs(CONTRAST) / (PLATE - DOT)


def _errors(kind: str, seed: int, **scene) -> np.ndarray:
    """Each dot's centre error (k, 2) px; fails unless every dot is found and nothing
    else."""
    frame, truth = dot_plate(kind, seed, **scene)
    marks = detect_marks(frame).marks
    found = np.array([[m.u, m.v] for m in marks])
    distance = np.linalg.norm(found[:, None] - truth[None], axis=2)
    assert len(found) == len(truth), f'{kind}, seed {seed}: {len(found)} of {len(truth)}'
    assert np.all(distance.min(axis=1) < 1.0), f'{kind}, seed {seed}: a Mark off every dot'
    return (found[distance.argmin(axis=0)] - truth)


@pytest.mark.parametrize('kind', ['plain', 'dark_table', 'light_table', 'round_view',
                                  'uneven', 'cable'])
def test_every_dot_found_within_the_bound(kind):
    errors = np.concatenate([_errors(kind, seed) for seed in SEEDS])
    bound = _bound(BLUR)
    if kind == 'uneven':        # each dot's contrast is its light's share of the plate's
        u = np.concatenate([dot_plate(kind, seed)[1][:, 0] for seed in SEEDS])
        bound *= np.sqrt(np.mean(uneven_light(u, 640) ** -2))
    ok, numbers = _within(errors, bound)
    assert ok, (kind, numbers)


@pytest.mark.parametrize('centre', [(160, 120), (480, 360), (320, 100), (120, 300)])
def test_a_plate_smaller_than_the_frame_anywhere_in_it(centre):
    """A plate of 3 x 2 dots on a dark table, here and there in the frame."""
    errors = np.concatenate([_errors('small_plate', seed, columns=3, rows=2, centre=centre)
                             for seed in SEEDS])
    ok, numbers = _within(errors, _bound(BLUR))
    assert ok, numbers


def test_a_defocused_plate_on_a_light_table():
    errors = np.concatenate([_errors('light_table', seed, blur=2.5) for seed in SEEDS])
    ok, numbers = _within(errors, _bound(2.5))
    assert ok, numbers

