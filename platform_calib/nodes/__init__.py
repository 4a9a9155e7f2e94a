"""ROS nodes of the platform."""
