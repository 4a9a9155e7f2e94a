"""Measured target poses: a target's 6-DOF pose in an instrument that stays put (a camera
beside the machine, a laser tracker, or the dispenser's own camera with the linear axes
held), per pose of the tilting-rotary table. The CSV contract of ``machine-align analyze
rotary``, and the board's pose in each of the dispenser's images with its covariance."""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calib_core.datasets import read_columns, write_columns
from calib_core.description import ANGLE_UNITS, LENGTH_UNITS, si_per_unit
from calib_core.errors import CalibrationError, InvalidInputError, UnitMistake
from dispenser_calib.core.data import board_points, one_board
from dispenser_calib.core.model import DispenserModel, distort, dot_centres

POSE_COLUMNS = ('x', 'y', 'z', 'qw', 'qx', 'qy', 'qz')


@dataclass(frozen=True)
class TargetPoses:
    """Measured target poses: table angles ``a``, ``c`` (n,) rad; the instrument-to-target
    rotation (n, 3, 3) and translation (n, 3) m (a target point p is at R p + t); other
    numeric columns (time in s, temperature in K) as covariates; optionally each pose's
    measurement covariance (n, 6, 6) of (translation m, rotation error vector rad, in the
    instrument frame: R = exp([w]) R_true), with which residuals are weighted."""

    a: np.ndarray
    c: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    covariates: dict = field(default_factory=dict)
    covariance: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.a)

    def subset(self, rows) -> 'TargetPoses':
        return TargetPoses(self.a[rows], self.c[rows], self.rotation[rows],
                           self.translation[rows],
                           {k: np.asarray(v)[rows] for k, v in self.covariates.items()},
                           None if self.covariance is None else self.covariance[rows])


def read_target_poses(path, a_column: str = 'a', c_column: str = 'c', angle_unit: str = 'rad',
                      length_unit: str = 'm') -> TargetPoses:
    """Poses from a CSV: ``a_column``, ``c_column`` (rad, or ``angle_unit``: deg), ``x, y,
    z`` (m, or ``length_unit``: mm, um, inch; the target's origin in the instrument frame),
    ``qw, qx, qy, qz`` (the instrument-to-target rotation); other numeric columns are kept
    as covariates.

    Raises
    ------
    InvalidInputError
        Missing columns, non-numbers, NaN, a quaternion far from unit length (a column in
        the wrong order or mm for m in the wrong place)."""
    columns = read_columns(path, [a_column, c_column, *POSE_COLUMNS])
    quaternion = np.column_stack([columns[k] for k in ('qx', 'qy', 'qz', 'qw')])
    norm = np.linalg.norm(quaternion, axis=1)
    if np.any(np.abs(norm - 1) > 1e-3):
        line = int(np.argmax(np.abs(norm - 1) > 1e-3)) + 2
        raise InvalidInputError(f'{path} line {line}: the quaternion qw, qx, qy, qz has norm '
                                f'{norm[line - 2]:.6g}, not 1')
    translation = np.column_stack([columns[k] for k in ('x', 'y', 'z')]) * si_per_unit(
        length_unit, LENGTH_UNITS, f'{path}: the length unit')
    per_angle = si_per_unit(angle_unit, ANGLE_UNITS, f'{path}: the angle unit')
    angles = {name: columns[name] * per_angle for name in (a_column, c_column)}
    if np.max(np.abs(translation)) > 100:
        raise UnitMistake(f'{path}: target positions up to {np.max(np.abs(translation)):.4g} m:'
                          ' the columns x, y, z must be in m (mm given?)', 'length', 'mm')
    for name, values in angles.items():
        if np.max(np.abs(values)) > 4 * np.pi:
            raise UnitMistake(f'{path}: {name} reaches {np.max(np.abs(values)):.4g} rad: '
                              'angles must be in rad (degrees given?)', 'angle', 'deg', name)
    used = {a_column, c_column, *POSE_COLUMNS}
    return TargetPoses(angles[a_column], angles[c_column],
                       Rotation.from_quat(quaternion / norm[:, None]).as_matrix(), translation,
                       {k: v for k, v in columns.items() if k not in used})


def poses_from_images(model: DispenserModel, images: list, covariates: dict | None = None
                      ) -> TargetPoses:
    """The board's pose in each image (OpenCV's solvePnP with ``model``'s intrinsics and
    distortion, then fitted to the dots' ellipse centres) with its covariance, as target
    poses for the rotary axes: the dispenser's camera is the instrument, which stays put if
    the linear axes do. ``covariates`` per image (name -> (n,): ``time`` s, ``temperature``
    K), optional. The covariance matters: a small
    board seen from close by fixes its turn about the optical axis far better than its
    tilts, and only the weighted residuals show an angle error of C below the tilts' noise.

    Raises
    ------
    CalibrationError
        The linear axes moved between the images, or an image with fewer than 6 dots."""
    return _poses_and_fits(model, images, covariates)[0]


