"""The simulated screen-registration platform (platform with its mark cameras, laser tracker, calibrator), for a full ROS 2 install:
ros2 launch machine_alignment platform_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.platform_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, platform_graph


def generate_launch_description():
    return launch_description(platform_graph)
