"""ROS message classes from type names such as ``alignment_msgs/msg/Mark``."""
import importlib

from calib_core.errors import BagError


def message_class(msgtype: str):
    """The rclpy message class for ``pkg/msg/Name``; BagError if it is not installed."""
    try:
        package, kind, name = msgtype.split('/')
        return getattr(importlib.import_module(f'{package}.{kind}'), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise BagError(f'message type {msgtype} is not available here: {exc}') from exc
