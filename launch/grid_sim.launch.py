"""The simulated printer's camera gantry over a grid plate (gantry, camera, detector, vision and grid calibrators), for a full ROS 2 install:
ros2 launch machine_alignment grid_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.grid_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, grid_graph


def generate_launch_description():
    return launch_description(grid_graph)
