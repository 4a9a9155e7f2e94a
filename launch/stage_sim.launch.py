"""The simulated printer with its XY-Theta stage (dot plate removed; the vision
calibration in ``calibration/`` is published by vision_calibrator), for a full ROS 2 install:
ros2 launch machine_alignment stage_sim.launch.py

The nodes and parameters come from machine_alignment.launcher.stage_graph, the graph
``machine-align launch`` and the demo start."""
from launch import LaunchDescription
from launch_ros.actions import Node

from machine_alignment.launcher import launch_arguments, stage_graph


def generate_launch_description():
    return LaunchDescription([Node(**arguments) for arguments in launch_arguments(stage_graph())])
