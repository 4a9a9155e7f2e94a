"""Code shared by every machine of machine_alignment: errors, parameter sets, least squares
with covariance, datasets, calibration files and MCAP bags. No rclpy outside ``nodes``."""
import os

# One BLAS thread unless the user says otherwise (set before numpy loads it, which the
# command line and the launcher's nodes do after this): the fits here are many small
# solves, on which OpenBLAS's threads spin against each other. `machine-align analyze
# rotary` on the real positioner took 9-14 s wall (11 s CPU) on 2 cores with its
# default threads, 2.6-3.0 s with one.
for _variable in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_variable, '1')
del _variable
