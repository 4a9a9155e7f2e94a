"""Mark detection in the scenes a camera at a machine sees (issue 55), on frames rendered
with exact centres by test/scenes.py: every dot found, nothing else, the centres within
1.1x the Cramer-Rao bound, on several seeds. The plate on a light table and in a round
field of view found no dot before each region too large to be a Mark was cut at a level
of its own."""
import cv2
import numpy as np
import pytest

from calib_core.errors import DetectionError
from calib_core.marks import detect_marks
from calib_core.sim.render import MarkShape, render
from machine_alignment.bench.vision import CONTRAST, cramer_rao
from calib_core.sim.scenes import (
    BLUR, DOT, NOISE, PLATE, RADIUS, disk_coverage, dot_plate, uneven_light)

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
                                  'uneven', 'cable', 'hot_spot'])
def test_every_dot_found_within_the_bound(kind):
    errors = np.concatenate([_errors(kind, seed) for seed in SEEDS])
    bound = _bound(BLUR)
    if kind == 'uneven':        # each dot's contrast is its light's share of the plate's
        u = np.concatenate([dot_plate(kind, seed)[1][:, 0] for seed in SEEDS])
        bound *= np.sqrt(np.mean(uneven_light(u, 640) ** -2))
    ok, numbers = _within(errors, bound)
    assert ok, (kind, numbers)


def _fading_dot(rng, centre, fade: float) -> np.ndarray:
    """A 100 x 120 frame (uint8) of one 12 px dot at ``centre`` (px) whose contrast falls
    linearly across it by ``fade`` of itself (a glare over one side; none left where it
    exceeds 1), the plate's level unchanged, the scenes' blur and noise."""
    radius = 12.0
    columns = np.mgrid[0:100, 0:120][1].astype(float)
    share = np.clip(1 - fade * np.clip((centre[0] + radius - columns) / (2 * radius), 0, 1),
                    0, 1)
    frame = PLATE - (PLATE - DOT) * disk_coverage((100, 120), centre[None], radius) * share
    frame = cv2.GaussianBlur(frame, (0, 0), BLUR) + rng.normal(0, NOISE, frame.shape)
    return np.clip(np.round(frame), 0, 255).astype(np.uint8)


def _unbiased_with_honest_sigmas(errors, z) -> None:
    """Centre errors (n, 2; px) whose mean is within 3 standard errors of zero, and whose
    ratios ``z`` (n, 2) to their stated sigmas have an RMS of 0.6-1.5."""
    errors, z = np.array(errors), np.array(z)
    standard_error = np.sqrt(np.mean(errors ** 2, axis=0) / len(errors))
    assert np.all(np.abs(errors.mean(axis=0)) < 3 * standard_error), errors.mean(axis=0)
    assert 0.6 < np.sqrt(np.mean(z ** 2)) < 1.5, np.sqrt(np.mean(z ** 2))


def test_a_highlight_beside_a_dot_moves_it_by_no_more_than_its_stated_sigma():
    """The hot spot's dot (the ninth) and its neighbour (the tenth, 45 px on), whose plain
    fits were 0.41 and 0.09 px off, over 12 seeds: their mean error within 3 standard
    errors of zero, and their errors over their stated sigmas of unit RMS (0.6-1.5): the
    local fit's covariance, not the plain one's, is reported. The other dots keep the
    plain fit's sigma (within 10 % of the clean plate's)."""
    z, errors, others = [], [], []
    for seed in range(12):
        frame, truth = dot_plate('hot_spot', seed)
        marks = detect_marks(frame).marks
        found = np.array([[m.u, m.v] for m in marks])
        nearest = np.linalg.norm(found[:, None] - truth[None], axis=2).argmin(axis=0)
        for dot in (8, 9):
            mark = marks[nearest[dot]]
            error = found[nearest[dot]] - truth[dot]
            errors.append(error)
            z.append(error / np.sqrt(np.diag(mark.covariance)))
        others += [marks[nearest[i]].sigma_px for i in range(len(truth)) if i not in (8, 9, 14)]
    _unbiased_with_honest_sigmas(errors, z)
    clean = [m.sigma_px for m in detect_marks(dot_plate('plain', 0)[0]).marks]
    assert abs(np.median(others) / np.median(clean) - 1) < 0.1


