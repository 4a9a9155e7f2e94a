"""Simulated printer hardware with its error sources (no rclpy)."""
