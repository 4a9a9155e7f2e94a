"""rclpy nodes of the printer: thin wrappers around core and sim."""
