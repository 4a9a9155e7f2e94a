"""The rotary axes from measured target poses: an instrument that stays put (a camera
beside the machine, a laser tracker) measures the 6-DOF pose of a target on the table while
A and C turn and the linear axes stand still. The model is the dispenser's chain with the
linear axes held,

    T_meas = [R_M R_A(a) R_C(c) R_F | R_M T_A(a) T_C(c) 0 + m],

R_F the fixed rotation from the target's coordinates to the table frame (chosen so that C
is nominally +Z and A +X, as on the dispenser), m the target's place at a = c = 0. 14
parameters: the camera's orientation (3, a small rotation about the start), m (3), and
each axis line's two tilts and two offsets (4 + 4); the gauge as in
:mod:`dispenser_calib.core.model` (a point's place along an axis is not observable, the
axes' zero angles are the target frame's at reset).

Residuals per pose (measured minus model, m): the target origin's position (3) and the
rotation error (3, rad) times a stated lever arm (default 0.1 m), so that both are
compared as displacements of a point that far from the origin; with the poses'
covariance, whitened instead (:func:`pose_residuals`). The poses themselves:
:mod:`dispenser_calib.core.target_poses`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calib_core.errors import CalibrationError
from dispenser_calib.core.model import (
    LOOKING_DOWN, NAMES, DispenserModel, _camera_rows, chain_rotation, rodrigues)
from dispenser_calib.core.target_poses import TargetPoses

AXIS_NAMES = ('a_tilt_1', 'a_tilt_2', 'a_offset_1', 'a_offset_2',
              'c_tilt_1', 'c_tilt_2', 'c_offset_1', 'c_offset_2')
FITTED_NAMES = ('camera_rx', 'camera_ry', 'camera_rz', 'M03', 'M13', 'M23') + AXIS_NAMES
LEVER = 0.1                   # m: rotation errors are compared as displacements this far out
SAME_ANGLE = 2e-3             # rad: two readings of an axis this close count as one angle
MIN_TURN = 0.05               # rad: a pair turned less than this says little about the axis


def _pair_axes(poses: TargetPoses, turning: np.ndarray, held: np.ndarray):
    """Unit axes (target coordinates) of R_i^T R_j over the pairs where ``held`` stays and
    ``turning`` turns by MIN_TURN to pi - MIN_TURN, signed by the turn; with each pair's
    held angle."""
    axes, held_at = [], []
    for i in range(len(poses)):
        same = np.flatnonzero((np.abs(held - held[i]) < SAME_ANGLE) & (np.arange(len(poses)) > i))
        for j in same:
            turn = turning[j] - turning[i]
            if MIN_TURN < abs(turn) < np.pi - MIN_TURN:
                vector = Rotation.from_matrix(poses.rotation[i].T @ poses.rotation[j]).as_rotvec()
                axes.append(vector / np.linalg.norm(vector) * np.sign(turn))
                held_at.append(held[i])
    return np.array(axes), np.array(held_at)


def table_frame(poses: TargetPoses) -> np.ndarray:
    """R_F (3, 3): from target coordinates to the table frame, whose +Z is C's axis and +X
    A's (made perpendicular), both found from the relative rotations of pose pairs where
    one axis alone turned.

    Raises
    ------
    CalibrationError
        No pair of poses where C alone turned, or none where A alone turned."""
    c_axes, _ = _pair_axes(poses, poses.c, poses.a)
    a_axes, c_held = _pair_axes(poses, poses.a, poses.c)
    for name, found in (('C', c_axes), ('A', a_axes)):
        if not len(found):
            raise CalibrationError(f'no two poses where {name} alone turned (by {MIN_TURN} to '
                                   f'{np.pi - MIN_TURN:.2f} rad): its axis is not determined')
    z = np.mean(c_axes, axis=0)
    z /= np.linalg.norm(z)
    # A's axis seen from the target turns with C: bring each pair's back to c = 0.
    x = np.mean([Rotation.from_rotvec(z * c).apply(v) for v, c in zip(a_axes, c_held)], axis=0)
    x = x - z * (x @ z)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def pose_residuals(model: DispenserModel, frame: np.ndarray, poses: TargetPoses,
                   lever: float = LEVER, turn: np.ndarray | None = None,
                   shift: np.ndarray | None = None, weighted: bool = True,
                   rotate: np.ndarray | None = None) -> np.ndarray:
    """Measured minus modelled, (n, 6) m: the target origin's position and ``lever`` times
    the rotation vector of R_meas R_model^T. ``turn`` (n, 2) rad is added to a, c,
    ``shift`` (n, 3) m to the modelled position and ``rotate`` (n, 3) rad, a rotation
    vector in the camera frame, turns the modelled target about its origin (the closed
    loop's effects). With the
    poses' covariance (and ``weighted``), the residuals are whitened instead: (position,
    rotation vector) times the inverse of each pose's covariance's Cholesky factor, in
    standard deviations."""
    angles = np.column_stack([poses.a, poses.c]) + (0 if turn is None else turn)
    stops = np.column_stack([np.zeros((len(poses), 3)), angles])
    position = _camera_rows(model, np.zeros((len(poses), 3)), stops)
    if shift is not None:
        position = position + shift
    modelled = chain_rotation(model, angles[:, 0], angles[:, 1]) @ frame
    if rotate is not None:
        modelled = Rotation.from_rotvec(rotate).as_matrix() @ modelled
    rotation = Rotation.from_matrix(poses.rotation @ np.transpose(modelled, (0, 2, 1)))
    if weighted and poses.covariance is not None:
        raw = np.column_stack([poses.translation - position, rotation.as_rotvec()])
        return np.linalg.solve(np.linalg.cholesky(poses.covariance), raw[:, :, None])[:, :, 0]
    return np.column_stack([poses.translation - position, lever * rotation.as_rotvec()])


def model_from(fitted: np.ndarray, camera_start: np.ndarray) -> DispenserModel:
    """The dispenser model of the 14 values in FITTED_NAMES order: the camera's rotation
    (a rotation vector, rad) applied to ``camera_start`` (3, 3), the target's place m, the
    axes' tilts and offsets; intrinsics unit and the linear axes' columns zero (unused)."""
    camera = Rotation.from_rotvec(fitted[:3]).as_matrix() @ camera_start
    values = dict.fromkeys(NAMES, 0.0)
    values.update(fx=1.0, fy=1.0)
    values.update(zip(('rm_x', 'rm_y', 'rm_z'),
                      Rotation.from_matrix(camera @ LOOKING_DOWN.T).as_rotvec()))
    values.update(zip(FITTED_NAMES[3:], fitted[3:]))
    return DispenserModel(np.array([values[n] for n in NAMES]))


def _start(poses: TargetPoses, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's orientation (chordal mean over every pose, nominal axes) and the
    target place and axis points by linear least squares with the gauge rows."""
    ra = rodrigues(np.array([1.0, 0, 0]), poses.a)
    rc = rodrigues(np.array([0, 0, 1.0]), poses.c)
    each = poses.rotation @ frame.T @ np.transpose(ra @ rc, (0, 2, 1))
    u, _, vt = np.linalg.svd(each.sum(axis=0))
    camera = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    # origin in camera = R_M R_A (I - R_C) t_c + R_M (I - R_A) t_a + m
    rows = np.concatenate([np.concatenate([camera @ ra[k] @ (np.eye(3) - rc[k]),
                                           camera @ (np.eye(3) - ra[k]), np.eye(3)], axis=1)
                           for k in range(len(poses))])
    gauge = np.zeros((2, 9))
    gauge[0, 2], gauge[1, 3] = 1.0, 1.0          # t_c . z = 0, t_a . x = 0
    solution = np.linalg.lstsq(np.vstack([rows, gauge]),
                               np.r_[poses.translation.ravel(), 0, 0], rcond=None)[0]
    t_c, t_a, m = solution[:3], solution[3:6], solution[6:]
    # Offsets along the perpendicular bases of model._basis: A: +Y, +Z; C: +Y, -X.
    fitted = np.r_[np.zeros(3), m, 0, 0, t_a[1], t_a[2], 0, 0, t_c[1], -t_c[0]]
    return fitted, camera


