"""The dispenser's vision calibration: Zhang's intrinsics (OpenCV), the stepwise start
(linear axes at a = c = 0, then A alone, then C alone, from each image's board pose), and
all of it refined together by least squares on the reprojection error, with RANSAC over
the images against bad ones (a mis-detected or occluded dot). SI units; residuals in px."""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calib_core.errors import CalibrationError
from calib_core.sanity import SanityGate
from dispenser_calib.core.data import SHIPPED_BOARD, Image, board_points, one_board
from dispenser_calib.core.iso230 import iso230_7_report
from dispenser_calib.core.model import (
    A_NOMINAL, C_NOMINAL, LOOKING_DOWN, NAMES, DispenserModel, _basis, project, project_rows)

ZERO_ANGLE = 1e-9             # rad: a rotary axis at this or less counts as at zero
MIN_DOTS = 6


def _board_of(image: Image) -> np.ndarray:
    """The board positions (k, 3) m of the dots ``image`` saw."""
    board, indices = board_points(image.board)
    where = {tuple(i): k for k, i in enumerate(indices)}
    try:
        return board[[where[tuple(i)] for i in image.indices]]
    except KeyError as exc:
        i, j = (int(v) for v in exc.args[0])
        raise CalibrationError(
            f'{image.name}: dot ({i}, {j}) is not on the {image.board.dots[0]} x '
            f'{image.board.dots[1]} board the dots were named on (indices centred: '
            f'{-((image.board.dots[0] - 1) // 2)}..{image.board.dots[0] // 2} along x): the '
            'data are of another board than declared') from None


def zhang(images: list[Image], image_size) -> tuple[np.ndarray, np.ndarray, list, list]:
    """K (3, 3), distortion (k1, k2, p1, p2) and each image's board pose (R (3, 3), t (3,)
    m) by OpenCV's calibrateCamera on the planar board."""
    objects = [_board_of(im).astype(np.float32) for im in images]
    pixels = [im.pixels.astype(np.float32).reshape(-1, 1, 2) for im in images]
    _, k, dist, rvecs, tvecs = cv2.calibrateCamera(
        objects, pixels, tuple(int(v) for v in image_size), None, None,
        flags=cv2.CALIB_FIX_K3)
    rotations = [cv2.Rodrigues(r)[0] for r in rvecs]
    return k, dist.ravel()[:4], rotations, [t.ravel() for t in tvecs]


def _chordal_mean(rotations: list) -> np.ndarray:
    u, _, vt = np.linalg.svd(np.sum(rotations, axis=0))
    return u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt


def _axis_line(rotation_m, affine, rotations, translations, poses, nominal):
    """A rotary axis's direction and a point on it (board-at-reset frame) from the images
    where only it turned: R_i = R_M R_axis, (I - R_axis) t = R_M^T (t_i - M q_i)."""
    directions, rows, right = [], [], []
    for r, t, pose in zip(rotations, translations, poses):
        turned = rotation_m.T @ r
        vector = cv2.Rodrigues(turned)[0].ravel()
        angle = np.linalg.norm(vector)
        direction = vector / angle
        directions.append(direction if direction @ nominal > 0 else -direction)
        rows.append(np.eye(3) - turned)
        right.append(rotation_m.T @ (t - affine @ np.r_[pose[:3], 1.0]))
    direction = np.mean(directions, axis=0)
    direction /= np.linalg.norm(direction)
    # The point's component along the axis is not observable: the gauge row holds it at 0.
    design = np.vstack(rows + [direction[None]])
    point = np.linalg.lstsq(design, np.concatenate(right + [[0.0]]), rcond=None)[0]
    return direction, point


def _axis_parameters(direction, point, nominal) -> list:
    first, second = _basis(nominal)
    along = direction @ nominal
    return [direction @ first / along, direction @ second / along, point @ first, point @ second]


