"""The simulated printer with its XY-Theta stage (dot plate removed; the vision
calibration in ``calibration/`` is published by vision_calibrator), for a full ROS 2 install:
ros2 launch machine_alignment stage_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.stage_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, stage_graph


def generate_launch_description():
    return launch_description(stage_graph)
