"""Printer algorithms: Mark detection, camera and gantry models, vision calibration (no rclpy)."""