def stepwise(images: list[Image], image_size) -> DispenserModel:
    """The stepwise start: Zhang, then R_M and M from the linear stops (a = c = 0, at least
    4 not coplanar), then A's line from the images where A alone turned, then C's.

    Raises
    ------
    CalibrationError
        Too few or degenerate stops: coplanar linear stops, a rotary axis that never turns
        (or turns to one angle only), images with too few dots (named)."""
    few = [im.name for im in images if len(im.indices) < MIN_DOTS]
    if few:
        raise CalibrationError(f'images with fewer than {MIN_DOTS} dots (board out of view or '
                               f'out of focus?): {", ".join(few[:5])}')
    k, dist, rotations, translations = zhang(images, image_size)
    poses = np.array([im.pose for im in images])
    at_zero = np.abs(poses[:, 3:]) <= ZERO_ANGLE
    linear = np.flatnonzero(at_zero.all(axis=1))
    only_a = np.flatnonzero(~at_zero[:, 0] & at_zero[:, 1])
    only_c = np.flatnonzero(at_zero[:, 0] & ~at_zero[:, 1])
    q = np.column_stack([poses[linear, :3], np.ones(len(linear))])
    if len(linear) < 4 or np.linalg.matrix_rank(q, tol=1e-6) < 4:
        raise CalibrationError(f'the linear axes need at least 4 stops at a = c = 0 that are '
                               f'not coplanar; got {len(linear)} of rank '
                               f'{np.linalg.matrix_rank(q, tol=1e-6) if len(linear) else 0}')
    for name, rows, column in (('A', only_a, 3), ('C', only_c, 4)):
        if len(np.unique(np.round(poses[rows, column], 9))) < 2:
            raise CalibrationError(f'axis {name} must turn alone to at least two angles other '
                                   f'than 0; the images have {len(rows)} such stop(s)')
    rotation_m = _chordal_mean([rotations[i] for i in linear])
    affine = np.linalg.lstsq(q, np.array([translations[i] for i in linear]), rcond=None)[0].T
    a_line = _axis_line(rotation_m, affine, [rotations[i] for i in only_a],
                        [translations[i] for i in only_a], poses[only_a], A_NOMINAL)
    c_line = _axis_line(rotation_m, affine, [rotations[i] for i in only_c],
                        [translations[i] for i in only_c], poses[only_c], C_NOMINAL)
    tilt = cv2.Rodrigues(rotation_m @ LOOKING_DOWN.T)[0].ravel()
    values = [k[0, 0], k[1, 1], k[0, 2], k[1, 2], *dist, *tilt,
              *affine.ravel(), *_axis_parameters(*a_line, A_NOMINAL),
              *_axis_parameters(*c_line, C_NOMINAL)]
    return DispenserModel(np.array(values, dtype=float))


def reprojection(model: DispenserModel, images: list[Image]) -> list[np.ndarray]:
    """Per image, the observed minus projected pixels (k, 2) of the dots' ellipse centres
    (each dot a circle of its board's radius), as a detector finds them."""
    return [im.pixels - project(model, _board_of(im), im.pose[None], im.board.radius)[0]
            for im in images]