def axis_lines_in_camera(model: DispenserModel) -> dict:
    """Each axis line in the camera frame with the table at a = c = 0 (C's as A carries
    it): its unit direction and its point nearest the camera's origin (m), which do not
    depend on the frame the parameters are written in."""
    lines = {}
    for name, (direction, point) in (('a', model.a_axis), ('c', model.c_axis)):
        v = model.rotation @ direction
        p = model.rotation @ point + model.affine[:, 3]
        lines[name] = (v, p - v * (p @ v))
    return lines


def housing_frames(model: DispenserModel, a: np.ndarray) -> np.ndarray:
    """Each rotary axis's housing frame in the camera frame, (n, 2, 3, 3) for A then C at
    the table's A angles ``a`` (n,) rad: columns radial_1, radial_2, axial (right-handed).
    A's are fixed: Y, Z, X of the table (its axial along v_a, radial_2 along v_c made
    perpendicular), ISO 230-7's EYA, EZA, EXA; C's are carried by A: X, Y, Z (radial_1
    along v_a made perpendicular to v_c), EXC, EYC, EZC."""
    (va, _), (vc, _) = model.a_axis, model.c_axis

    def frame(axial, towards):
        second = towards - axial * (towards @ axial)
        second /= np.linalg.norm(second)
        return second, np.cross(axial, second)
    z_of_a, y_of_a = frame(va, vc)          # radial_2, then axial x radial_2 = -radial_1
    x_of_c, y_of_c = frame(vc, va)
    a_frame = np.column_stack([-y_of_a, z_of_a, va])
    c_frame = np.column_stack([x_of_c, y_of_c, vc])
    carried = model.rotation @ rodrigues(va, np.asarray(a, float))
    return np.stack([np.broadcast_to(model.rotation @ a_frame, carried.shape),
                     carried @ c_frame], axis=1)