@pytest.mark.parametrize('fade', [0.3, 0.6, 0.9])
def test_a_dot_fading_across_itself_is_measured_within_its_sigma(fade):
    """A 12 px dot whose contrast falls linearly across it by ``fade`` of itself (a glare
    over one side; the plate's level unchanged), 1 px blur, 2 grey levels of noise: the
    centre within 3 of its stated sigmas on 6 seeds, their mean within 3 standard errors.
    The plain fit's light multiplies the plate with the dot, so it could not: 0.29 px off
    (20 sigma) at 0.3; at 0.9 it took the fade for a 1.7 px blur, 3.6 px off at a stated
    0.09 px. The local fit without the edge's shift by the blur of the varying contrast
    (local_fit._local_columns) was 0.04 px off at 0.6 (mean error over sigma -2.0 here,
    largest 3.5)."""
    rng = np.random.default_rng(5)
    z = []
    for _ in range(6):
        centre = np.array([60.0, 50.0]) + rng.uniform(-0.5, 0.5, 2)
        mark = detect_marks(_fading_dot(rng, centre, fade), expected_count=1).marks[0]
        z.append((np.array([mark.u, mark.v]) - centre) / np.sqrt(np.diag(mark.covariance)))
    assert np.all(np.abs(z) < 3), z
    assert np.all(np.abs(np.mean(z, axis=0)) < 3 / np.sqrt(len(z))), np.mean(z, axis=0)


def test_a_lone_dot_beside_the_hot_spot_is_found_and_measured_within_its_sigma():
    """The hot spot over the edge of the only dot in view (a fiducial under a glare), 10
    seeds: found in each, nothing else, its errors over its stated sigmas of unit RMS and
    its mean within 3 standard errors. Otsu's level had split the highlight, which
    outnumbers the dot's pixels, off the plate: no Mark in any of them."""
    errors, z = [], []
    for seed in range(10):
        frame, truth = dot_plate('hot_spot', seed, columns=1, rows=1)
        mark, = detect_marks(frame, expected_count=1).marks
        error = np.array([mark.u, mark.v]) - truth[0]
        errors.append(error)
        z.append(error / np.sqrt(np.diag(mark.covariance)))
    _unbiased_with_honest_sigmas(errors, z)


def test_a_highlight_beside_a_dot_seen_at_an_angle_leaves_its_centre():
    """A 3 x 3 grid of 12 px dots seen at an angle (ellipses of aspect 1.6, fitted as
    such), a highlight of 60 grey levels beside the middle one: over 8 seeds its errors
    over its stated sigmas of unit RMS (0.6-1.5) and its mean within 3 standard errors.
    The plain fit had left it 0.3 px off, 11 sigma."""
    rng = np.random.default_rng(2)
    rows, columns = np.mgrid[0:240, 0:280]
    errors, z = [], []
    for _ in range(8):
        dots = [MarkShape('circle', 80 + 60 * i + rng.uniform(-0.5, 0.5),
                          70 + 50 * j + rng.uniform(-0.5, 0.5), 12.0, angle=0.6, aspect=1.6)
                for j in range(3) for i in range(3)]
        middle = dots[4]
        frame = render(dots, 280, 240, BLUR, PLATE, DOT - PLATE) + 60.0 * np.exp(
            -((columns - middle.u - 16) ** 2 + (rows - middle.v - 6) ** 2) / (2 * 12.5 ** 2))
        frame = frame + rng.normal(0, NOISE, frame.shape)
        marks = detect_marks(np.clip(np.round(frame), 0, 255).astype(np.uint8),
                             expected_count=9).marks
        mark = min(marks, key=lambda m: np.hypot(m.u - middle.u, m.v - middle.v))
        error = np.array([mark.u - middle.u, mark.v - middle.v])
        errors.append(error)
        z.append(error / np.sqrt(np.diag(mark.covariance)))
    _unbiased_with_honest_sigmas(errors, z)


def test_a_dot_washed_out_on_one_side_is_refused_naming_it():
    """The dot above faded by 1.6 of its contrast: a third of it is gone under the glare.
    What is left is no dot's shape; the refusal names that it may be one washed out."""
    frame = _fading_dot(np.random.default_rng(6), np.array([60.2, 50.4]), 1.6)
    with pytest.raises(DetectionError, match='washed out on one side'):
        detect_marks(frame)


