"""Conversions from the hexapod core's pose vectors to ROS messages, kept at the node
boundary. Core poses are x, y, z (m), roll, pitch, yaw (rad, about fixed X, Y, Z); messages
carry geometry_msgs/Pose (position in m, orientation as a quaternion, REP-103). Reading
messages (live or decoded from a bag) is in :mod:`hexapod_calib.core.records`."""
from __future__ import annotations

from geometry_msgs.msg import Point, Pose, Quaternion
from scipy.spatial.transform import Rotation

from hexapod_calib.core.geometry import as_poses


def pose_as_message(pose) -> Pose:
    pose = as_poses(pose)[0]
    x, y, z, w = Rotation.from_euler('xyz', pose[3:]).as_quat()
    return Pose(position=Point(x=float(pose[0]), y=float(pose[1]), z=float(pose[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))