def tilt_arms(model: DispenserModel, a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """From each rotary axis's tilt pivot to the target's origin in the camera frame, (n,
    2, 3) m for A then C at the table's angles a, c (n,) rad. The pivot is the foot of the
    origin at reset on the axis line (A's t_a, C's t_c as A carries it): a tilt of the
    rotor by w (rad, camera frame) moves the origin by w x arm. Where along the axis the
    rotor tilts is a gauge: another pivot adds to the radial error motion of the same
    orders, so the radial motion stated is the one at the target's own height."""
    (va, ta), (vc, tc) = model.a_axis, model.c_axis
    a, c = np.asarray(a, float), np.asarray(c, float)
    carried = rodrigues(va, a)
    from_c = (carried @ rodrigues(vc, c)) @ -tc
    from_a = from_c + carried @ (tc - ta)
    return np.stack([from_a, from_c], axis=1) @ model.rotation.T


def squareness(model: DispenserModel) -> float:
    """The angle (rad) by which A and C miss being perpendicular, positive when the
    angle between them is less than 90 degrees."""
    (va, _), (vc, _) = model.a_axis, model.c_axis
    return float(np.arcsin(np.clip(va @ vc, -1, 1)))


@dataclass
class RotaryFit:
    """The identified rotary axes: the model, the table frame R_F, the fitted values and
    their covariance (FITTED_NAMES order), the lever arm (m) and the residuals (n, 6) m."""

    model: DispenserModel
    frame: np.ndarray
    values: np.ndarray
    covariance: np.ndarray
    camera_start: np.ndarray
    lever: float
    residuals: np.ndarray

    @property
    def std_devs(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    def derived_std(self, quantity) -> float:
        """1-sigma of ``quantity`` (a function of the model, float) by first-order
        propagation of the covariance (central differences)."""
        gradient = np.zeros(len(self.values))
        for j in range(len(self.values)):
            step = np.zeros(len(self.values))
            step[j] = 1e-7 * max(1.0, abs(self.values[j]))
            gradient[j] = (quantity(model_from(self.values + step, self.camera_start))
                           - quantity(model_from(self.values - step, self.camera_start))) / (2 * step[j])
        return float(np.sqrt(gradient @ self.covariance @ gradient))

    def report(self) -> dict:
        (va, ta), (vc, tc) = self.model.a_axis, self.model.c_axis
        position = np.linalg.norm(self.residuals[:, :3], axis=1)
        rotation = np.linalg.norm(self.residuals[:, 3:], axis=1) / self.lever
        return {
            'parameters': dict(zip(FITTED_NAMES, map(float, self.values))),
            'std_devs': dict(zip(FITTED_NAMES, map(float, self.std_devs))),
            'a_axis': {'direction': va.tolist(), 'point_m': ta.tolist()},
            'c_axis': {'direction': vc.tolist(), 'point_m': tc.tolist()},
            'squareness_a_c_rad': squareness(self.model),
            'squareness_std_rad': self.derived_std(squareness),
            'position_error_m': {'rms': float(np.sqrt(np.mean(position ** 2))),
                                 'max': float(position.max())},
            'orientation_error_rad': {'rms': float(np.sqrt(np.mean(rotation ** 2))),
                                      'max': float(rotation.max())},
            'lever_m': self.lever,
            'gauge': ('frame: the target at a = c = 0, turned so that C is +Z and A +X; a '
                      'point\'s place along an axis is not observable (held perpendicular); '
                      'the axes\' zero angles are those of the readings'),
        }


def identify_rotary_axes(poses: TargetPoses, lever: float = LEVER) -> RotaryFit:
    """The 14 parameters by least squares on :func:`pose_residuals`, from the start of
    :func:`table_frame` and :func:`_start`, with 1-sigma from the Jacobian and the
    residuals' variance.

    Raises
    ------
    CalibrationError
        Fewer poses than parameters allow, or one axis never turns alone."""
    if 6 * len(poses) < 2 * len(FITTED_NAMES):
        raise CalibrationError(f'{len(poses)} poses are too few for {len(FITTED_NAMES)} '
                               f'parameters (at least {len(FITTED_NAMES) // 3} needed)')
    frame = table_frame(poses)
    start, camera = _start(poses, frame)

    def residual(x):
        return pose_residuals(model_from(x, camera), frame, poses, lever).ravel()
    solution = least_squares(residual, start, x_scale='jac', xtol=1e-15, ftol=1e-15,
                             gtol=1e-15, max_nfev=200)
    dof = max(solution.fun.size - len(FITTED_NAMES), 1)
    variance = float(solution.fun @ solution.fun) / dof
    covariance = np.linalg.pinv(solution.jac.T @ solution.jac) * variance
    model = model_from(solution.x, camera)
    return RotaryFit(model, frame, solution.x, covariance, camera, lever,
                     pose_residuals(model, frame, poses, lever, weighted=False))
