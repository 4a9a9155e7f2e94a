"""Grid self-calibration without ROS: the views, the stage error model, the solver."""
