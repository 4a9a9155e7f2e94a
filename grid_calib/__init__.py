"""grid_calib: self-calibration of a 2-D stage's measuring system with an imperfect grid
plate (CN104006777A, corrected as in SEEDS_CDE.md section 002)."""
