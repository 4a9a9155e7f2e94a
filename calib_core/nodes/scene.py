"""What a viewer shows of a recorded run (Foxglove's 3-D and image panels, RViz): each
stop's machine frames as TF (``tf2_msgs/TFMessage`` on ``/tf``), a measured pose as
``geometry_msgs/PoseStamped``, camera frames as ``sensor_msgs/CompressedImage``. Every
calibrator records them beside its own messages; replays read only their own topics.

``tf2_msgs`` is built by ``make setup`` from its standard Jazzy definition
(interfaces/tf2_msgs): the ROS 2 wheels on PyPI lack it. Live, the calibrators publish
their calibrated frames on ``/tf_static`` (:mod:`calib_core.nodes.status`).

Frames are named per machine (``base``, ``platform``, ``camera``, ...); positions in m,
rotations as unit quaternions (x, y, z, w, ROS order).
"""
from __future__ import annotations

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from calib_core.errors import InvalidInputError
from calib_core.frames import Frame

TF_TOPIC = '/tf'
TF_STATIC_TOPIC = '/tf_static'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
POSE_TYPE = 'geometry_msgs/msg/PoseStamped'
IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'
# JPEG at this quality keeps a 2448 x 2048 board frame near 0.5 MB; 'png' keeps every grey
# level (2.3 MB a frame with 2 grey levels of noise) for detecting the dots again offline.
JPEG_QUALITY = 90


def pose_stamped(header, position, rotation) -> PoseStamped:
    """``position`` (3,) m and ``rotation`` quaternion (x, y, z, w) in ``header.frame_id``."""
    msg = PoseStamped(header=header)
    _fill(msg.pose.position, msg.pose.orientation, position, rotation)
    return msg


def transform_message(stamp_ns: int, frames: list[Frame]) -> TFMessage:
    """A ``tf2_msgs/TFMessage`` stamped ``stamp_ns`` (ns since the epoch) of (parent, child,
    translation (3,) m, quaternion (x, y, z, w)) per frame."""
    stamp = Time(sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
    out = []
    for parent, child, translation, rotation in frames:
        message = TransformStamped(header=Header(stamp=stamp, frame_id=parent),
                                   child_frame_id=child)
        _fill(message.transform.translation, message.transform.rotation, translation, rotation)
        out.append(message)
    return TFMessage(transforms=out)


def transforms_cdr(stamp_ns: int, frames: list[Frame]) -> bytes:
    """:func:`transform_message` serialised (CDR bytes), as a bag stores it."""
    return serialize_message(transform_message(stamp_ns, frames))


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
