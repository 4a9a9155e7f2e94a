"""Conversions between ROS messages and the hexapod core's pose vectors, kept at the node
boundary. Core poses are x, y, z (m), roll, pitch, yaw (rad, about fixed X, Y, Z); messages
carry geometry_msgs/Pose (position in m, orientation as a quaternion, REP-103)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion
from scipy.spatial.transform import Rotation

from calib_core.errors import InvalidInputError
from hexapod_calib.core.geometry import as_poses


def pose_as_message(pose) -> Pose:
    pose = as_poses(pose)[0]
    x, y, z, w = Rotation.from_euler('xyz', pose[3:]).as_quat()
    return Pose(position=Point(x=float(pose[0]), y=float(pose[1]), z=float(pose[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def pose_from_message(msg) -> np.ndarray:
    """(6,) pose from a geometry_msgs/Pose (or a decoded bag message).

    Raises InvalidInputError on NaN or a quaternion far from unit length."""
    p, q = msg.position, msg.orientation
    values = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=float)
    if not np.all(np.isfinite(values)):
        raise InvalidInputError('pose message contains NaN or infinite values')
    norm = np.linalg.norm(values[3:])
    if abs(norm - 1.0) > 1e-6:
        raise InvalidInputError(f'pose orientation is not a unit quaternion (norm {norm:.6g})')
    return np.concatenate([values[:3], Rotation.from_quat(values[3:]).as_euler('xyz')])


def leg_lengths_from_message(values) -> np.ndarray:
    lengths = np.asarray(values, dtype=float)
    if lengths.shape != (6,) or not np.all(np.isfinite(lengths)):
        raise InvalidInputError(f'need six finite leg lengths (m), got {len(lengths)} values')
    return lengths


def measurement_record(msg) -> tuple:
    """(phase, target (6,), leg lengths (6,), measured (6,)) from a HexapodMeasurement."""
    return (msg.phase, pose_from_message(msg.target), leg_lengths_from_message(msg.leg_lengths),
            pose_from_message(msg.measured.pose))
