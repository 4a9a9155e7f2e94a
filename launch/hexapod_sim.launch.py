"""The simulated hexapod cell (hexapod, pose sensor, calibrator with the known payload), for a full ROS 2 install:
ros2 launch machine_alignment hexapod_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.hexapod_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, hexapod_graph


def generate_launch_description():
    return launch_description(hexapod_graph)
