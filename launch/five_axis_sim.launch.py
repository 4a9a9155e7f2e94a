"""The simulated five-axis dispenser (the machine with its camera over the dot board, calibrator), for a full ROS 2 install:
ros2 launch machine_alignment five_axis_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.five_axis_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, five_axis_graph


def generate_launch_description():
    return launch_description(five_axis_graph)