@dataclass
class Refinement:
    """The refined model, the parameters' covariance, the mean reprojection error per
    iteration (px), the images used and those RANSAC set aside (with their error, px)."""

    model: DispenserModel
    covariance: np.ndarray
    history: list
    inliers: list
    outliers: dict = field(default_factory=dict)

    @property
    def std_devs(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def report(self, images: list[Image]) -> dict:
        errors = reprojection(self.model, images)
        per_image = {im.name: float(np.sqrt(np.mean(e ** 2))) for im, e in zip(images, errors)}
        used = np.concatenate([errors[k] for k, im in enumerate(images) if im.name in self.inliers])
        return {'parameters': dict(zip(NAMES, map(float, self.model.values))),
                'std_devs': dict(zip(NAMES, map(float, self.std_devs))),
                'mean_reprojection_px': float(np.mean(np.linalg.norm(used, axis=1))),
                'rms_reprojection_px': float(np.sqrt(np.mean(used ** 2))),
                'per_image_rms_px': per_image, 'history_mean_px': self.history,
                'bad_images': self.outliers, 'images_used': len(self.inliers),
                'iso230_7': iso230_7_report(self.model, self.covariance),
                'gauge': 'the points t_a, t_c are held perpendicular to their axes (a '
                         'point\'s place along a rotary axis is not observable)'}


def refine(start: DispenserModel, images: list[Image], max_iterations: int = 50,
           pose_sigma=None) -> Refinement:
    """All parameters together by least squares on the reprojection error (trust-region
    reflective), from ``start``; the mean reprojection recorded per iteration. Each dot is
    projected as the centre of its circle's image (its board's radius, m), which is what a
    dot detector finds under perspective, not the image of the dot's centre.

    The covariance takes the dots' noise from the residual and, given ``pose_sigma`` (5,)
    (m, rad, 1 sigma: how far each axis stops from its reading, a machine description's),
    that noise too: it moves every dot of an image together, so unlike the dots' own noise
    it does not average out over an image's dots (:func:`_pose_noise_information`)."""
    dot_radius = one_board(images).radius
    points = np.concatenate([_board_of(im) for im in images])
    poses = np.concatenate([np.repeat(im.pose[None], len(im.indices), 0) for im in images])
    observed = np.concatenate([im.pixels for im in images])
    scale = np.maximum(np.abs(start.values), 1e-3)

    def residual(x):
        r = (project_rows(DispenserModel(x * scale), points, poses, dot_radius) - observed).ravel()
        return np.where(np.isfinite(r), r, 1e6)

    history = [float(np.mean(np.linalg.norm(residual(start.values / scale).reshape(-1, 2),
                                            axis=1)))]

    def record(intermediate_result):
        history.append(float(np.mean(np.linalg.norm(intermediate_result.fun.reshape(-1, 2),
                                                    axis=1))))
    # Imported here: scipy.optimize costs 0.4 s, and a command's --help should not wait.
    from scipy.optimize import least_squares
    solution = least_squares(residual, start.values / scale, method='trf', x_scale='jac',
                             xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=max_iterations,
                             callback=record)
    model = DispenserModel(solution.x * scale)
    dof = max(solution.fun.size - len(NAMES), 1)
    variance = float(solution.fun @ solution.fun) / dof
    # In the scaled variables the normal matrix is well conditioned; scale back after.
    jacobian = solution.jac
    inverse = np.linalg.inv(jacobian.T @ jacobian)
    covariance = inverse * variance
    if pose_sigma is not None and np.any(np.asarray(pose_sigma) > 0):
        counts = [2 * len(im.indices) for im in images]
        meat = _pose_noise_information(model, points, poses, dot_radius, jacobian, counts,
                                       np.asarray(pose_sigma, dtype=float))
        covariance = covariance + inverse @ meat @ inverse
    return Refinement(model, covariance * np.outer(scale, scale), history,
                      [im.name for im in images])


def _pose_noise_information(model: DispenserModel, points, poses, dot_radius, jacobian,
                            counts: list, pose_sigma: np.ndarray) -> np.ndarray:
    """J^T N J (p, p) of the axes' stopping noise ``pose_sigma`` (5,) m, rad: within an
    image of ``counts`` rows its residuals move together as D S D^T, D (rows, 5) the
    pixels' derivatives by the image's pose (central differences) and S the noise's
    variances; none between images. ``jacobian`` (rows, p) in the fit's variables."""
    step = 1e-6
    along = np.column_stack([
        (project_rows(model, points, poses + step * e, dot_radius)
         - project_rows(model, points, poses - step * e, dot_radius)).ravel() / (2 * step)
        for e in np.eye(5)])
    meat = np.zeros((jacobian.shape[1],) * 2)
    for rows in np.split(np.arange(len(jacobian)), np.cumsum(counts)[:-1]):
        moved = along[rows].T @ jacobian[rows]                        # (5, p)
        meat += moved.T @ (pose_sigma[:, None] ** 2 * moved)
    return meat


def calibrate(images: list[Image], image_size, threshold_px: float | None = None,
              trials: int = 8, seed: int = 0,
              pose_sigma=None) -> tuple[DispenserModel, Refinement]:
    """Stepwise start, then RANSAC over the images: refine on random subsets of 60 % of
    them, count as inliers the images whose RMS reprojection is below the threshold
    (default: 5 x the median image's, at least 0.5 px), keep the largest consensus and
    refine on it (its covariance with the axes' ``pose_sigma``, :func:`refine`). Returns
    the stepwise model and the refinement."""
    start = stepwise(images, image_size)
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(trials):
        subset = sorted(rng.choice(len(images), max(int(0.6 * len(images)), 6), replace=False))
        trial = refine(start, [images[k] for k in subset], max_iterations=4)
        errors = np.array([np.sqrt(np.mean(e ** 2)) for e in reprojection(trial.model, images)])
        limit = threshold_px or max(0.5, 5 * np.median(errors))
        inliers = np.flatnonzero(errors < limit)
        if best is None or len(inliers) > len(best[0]) or (
                len(inliers) == len(best[0]) and errors[inliers].mean() < best[1]):
            best = (inliers, errors[inliers].mean(), errors, limit)
        if len(inliers) == len(images):
            break
    inliers, _, errors, limit = best
    result = refine(start, [images[k] for k in inliers], pose_sigma=pose_sigma)
    final = np.array([np.sqrt(np.mean(e ** 2)) for e in reprojection(result.model, images)])
    result.outliers = {images[k].name: float(final[k]) for k in range(len(images))
                       if k not in set(inliers)}
    return start, result


# The gate before a calibration is written or put in force. Dots detected to subpixel give
# a few tenths of a pixel (the simulated dispenser: 0.1 px); an RMS of 3 px is a model that
# does not describe the images.
MAX_REPROJECTION_RMS_PX = 3.0
# M maps the linear axes (m) into the camera frame: a rotation times scale errors of at
# most a few parts per thousand on any real axis. Its singular values far from 1 mean axes
# read in another unit (mm: 0.001).
MAX_AXIS_SCALE_ERROR = 0.05


def check_calibration(model: DispenserModel, report: dict, description=None,
                      causes: str | None = None) -> None:
    """Refuse a calibration that cannot be the machine: reprojection RMS above
    :data:`MAX_REPROJECTION_RMS_PX` (with a ``description``,
    :class:`dispenser_calib.core.description.FiveAxisDescription`, above its limit from the
    declared noise), a linear-axis scale beyond :data:`MAX_AXIS_SCALE_ERROR` (singular
    values of M's 3 x 3 part), a standard deviation that is not finite. ``report`` is the
    refinement's :meth:`Refinement.report`; ``causes`` the likely causes of a residual
    above the limit, most likely first.

    Raises
    ------
    CalibrationError
        Every failure named; nothing may be written."""
    gate = SanityGate('the five-axis calibration')
    if description is None:
        limit, expected = MAX_REPROJECTION_RMS_PX, ('dots detected to subpixel reproject '
                                                    'within a few tenths of a pixel')
    else:
        limit, expected = description.residual_limit_px(), description.expected_text()
    gate.residual(report['rms_reprojection_px'], limit, 'px', expected,
                  *(() if causes is None else (causes,)))
    units = ('axes read in m; 0.001 means mm' if description is None else
             f'axes read in {description.linear_unit}; 1000x or 0.001 is another unit')
    scales = np.linalg.svd(model.affine[:, :3], compute_uv=False)
    common = float(np.median(scales))
    if (np.ptp(scales) < 0.01 * common and not abs(common - 1) <= MAX_AXIS_SCALE_ERROR
            and 0.1 < common < 10):
        # All three axes off alike, and not by a unit: the camera measured the board at
        # another size than declared (the same image, a board that much smaller or larger
        # at that much less or more distance), or every axis's lead is off alike.
        pitch = (description.board if description is not None else SHIPPED_BOARD).pitch
        units += (f'; all three alike: a board of another pitch than the declared '
                  f'{pitch * 1e3:.4g} mm (the axes fit {pitch / common * 1e3:.4g} mm), or '
                  'every axis\'s lead off alike')
    for k, value in enumerate(scales):
        gate.within(f'linear-axis scale {k + 1} (singular value of M)', value,
                    1 - MAX_AXIS_SCALE_ERROR, 1 + MAX_AXIS_SCALE_ERROR, '', units)
    gate.finite_std_devs(report['std_devs'])
    gate.enforce()
