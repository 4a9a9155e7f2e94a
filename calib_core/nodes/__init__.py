"""rclpy nodes shared by every machine (recorder, player) and the common main()."""
