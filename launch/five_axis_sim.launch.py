"""The simulated five-axis dispenser (the machine with its camera over the dot board, calibrator), for a full ROS 2 install:
ros2 launch machine_alignment five_axis_sim.launch.py

The nodes and parameters come from machine_alignment.launcher.five_axis_graph, the graph
``machine-align launch`` and the demo start."""
from launch import LaunchDescription
from launch_ros.actions import Node

from machine_alignment.launcher import five_axis_graph, launch_arguments


def generate_launch_description():
    return LaunchDescription([Node(**arguments) for arguments in launch_arguments(five_axis_graph())])
