"""Registering a screen: from the two marks the camera measures to the platform pose that
puts them on their targets, then the feeds for that pose (``compensation``). Hardware is
passed in as callables, so the node, the bench and the tests run the same code.

Poses are 2-D rigid transforms (x m, y m, theta rad): ``compose(a, b)`` applies b, then a.
The screen lies on the platform at an unknown pose S (it is re-mounted every layer); the
camera sees its marks at P S m in the base frame, P the platform's pose."""
from __future__ import annotations

from typing import Callable

import numpy as np

from calib_core.errors import InvalidInputError
from platform_calib.core.compensation import (
    SCREEN, Compensation, PSOSettings, compensate, mark_positions)
from platform_calib.core.geometry import PlatformGeometry
from platform_calib.core.kinematics import forward, rotation


def compose(a, b) -> np.ndarray:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.array([*(a[:2] + rotation(np.array([a[2]]))[0] @ b[:2]), a[2] + b[2]])


def invert(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.array([*(-(rotation(np.array([-a[2]]))[0] @ a[:2])), -a[2]])


def pose_of_marks(marks, screen=SCREEN) -> np.ndarray:
    """The screen pose (3,) that puts its marks A, B at ``marks`` (2, 2) m (base frame):
    the angle of the diagonal and its midpoint.

    Raises
    ------
    InvalidInputError
        NaN marks, or marks whose distance is not the screen's diagonal (another screen, a
        mark mistaken) to within 1 %."""
    marks = np.asarray(marks, dtype=float)
    if marks.shape != (2, 2) or not np.all(np.isfinite(marks)):
        raise InvalidInputError('two finite marks (x, y m) are needed')
    local = mark_positions(np.zeros((1, 3)), screen)[0]
    seen, nominal = marks[0] - marks[1], local[0] - local[1]
    if abs(np.linalg.norm(seen) / np.linalg.norm(nominal) - 1) > 0.01:
        raise InvalidInputError(f'the marks are {np.linalg.norm(seen) * 1e3:.2f} mm apart; the '
                                f'screen\'s diagonal is {np.linalg.norm(nominal) * 1e3:.2f} mm')
    theta = np.arctan2(seen[1], seen[0]) - np.arctan2(nominal[1], nominal[0])
    middle = marks.mean(axis=0) - rotation(np.array([theta]))[0] @ local.mean(axis=0)
    return np.array([*middle, theta])


def registration_pose(model: PlatformGeometry, feeds, measured, targets,
                      screen=SCREEN) -> np.ndarray:
    """The platform pose (3,) that brings the marks measured at ``feeds`` onto ``targets``
    (2, 2) m, with the platform's pose now from the ``model``."""
    now = forward(model, np.atleast_2d(feeds))[0]
    on_platform = compose(invert(now), pose_of_marks(measured, screen))
    return compose(pose_of_marks(targets, screen), invert(on_platform))


def register(model: PlatformGeometry, nominal: PlatformGeometry, feeds,
             measure: Callable[[], np.ndarray], move: Callable[[np.ndarray], None], targets,
             method: str = 'exact', screen=SCREEN, pso: PSOSettings = PSOSettings(),
             accept_unconverged: bool = False) -> tuple[np.ndarray, Compensation]:
    """Measure the marks, compute the pose and the feeds by ``method``, move. Returns the
    pose asked for and the compensation; an unconverged swarm is refused and nothing moves,
    unless ``accept_unconverged`` (what the source does; for comparisons only).

    Raises
    ------
    WorkspaceError
        The pose is out of reach or out of the stroke (nothing moves).
    InvalidInputError
        The marks are not the screen's; the swarm did not converge."""
    pose = registration_pose(model, feeds, measure(), targets, screen)
    result = compensate(model, nominal, pose, method, screen, pso)
    if not result.converged and not accept_unconverged:
        raise InvalidInputError(f'{method} did not converge ({result.message}); the platform '
                                'was not moved')
    move(result.feeds)
    return pose, result
