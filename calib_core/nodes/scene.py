"""What a viewer shows of a recorded run (Foxglove's 3-D and image panels, RViz): each
stop's machine frames as TF (``tf2_msgs/TFMessage`` on ``/tf``), a measured pose as
``geometry_msgs/PoseStamped``, camera frames as ``sensor_msgs/CompressedImage``. Every
calibrator records them beside its own messages; replays read only their own topics.

The TF messages go to the bag only: the ROS 2 wheels this suite installs have no
``tf2_msgs`` Python package, so they are serialised with rosbags' copy of the standard
Jazzy definitions (the same CDR bytes rclpy would write) and not published live.

Frames are named per machine (``base``, ``platform``, ``camera``, ...); positions in m,
rotations as unit quaternions (x, y, z, w, ROS order).
"""
from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from geometry_msgs.msg import PoseStamped
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CompressedImage

from calib_core.errors import InvalidInputError

TF_TOPIC = '/tf'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
POSE_TYPE = 'geometry_msgs/msg/PoseStamped'
IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'
# JPEG at this quality keeps a 2448 x 2048 board frame near 0.5 MB; 'png' keeps every grey
# level (2.3 MB a frame with 2 grey levels of noise) for detecting the dots again offline.
JPEG_QUALITY = 90


def quaternion(rotation_vector=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a rotation vector (3,) rad."""
    return Rotation.from_rotvec(np.asarray(rotation_vector, dtype=float)).as_quat()


def planar(x: float, y: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,) m, quaternion) of a pose in the plane: x, y (m), theta (rad,
    counter-clockwise about +Z)."""
    return np.array([x, y, 0.0]), quaternion((0.0, 0.0, theta))


def pose_stamped(header, position, rotation) -> PoseStamped:
    """``position`` (3,) m and ``rotation`` quaternion (x, y, z, w) in ``header.frame_id``."""
    msg = PoseStamped(header=header)
    _fill(msg.pose.position, msg.pose.orientation, position, rotation)
    return msg


def transforms_cdr(stamp_ns: int, frames: list[tuple[str, str, np.ndarray, np.ndarray]]) -> bytes:
    """A ``tf2_msgs/TFMessage`` (CDR bytes) stamped ``stamp_ns`` (ns since the epoch) of
    (parent, child, translation (3,) m, quaternion (x, y, z, w)) per frame."""
    types = _standard_types().types
    time = types['builtin_interfaces/msg/Time'](sec=int(stamp_ns // 10**9),
                                                  nanosec=int(stamp_ns % 10**9))
    out = []
    for parent, child, translation, rotation in frames:
        translation, rotation = _checked(translation, rotation)
        out.append(types['geometry_msgs/msg/TransformStamped'](
            header=types['std_msgs/msg/Header'](stamp=time, frame_id=parent),
            child_frame_id=child,
            transform=types['geometry_msgs/msg/Transform'](
                translation=types['geometry_msgs/msg/Vector3'](*translation),
                rotation=types['geometry_msgs/msg/Quaternion'](*rotation))))
    message = types[TF_TYPE](transforms=out)
    return bytes(_standard_types().serialize_cdr(message, TF_TYPE))


@lru_cache(maxsize=1)
def _standard_types():
    return get_typestore(Stores.ROS2_JAZZY)


def frame_of(pose_msg) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,) m, quaternion (x, y, z, w)) of a geometry_msgs/Pose."""
    p, q = pose_msg.position, pose_msg.orientation
    return np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])


def compressed_image(pixels: np.ndarray, header, image_format: str = 'jpeg') -> CompressedImage:
    """A grey frame (H, W) uint8 as ``sensor_msgs/CompressedImage`` (``jpeg`` or lossless
    ``png``).

    Raises
    ------
    InvalidInputError
        Another format, or not a uint8 array."""
    if image_format not in ('jpeg', 'png'):
        raise InvalidInputError(f'image format {image_format!r}: jpeg or png')
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8 or pixels.ndim != 2:
        raise InvalidInputError('a frame to compress is a 2-D uint8 array')
    options = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if image_format == 'jpeg' else []
    ok, data = cv2.imencode('.jpg' if image_format == 'jpeg' else '.png', pixels, options)
    if not ok:
        raise InvalidInputError(f'OpenCV could not encode the frame as {image_format}')
    return CompressedImage(header=header, format=image_format, data=data.tobytes())


def _checked(position, rotation) -> tuple[list, list]:
    position = np.asarray(position, dtype=float)
    rotation = np.asarray(rotation, dtype=float)
    if position.shape != (3,) or rotation.shape != (4,) or not (
            np.all(np.isfinite(position)) and np.all(np.isfinite(rotation))):
        raise InvalidInputError('a pose is a finite position (3,) m and quaternion (4,)')
    return [float(v) for v in position], [float(v) for v in rotation / np.linalg.norm(rotation)]


def _fill(position_msg, orientation_msg, position, rotation) -> None:
    position, rotation = _checked(position, rotation)
    position_msg.x, position_msg.y, position_msg.z = position
    orientation_msg.x, orientation_msg.y, orientation_msg.z, orientation_msg.w = rotation
