"""ROS nodes of the dispenser."""
