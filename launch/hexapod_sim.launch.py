"""The simulated hexapod cell (hexapod, pose sensor, calibrator with the known payload), for a full ROS 2 install:
ros2 launch machine_alignment hexapod_sim.launch.py

The nodes and parameters come from machine_alignment.launcher.hexapod_graph, the graph
``machine-align launch`` and the demo start."""
from launch import LaunchDescription
from launch_ros.actions import Node

from machine_alignment.launcher import launch_arguments, hexapod_graph


def generate_launch_description():
    return LaunchDescription([Node(**arguments) for arguments in launch_arguments(hexapod_graph())])