@pytest.mark.parametrize('centre', [(160, 120), (480, 360), (320, 100), (120, 300)])
def test_a_plate_smaller_than_the_frame_anywhere_in_it(centre):
    """A plate of 3 x 2 dots on a dark table, here and there in the frame."""
    errors = np.concatenate([_errors('small_plate', seed, columns=3, rows=2, centre=centre)
                             for seed in SEEDS])
    ok, numbers = _within(errors, _bound(BLUR))
    assert ok, numbers


def test_a_defocused_plate_on_a_light_table():
    """Blur 2.5 px, 12 frames (the allowance for chance 6 %, not the 10 % of 4): fitted on
    the 6 px band alone, its edge cut short at 2.4 sigma, the centres were 1.22x the
    bound (the band's own bound: 1.25x); on a band that holds the edge, 1.03x."""
    errors = np.concatenate([_errors('light_table', seed, blur=2.5) for seed in range(12)])
    ok, numbers = _within(errors, _bound(2.5))
    assert ok, numbers


def _block_means(kind: str) -> np.ndarray:
    import cv2
    from calib_core.marks.config import TREND_BLOCK_PX
    from calib_core.marks.trend import tile_means
    frame, _ = dot_plate(kind, 0)
    scaled = cv2.normalize(frame, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    return tile_means(cv2.GaussianBlur(scaled, (5, 5), 1.0), TREND_BLOCK_PX)


@pytest.mark.parametrize('kind, step', [('light_table', 'inside'), ('plain', None),
                                        ('uneven', None), ('cable', None),
                                        ('shadow', 'across')])
def test_a_plate_inside_a_surround_and_a_shadow_are_steps_and_light_is_not(kind, step):
    """The flattening is not fitted across a plate's edge (it warped the plate on a light
    table and left its corners as blobs): a plate inside its surround is a step inside
    the frame, a shadow's edge one across it; uneven light, a cable across the plate and
    a plate filling the view are none."""
    from calib_core.marks.segmentation import _step
    assert _step(_block_means(kind)) == step


def test_blocks_in_two_classes_are_a_step_across_only_in_one_piece():
    """Block means in two well-parted classes that both reach the frame's border: half
    the field in shadow is a step across it; blocks with and without a grid's dots,
    scattered alike (a checkerboard: every neighbour differs), are none, and keep the
    quadratic flattening."""
    from calib_core.marks.segmentation import _step
    shadow = np.full((30, 40), 200.0)
    shadow[:, :20] = 60.0
    assert _step(shadow) == 'across'
    grid = np.where(np.add.outer(np.arange(30), np.arange(40)) % 2, 200.0, 120.0)
    assert _step(grid) is None
    plate = np.full((30, 40), 230.0)          # a darker plate inside a light table
    plate[6:24, 8:32] = 120.0
    assert _step(plate) == 'inside'


def test_a_shadow_over_a_third_of_the_plate():
    """The scenes' shadow (30 % of the light beyond an edge a pitch right of the plate's
    centre): every dot found and nothing else, on 4 seeds, the errors over their stated
    sigmas of RMS 0.6-1.5 (1.07 in the light, 1.18 in the shadow over 10 seeds: the
    edge's tail, 2 % of the light 7 px from it, reaches the windows of the dots beside
    it, 0.02-0.04 px off). The quadratic flattening could not take up the step: the
    shadowed dots were lost, 16 of 24 found in every frame."""
    z = []
    for seed in SEEDS:
        frame, truth = dot_plate('shadow', seed)
        marks = detect_marks(frame).marks
        found = np.array([[m.u, m.v] for m in marks])
        distance = np.linalg.norm(found[:, None] - truth[None], axis=2)
        assert len(found) == len(truth) and np.all(distance.min(axis=1) < 1.0), seed
        for mark, error in zip(marks, found - truth[distance.argmin(axis=1)]):
            z.append(error / np.sqrt(np.diag(mark.covariance)))
    assert 0.6 < np.sqrt(np.mean(np.square(z))) < 1.5
