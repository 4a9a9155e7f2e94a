"""The closed loop's view of the rotary axes measured by target poses
(:mod:`dispenser_calib.core.rotary`): rows are the poses, the base model the 14 parameters
(the axes as lines, the camera's orientation, the target's place), channels the two table
angles (rad) and a shift of the target in the camera frame (m). An effect on an angle is
the table turning other than its reading says (a worm gear, an encoder's eccentricity,
lost motion as the axis reverses); one on the shift is the target moving against the
instrument (thermal drift of a stand or of the Z column)."""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop.model import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import directions_from_order
from calib_core.effects.rotary import commanded_places
from calib_core.parameters import Parameter, ParameterSet
from dispenser_calib.core.rotary import (
    FITTED_NAMES, LEVER, housing_frames, identify_rotary_axes, model_from, pose_residuals)
from dispenser_calib.core.target_poses import TargetPoses

ANGLE_STEP = 1e-6   # rad: finite-difference step of the channel Jacobian


def _unit(name: str) -> str:
    return 'rad' if name.startswith(('camera_r', 'a_tilt', 'c_tilt')) else 'm'


class RotaryLoopModel(MachineModel):
    """Measured target poses on the tilting-rotary table for the closed loop."""

    name = 'rotary axes'
    linearise = True
    base_model = ('A and C as lines (two tilts and two offsets each), the camera\'s '
                  'orientation and the target\'s place: 14 parameters; residual: the target '
                  'origin\'s position and the lever arm times its orientation error (m)')
    channels = ('a', 'c', 'camera_x', 'camera_y', 'camera_z')
    channel_units = ('rad', 'rad', 'm', 'm', 'm')
    candidates = ('scale', 'angular_harmonics', 'error_motion', 'reversal', 'drift_time',
                  'drift_temperature')
    # Encoders turn, gears wobble and axes reverse; heat moves the target against the camera.
    effect_channels = {'scale': ('a', 'c'), 'angular_harmonics': ('a', 'c'),
                       'reversal': ('a', 'c'), 'drift_time': ('camera_x', 'camera_y', 'camera_z'),
                       'drift_temperature': ('camera_x', 'camera_y', 'camera_z')}
    min_effect = 1e-6

    def __init__(self, poses: TargetPoses, lever: float = LEVER):
        self.poses, self.lever = poses, lever
        if poses.covariance is not None:
            # Residuals whitened by each pose's covariance: in standard deviations.
            self.unit, self.min_effect = 'sigma', 0.1
            self.base_model = self.base_model.replace(
                'the lever arm times its orientation error (m)',
                'its orientation error, weighted by each pose\'s covariance (sigma)')
        self.identified = identify_rotary_axes(poses, lever)   # every pose, base model only
        self.frame, self.camera_start = self.identified.frame, self.identified.camera_start
        angles = np.column_stack([poses.a, poses.c])
        self.directions = directions_from_order(angles)
        self._scalars = scalar_covariates(poses.covariates)
        # Hold-out and folds sample every tilt: the table's sweeps are at fixed a.
        self._strata = np.unique(np.round(poses.a, 3), return_inverse=True)[1]

    def __len__(self):
        return len(self.poses)

    def strata(self):
        return self._strata

    def initial(self) -> ParameterSet:
        return ParameterSet([Parameter(n, float(v), _unit(n))
                             for n, v in zip(FITTED_NAMES, self.identified.values)])

    def context(self, base, rows):
        n = len(rows)
        angles = np.column_stack([self.poses.a[rows], self.poses.c[rows]])
        # Encoder readings of one commanded angle differ in the last digits; the tests for
        # periods and trends count distinct positions, so they see the commanded places.
        places = np.column_stack([commanded_places(angles[:, 0]), commanded_places(angles[:, 1])])
        context = {'position': np.column_stack([places, np.zeros((n, 3))]),
                   'angle': np.column_stack([angles, np.full((n, 3), np.nan)]),
                   'direction': np.column_stack([self.directions[rows], np.zeros((n, 3))]),
                   'rotor_frame': self._rotor_frame(base, rows)}
        context.update(select_rows(self._scalars, rows))
        return context

    def _rotor_frame(self, base, rows):
        """(n, 5, 5, 3): A's and C's rotor displacement (radial_1, radial_2, axial, m; see
        :func:`housing_frames`) as the target's shift in the camera frame, the channels
        camera_x, camera_y, camera_z."""
        model = model_from(np.array([base[n] for n in FITTED_NAMES]), self.camera_start)
        frame = np.zeros((len(rows), 5, 5, 3))
        frame[:, :2, 2:, :] = housing_frames(model, self.poses.a[rows])
        return frame

    def _residuals(self, base, delta, rows, turn_step=None):
        model = model_from(np.array([base[n] for n in FITTED_NAMES]), self.camera_start)
        turn = delta[:, :2] if turn_step is None else delta[:, :2] + turn_step
        return pose_residuals(model, self.frame, self.poses.subset(rows), self.lever,
                              turn=turn, shift=delta[:, 2:])

    def residuals(self, base, delta, rows, context):
        return self._residuals(base, delta, rows)

    def channel_residuals(self, base, delta, rows, context):
        """Per pose, the angle turns (rad) and target shift (m) that best explain its
        residual: least squares on the pose's 6 x 5 channel Jacobian."""
        r0 = self._residuals(base, delta, rows)
        jacobian = np.zeros((len(rows), 6, 5))
        for k in range(2):
            step = np.zeros((len(rows), 2))
            step[:, k] = ANGLE_STEP
            jacobian[:, :, k] = (r0 - self._residuals(base, delta, rows, step)) / ANGLE_STEP
        jacobian[:, :3, 2:] = np.eye(3)
        return np.einsum('nij,nj->ni', np.linalg.pinv(jacobian), r0)

    def row_errors(self, residuals):
        """Per pose, the norm of the target origin's position error and the lever arm
        times its orientation error (m): both kinds of error, one number."""
        return np.linalg.norm(residuals, axis=1)
