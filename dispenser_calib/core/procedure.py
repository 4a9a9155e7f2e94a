"""The dispenser's calibration run: the stepwise plan (linear stops, A alone, C alone), the
strokes every stop is checked against before anything moves, and the run itself with the
hardware passed in as callables (the node, the tests and the offline replay run the same
code). The calibration is evaluated on held-out images at poses where A and C both turn,
which the stepwise plan never visits."""
from __future__ import annotations

from typing import Callable

import numpy as np

from dispenser_calib.core.calibration import calibrate, reprojection
from dispenser_calib.core.data import Image
from dispenser_calib.core.model import DispenserModel, place
from dispenser_calib.errors import StrokeError

WORKING_DISTANCE = 0.120        # m, the camera to the board's centre
STROKES = {'x': (-0.200, 0.200), 'y': (-0.150, 0.150), 'z': (-0.050, 0.050),
           'a': (-np.pi / 2, np.pi / 2), 'c': (-2 * np.pi, 2 * np.pi)}


def check_stroke(pose: np.ndarray, strokes: dict = STROKES) -> None:
    """Refuse a pose (5,) outside an axis's stroke (m, rad).

    Raises
    ------
    StrokeError"""
    for value, (name, (low, high)) in zip(pose, strokes.items()):
        if not low <= value <= high:
            raise StrokeError(f'{name} = {value:.6g} is outside the stroke {low:.6g}..{high:.6g}; '
                              'nothing moved')


def plan_stops(nominal: DispenserModel, seed: int = 0) -> np.ndarray:
    """The stepwise plan (n, 5): 12 linear stops (a = c = 0, not coplanar), A alone at
    -60, -30, 30, 60 degrees, C alone every 30 degrees; each aimed (nominal model) so the
    board's centre is on the optical axis at the working distance, then moved a little."""
    rng = np.random.default_rng(seed + 50)
    centre = np.array([0.0, 0.0, WORKING_DISTANCE])
    stops = []
    for _ in range(12):
        pose = place(nominal, np.zeros(3), 0.0, 0.0, centre)
        stops.append(pose + np.r_[rng.uniform(-3e-3, 3e-3, 2), rng.uniform(-4e-3, 4e-3), 0, 0])
    for a in np.deg2rad([-60, -30, 30, 60]):
        stops.append(place(nominal, np.zeros(3), a, 0.0, centre))
    for c in np.deg2rad(np.arange(30, 360, 30)):
        stops.append(place(nominal, np.zeros(3), 0.0, c, centre))
    return np.array(stops)


def evaluation_stops(nominal: DispenserModel, count: int, seed: int = 0) -> np.ndarray:
    """``count`` held-out stops with A and C both turned (a within +-45 degrees)."""
    rng = np.random.default_rng(seed + 70)
    centre = np.array([0.0, 0.0, WORKING_DISTANCE])
    return np.array([place(nominal, np.zeros(3), rng.uniform(-0.8, 0.8), rng.uniform(0, 2 * np.pi),
                           centre) for _ in range(count)])


def run_five_axis_calibration(nominal: DispenserModel, image_size, seed: int, evaluation: int,
                              move: Callable[[np.ndarray], np.ndarray],
                              capture: Callable[[], tuple],
                              record: Callable[[Image, str], None] = lambda *a: None,
                              progress: Callable[[int, int, str], None] = lambda *a: None):
    """Plan, check every stop, drive, image, calibrate (RANSAC), evaluate on the held-out
    stops. ``move(pose)`` returns the pose the encoders report; ``capture()`` the dots'
    (indices (k, 2), pixels (k, 2)). Returns (the refinement, its report with the held-out
    evaluation, the images).

    Raises
    ------
    StrokeError
        A planned stop outside a stroke (before anything moves)."""
    stops = plan_stops(nominal, seed)
    held_out = evaluation_stops(nominal, evaluation, seed)
    for pose in np.vstack([stops, held_out]):
        check_stroke(pose)
    total = len(stops) + len(held_out) + 1
    images, evaluation_images = [], []
    for phase, poses, out in (('calibrate', stops, images), ('evaluate', held_out,
                                                               evaluation_images)):
        for pose in poses:
            reached = np.asarray(move(pose), dtype=float)
            indices, pixels = capture()
            out.append(Image(f'{phase}{len(out):03d}', reached, np.asarray(indices, int),
                             np.asarray(pixels, float)))
            record(out[-1], phase)
            progress(len(images) + len(evaluation_images), total,
                     f'{phase} image {len(out)}: {len(indices)} dots')
    return finish(nominal, image_size, images, evaluation_images)


def finish(nominal: DispenserModel, image_size, images: list, evaluation_images: list):
    """Calibrate on ``images`` and evaluate on the held-out ``evaluation_images``: the
    reprojection RMS with the calibrated and with the nominal model (px), over the held-out
    images that are not bad themselves (RANSAC's rule: over 5 x the median image's RMS and
    0.5 px; those are named)."""
    _, result = calibrate(images, image_size)
    report = result.report(images)
    if evaluation_images:
        per_image = [np.sqrt(np.mean(e ** 2)) for e in reprojection(result.model, evaluation_images)]
        limit = max(0.5, 5 * float(np.median(per_image)))
        good = [im for im, e in zip(evaluation_images, per_image) if e < limit]

        def rms(model):
            return float(np.sqrt(np.mean(np.concatenate(reprojection(model, good)) ** 2)))
        report['held_out'] = {'images': len(good), 'rms_px_calibrated': rms(result.model),
                              'rms_px_nominal': rms(nominal),
                              'bad_images': [im.name for im, e in zip(evaluation_images, per_image)
                                             if e >= limit]}
    return result, report, images
