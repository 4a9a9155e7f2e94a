"""Models, identification and localisation of the dispenser; numpy/scipy/OpenCV, no ROS."""
