"""6-SPS hexapod calibration (issue 4): not implemented yet."""
