"""6-SPS hexapod (Gough-Stewart platform) calibration: core (kinematics, 42-parameter
identification, pose selection, the calibration run), sim (hexapod with joint play, pose
sensor) and nodes (hexapod_sim, pose_sensor_sim, hexapod_calibrator)."""
