"""The simulated screen-registration platform (platform with its mark cameras, laser tracker, calibrator), for a full ROS 2 install:
ros2 launch machine_alignment platform_sim.launch.py

The nodes and parameters come from machine_alignment.launcher.platform_graph, the graph
``machine-align launch`` and the demo start."""
from launch import LaunchDescription
from launch_ros.actions import Node

from machine_alignment.launcher import launch_arguments, platform_graph


def generate_launch_description():
    return LaunchDescription([Node(**arguments) for arguments in launch_arguments(platform_graph())])
