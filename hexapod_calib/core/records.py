"""Reading the hexapod's messages into core values: live messages and messages decoded
from a recorded bag have the same fields, so the nodes and the offline tools read a run
with the same code, and neither needs the message types.

Core poses are x, y, z (m), roll, pitch, yaw (rad, about fixed X, Y, Z); messages carry
geometry_msgs/Pose (position in m, orientation as a quaternion, REP-103)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core.errors import InvalidInputError

MEASUREMENTS_TOPIC = '/hexapod_calibrator/measurements'   # a calibration run's measured poses
HEXAPOD_RESULT_TOPIC = '/hexapod_calibrator/result'


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
