"""Explicit conversions between planar platform poses and geometry_msgs (rclpy side)."""
import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion

from platform_calib.core.records import planar_pose_from_quaternion


def planar_pose_as_message(pose) -> Pose:
    """(x m, y m, theta rad) as a Pose rotated about z."""
    x, y, theta = (float(v) for v in pose)
    return Pose(position=Point(x=x, y=y, z=0.0),
                orientation=Quaternion(x=0.0, y=0.0, z=float(np.sin(theta / 2)),
                                       w=float(np.cos(theta / 2))))


def planar_pose_from_message(pose: Pose) -> np.ndarray:
    return planar_pose_from_quaternion(pose.position.x, pose.position.y, pose.orientation.z,
                                       pose.orientation.w)
