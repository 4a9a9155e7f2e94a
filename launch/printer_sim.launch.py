"""The simulated printer vision chain (gantry, camera, Mark detector, vision calibrator), for a full ROS 2 install:
ros2 launch machine_alignment printer_sim.launch.py [output_dir:=calibration record_dir:=runs]

The nodes and parameters come from machine_alignment.launcher.printer_graph, the graph
``machine-align launch`` and the demo start."""
from machine_alignment.launcher import launch_description, printer_graph


def generate_launch_description():
    return launch_description(printer_graph)
