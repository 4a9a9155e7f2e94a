"""Code shared by every machine of machine_alignment: errors, parameter sets, least squares
with covariance, datasets, calibration files and MCAP bags. No rclpy outside ``nodes``."""
