"""Five-axis dual-turntable dispenser (XYZAC, camera on Z): vision kinematic calibration and workpiece localisation (issue 23)."""
