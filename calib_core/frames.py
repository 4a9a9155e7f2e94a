"""Coordinate frames as ROS hands them on (REP 103: metres, radians, right-handed; a frame
is (parent, child, translation (3,) m, quaternion (x, y, z, w))), without ROS: the
machines' core modules say which frames a calibration fixes, the nodes publish them."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

Frame = tuple[str, str, np.ndarray, np.ndarray]


def quaternion(rotation_vector=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a rotation vector (3,) rad."""
    return Rotation.from_rotvec(np.asarray(rotation_vector, dtype=float)).as_quat()


def planar(x: float, y: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,) m, quaternion) of a pose in the plane: x, y (m), theta (rad,
    counter-clockwise about +Z)."""
    return np.array([x, y, 0.0]), quaternion((0.0, 0.0, theta))


def turning(axis_from, axis_to) -> np.ndarray:
    """The quaternion (x, y, z, w) of the smallest rotation taking unit vector ``axis_from``
    (3,) onto ``axis_to`` (3,): a frame whose nominal axis is tilted onto a measured one."""
    a = np.asarray(axis_from, dtype=float) / np.linalg.norm(axis_from)
    b = np.asarray(axis_to, dtype=float) / np.linalg.norm(axis_to)
    cross = np.cross(a, b)
    sine = np.linalg.norm(cross)
    if sine < 1e-15:
        return quaternion()     # same direction (a calibrated axis is never reversed)
    return quaternion(cross / sine * np.arctan2(sine, a @ b))