def _poses_and_fits(model: DispenserModel, images: list, covariates: dict | None):
    """:func:`poses_from_images` and, per image, what a pose's change is computed from:
    (its dots (k, 3) m, pixels (k, 2), the fitted rotation (3, 3) and translation (3,),
    the fit's Jacobian (2 k, 6) by (rotation vector, translation))."""
    linear = np.array([im.pose[:3] for im in images])
    if np.ptp(linear, axis=0).max() > 1e-9:
        raise CalibrationError('the linear axes moved between the images (by up to '
                               f'{np.ptp(linear, axis=0).max() * 1e3:.4g} mm): the rotary axes '
                               'from board poses need them held')
    board = one_board(images)
    dots, indices = board_points(board)
    where = {tuple(i): k for k, i in enumerate(indices)}
    distortion = np.r_[model.distortion, 0.0]
    rotations, translations, covariances, fits = [], [], [], []
    for im in images:
        if len(im.indices) < 6:
            raise CalibrationError(f'{im.name}: {len(im.indices)} dots, a board pose needs 6')
        points = dots[[where[tuple(i)] for i in im.indices]]
        # Ellipse centres, as the calibration projects them, are not the dots' images:
        # start from PnP on the centres, then fit the pose to the ellipse centres.
        _, rvec, tvec = cv2.solvePnP(points, im.pixels, model.camera_matrix, distortion,
                                     flags=cv2.SOLVEPNP_ITERATIVE)
        rotation, translation, covariance, jacobian = _fit_board_pose(
            model, points, im.pixels, rvec.ravel(), tvec.ravel(), board.radius)
        rotations.append(rotation)
        translations.append(translation)
        covariances.append(covariance)
        fits.append((points, im.pixels, rotation, translation, jacobian))
    poses = np.array([im.pose for im in images])
    covariates = {name: np.asarray(v, float) for name, v in (covariates or {}).items()}
    return (TargetPoses(poses[:, 3], poses[:, 4], np.array(rotations), np.array(translations),
                        covariates, np.array(covariances)), fits)


def pose_variants(model: DispenserModel, covariance: np.ndarray, images: list,
                  covariates: dict | None = None, floor: float = 1e-9):
    """A callable giving :func:`poses_from_images` of ``images`` through each one-sigma
    variant of the calibration ``model`` with its parameters' ``covariance`` (31, 31), one
    per column of a square root of it (the correlation's eigenvectors, those above
    ``floor`` of the largest eigenvalue), for the closed loop to weigh an effect against
    what the calibration's own error gives
    (:meth:`dispenser_calib.core.loop_model.RotaryLoopModel.input_variants`). Computed when
    called: 31 pose fits or fewer."""
    covariance = np.asarray(covariance, dtype=float)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    scale = np.where(sigma > 0, sigma, 1.0)
    values, vectors = np.linalg.eigh(covariance / np.outer(scale, scale))
    kept = values > floor * values.max()
    root = scale[:, None] * vectors[:, kept] * np.sqrt(values[kept])

    radius = one_board(images).radius

    def variants() -> list:
        # Each pose's change to first order: one Gauss-Newton step from the pose fitted
        # through ``model``, on its dots' residuals through the variant.
        reference, fits = _poses_and_fits(model, images, covariates)
        out = []
        for column in root.T:
            varied = DispenserModel(model.values + column)
            rotations, translations = [], []
            for points, pixels, rotation, translation, jacobian in fits:
                residual = _board_residual(varied, points, pixels, rotation,
                                           np.r_[np.zeros(3), translation], radius)
                step = -np.linalg.lstsq(jacobian, residual, rcond=None)[0]
                rotations.append(Rotation.from_rotvec(step[:3]).as_matrix() @ rotation)
                translations.append(translation + step[3:])
            out.append(TargetPoses(reference.a, reference.c, np.array(rotations),
                                   np.array(translations), reference.covariates,
                                   reference.covariance))
        return out
    return variants


def _board_residual(model, points, pixels, start, x, dot_radius: float) -> np.ndarray:
    """The dots' ellipse centres through ``model`` less ``pixels`` (2 k,) px, the board at
    rotation exp(x[:3]) ``start`` and translation x[3:] (m) in the camera frame."""
    rotation = Rotation.from_rotvec(x[:3]).as_matrix() @ start
    centre = dot_centres(points @ rotation.T + x[3:],
                         np.repeat(rotation[None, :, :2], len(points), 0), dot_radius)
    return (distort(model, centre[:, :2] / centre[:, 2:3]) - pixels).ravel()


def _fit_board_pose(model, points, pixels, rvec, tvec, dot_radius: float):
    """The board pose whose dots' ellipse centres (``dot_radius`` m, through ``model``'s
    lens) best match ``pixels``: rotation (3, 3), translation (3,) m, the covariance (6, 6)
    of (translation, rotation error vector in the camera frame) from the fit's Jacobian
    and its residual variance, and that Jacobian (2 k, 6) by (rotation vector,
    translation)."""
    start = Rotation.from_rotvec(rvec).as_matrix()
    solution = least_squares(
        lambda x: _board_residual(model, points, pixels, start, x, dot_radius),
        np.r_[np.zeros(3), tvec], x_scale='jac')
    variance = float(solution.fun @ solution.fun) / max(solution.fun.size - 6, 1)
    covariance = np.linalg.inv(solution.jac.T @ solution.jac) * variance
    order = [3, 4, 5, 0, 1, 2]
    return (Rotation.from_rotvec(solution.x[:3]).as_matrix() @ start, solution.x[3:],
            covariance[np.ix_(order, order)], solution.jac)


def write_target_poses(path, poses: TargetPoses) -> None:
    """The CSV of :func:`read_target_poses` (columns a, c, the pose, then the covariates)."""
    q = Rotation.from_matrix(poses.rotation).as_quat()
    names = ['a', 'c', *POSE_COLUMNS, *poses.covariates]
    write_columns(path, names, [poses.a, poses.c, poses.translation, q[:, 3], q[:, :3],
                                *poses.covariates.values()])
