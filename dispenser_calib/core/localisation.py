"""With the calibrated model: a workpiece's features located from several views through the
kinematic chain (multi-view triangulation: the depth eliminated, the reprojection
minimised), the needle's offset from the camera (the tool centre point) from dispensed test
dots, and the poses that place a dispensing path on the workpiece."""
from __future__ import annotations

import numpy as np

from calib_core.errors import CalibrationError, InvalidInputError
from dispenser_calib.core.model import (
    DispenserModel, camera_points, place, project_rows, rodrigues)


def locate(model: DispenserModel, poses: np.ndarray, pixels: np.ndarray,
           start=None) -> tuple[np.ndarray, float]:
    """A feature's position (3,) m in the board-at-reset frame from its pixels (n, 2) in
    views at poses (n, 5), and the RMS reprojection (px).

    Raises
    ------
    InvalidInputError
        Fewer than 2 views, or NaN.
    CalibrationError
        Views that do not determine the point (all from one direction)."""
    poses, pixels = np.atleast_2d(poses), np.atleast_2d(pixels)
    if len(poses) < 2 or len(poses) != len(pixels) or not (
            np.all(np.isfinite(poses)) and np.all(np.isfinite(pixels))):
        raise InvalidInputError('a feature needs at least 2 finite views (pose and pixel each)')
    start = np.zeros(3) if start is None else np.asarray(start, float)

    def residual(point):
        return (project_rows(model, np.repeat(point[None], len(poses), 0), poses) - pixels).ravel()
    from scipy.optimize import least_squares   # here: the planner's import stays light
    solution = least_squares(residual, start, method='lm', xtol=1e-15, ftol=1e-15)
    if np.linalg.matrix_rank(solution.jac, tol=1e-6 * np.abs(solution.jac).max()) < 3:
        raise CalibrationError('the views do not determine the feature (seen from one '
                               'direction only): add views at other a, c')
    return solution.x, float(np.sqrt(np.mean(solution.fun ** 2)))


def tool_centre(model: DispenserModel, dispensed_at: np.ndarray, dots: np.ndarray) -> np.ndarray:
    """The needle tip in the camera frame (3,) m: each test dot (k, 3), located on the board,
    was dispensed with the machine at ``dispensed_at`` (k, 5), where the tip touched it:
    tip = R_M T_A T_C p + M q, the same for every dot; least squares over the dots."""
    dispensed_at, dots = np.atleast_2d(dispensed_at), np.atleast_2d(dots)
    if len(dots) < 1:
        raise InvalidInputError('the tool centre needs at least one dispensed dot')
    tips = np.array([camera_points(model, d[None], q[None])[0, 0]
                     for d, q in zip(dots, dispensed_at)])
    return tips.mean(axis=0)


def place_path(model: DispenserModel, tip: np.ndarray, path: np.ndarray, a: float,
               c: float) -> np.ndarray:
    """Poses (k, 5) that put the needle tip on each path point (k, 3) (board-at-reset
    frame) with the table at a, c."""
    return np.array([place(model, p, a, c, tip) for p in np.atleast_2d(path)])


def reached(model: DispenserModel, tip: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Where the tip touches the table at ``poses`` (k, 5): the board-frame points (k, 3)
    that the chain carries to the tip (the inverse of ``place`` for a known a, c)."""
    (va, ta), (vc, tc) = model.a_axis, model.c_axis
    out = []
    for q in np.atleast_2d(poses):
        on_table = model.rotation.T @ (tip - model.affine @ np.r_[q[:3], 1.0])
        # Undo A, then C (A carries C).
        p = rodrigues(va, np.array([-q[3]]))[0] @ (on_table - ta) + ta
        out.append(rodrigues(vc, np.array([-q[4]]))[0] @ (p - tc) + tc)
    return np.array(out)


def fit_part_pose(cad: np.ndarray, located: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The rigid motion (R (3, 3), t (3,) m) that carries the part's CAD features (k, 3) onto
    their located positions (k, 3) (Kabsch), and the RMS misfit (m).

    Raises
    ------
    InvalidInputError
        Fewer than 3 features, or features on one line (the pose is not determined)."""
    cad, located = np.atleast_2d(cad), np.atleast_2d(located)
    if len(cad) < 3 or cad.shape != located.shape:
        raise InvalidInputError('a part pose needs at least 3 located features matching its CAD')
    centred_cad, centred = cad - cad.mean(axis=0), located - located.mean(axis=0)
    if np.linalg.matrix_rank(centred_cad, tol=1e-9) < 2:
        raise InvalidInputError('the CAD features lie on one line: the part\'s pose is not '
                                'determined')
    u, _, vt = np.linalg.svd(centred_cad.T @ centred)
    rotation = (u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt).T
    translation = located.mean(axis=0) - rotation @ cad.mean(axis=0)
    misfit = located - (cad @ rotation.T + translation)
    return rotation, translation, float(np.sqrt(np.mean(np.sum(misfit ** 2, axis=1))))
