"""Models, identification and compensation of the platform; numpy/scipy, no ROS."""
