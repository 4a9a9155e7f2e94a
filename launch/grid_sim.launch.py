"""The simulated printer's camera gantry over a grid plate (gantry, camera, detector, vision and grid calibrators), for a full ROS 2 install:
ros2 launch machine_alignment grid_sim.launch.py

The nodes and parameters come from machine_alignment.launcher.grid_graph, the graph
``machine-align launch`` and the demo start."""
from launch import LaunchDescription
from launch_ros.actions import Node

from machine_alignment.launcher import grid_graph, launch_arguments


def generate_launch_description():
    return LaunchDescription([Node(**arguments) for arguments in launch_arguments(grid_graph())])
