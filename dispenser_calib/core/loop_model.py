"""The closed loop's view of the rotary axes measured by target poses
(:mod:`dispenser_calib.core.rotary`): rows are the poses, the base model the 14 parameters
(the axes as lines, the camera's orientation, the target's place), channels the two table
angles (rad), a shift of the target in the camera frame (m) and a turn of the target about
its origin, a rotation vector in the camera frame (rad). An effect on an angle is the
table turning other than its reading says (a worm gear, an encoder's eccentricity, lost
motion as the axis reverses); one on the shift is the target moving against the
instrument (thermal drift of a stand or of the Z column); the rotor's error motion
(ISO 230-7) shifts and tilts it.

A row has six residuals and the channels are eight: a turn about A's axis is a turn of
the target and a shift at once. The residual's view in the channels is therefore found
in two blocks, each explaining the whole residual on its own: the angles with the shift,
and the turn alone (what a tilt of a rotor's axis shows)."""
from __future__ import annotations

import copy

import numpy as np

from calib_core.closed_loop.model import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import directions_from_order
from calib_core.effects.rotary import commanded_places
from calib_core.parameters import Parameter, ParameterSet
from dispenser_calib.core.rotary import (
    FITTED_NAMES, LEVER, housing_frames, identify_rotary_axes, model_from, pose_residuals,
    tilt_arms)
from dispenser_calib.core.target_poses import TargetPoses

CHANNEL_STEP = 1e-6   # rad or m: finite-difference step of the channel Jacobian
SHIFT = ('camera_x', 'camera_y', 'camera_z')
TURN = ('turn_x', 'turn_y', 'turn_z')


def _unit(name: str) -> str:
    return 'rad' if name.startswith(('camera_r', 'a_tilt', 'c_tilt')) else 'm'


class RotaryLoopModel(MachineModel):
    """Measured target poses on the tilting-rotary table for the closed loop."""

    name = 'rotary axes'
    linearise = True
    base_model = ('A and C as lines (two tilts and two offsets each), the camera\'s '
                  'orientation and the target\'s place: 14 parameters; residual: the target '
                  'origin\'s position and the lever arm times its orientation error (m)')
    channels = ('a', 'c') + SHIFT + TURN
    channel_units = ('rad', 'rad', 'm', 'm', 'm', 'rad', 'rad', 'rad')
    channel_blocks = (('a', 'c') + SHIFT, TURN)
    candidates = ('scale', 'angular_harmonics', 'error_motion', 'reversal', 'drift_time',
                  'drift_sequence', 'drift_temperature')
    # Encoders turn, gears wobble and axes reverse; heat moves the target against the camera.
    effect_channels = {'scale': ('a', 'c'), 'angular_harmonics': ('a', 'c'),
                       'reversal': ('a', 'c'), 'drift_time': SHIFT, 'drift_sequence': SHIFT,
                       'drift_temperature': SHIFT}
    min_effect = 1e-6

    def __init__(self, poses: TargetPoses, lever: float = LEVER, variants=None):
        """``variants``: where the poses were measured through a calibrated camera, a
        callable giving them as measured through each one-sigma variant of its calibration
        (:func:`dispenser_calib.core.target_poses.pose_variants`), called only when an
        effect is to be added (:meth:`input_variants`)."""
        self.poses, self.lever, self._variants = poses, lever, variants
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
        # How a channel term looks in the channel residuals (N, 8, 8): the two blocks see a
        # tilt about A's direction partly as a turn of A, and the error-motion screen must
        # expect that. Once, at the base model on every pose: it moves with the base only
        # to second order, and only the screen reads it.
        every = np.arange(len(poses))
        zero = np.zeros((len(poses), len(self.channels)))
        jacobian = self._channel_jacobian(self.initial(), zero, every)[1]
        self._seen = -np.einsum('nck,nkd->ncd', self.to_channels(jacobian), jacobian)

    def __len__(self):
        return len(self.poses)

    def input_variants(self):
        """This machine with each variant's poses in place of its own, all else (the
        identification, the frames, the screen's view) kept: the loop evaluates the
        variants at its own fit's parameters (:mod:`calib_core.closed_loop.inputs`)."""
        if self._variants is None:
            return None
        out = []
        for poses in self._variants():
            variant = copy.copy(self)
            variant.poses, variant._variants = poses, None
            out.append(variant)
        return out

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
        context = {'position': np.column_stack([places, np.zeros((n, 6))]),
                   'angle': np.column_stack([angles, np.full((n, 6), np.nan)]),
                   'direction': np.column_stack([self.directions[rows], np.zeros((n, 6))]),
                   'rotor_frame': self._rotor_frame(base, rows)}
        context['rotor_view'] = np.einsum('ncd,nidm->nicm', self._seen[rows],
                                          context['rotor_frame'])
        context.update(select_rows(self._scalars, rows))
        return context

    def _rotor_frame(self, base, rows):
        """(n, 8, 8, 5): A's and C's rotor displacement (radial_1, radial_2, axial, m) and
        tilt (about radial_1 and radial_2, rad; see :func:`housing_frames`) as the
        channels' terms: a displacement shifts the target in the camera frame, a tilt about
        the pivot of :func:`tilt_arms` turns it and shifts its origin by tilt x arm."""
        model = model_from(np.array([base[n] for n in FITTED_NAMES]), self.camera_start)
        a, c = self.poses.a[rows], self.poses.c[rows]
        housing, arms = housing_frames(model, a), tilt_arms(model, a, c)
        frame = np.zeros((len(rows), 8, 8, 5))
        for axis in range(2):
            frame[:, axis, 2:5, :3] = housing[:, axis]
            for k in range(2):
                tilt = housing[:, axis, :, k]
                frame[:, axis, 5:, 3 + k] = tilt
                frame[:, axis, 2:5, 3 + k] = np.cross(tilt, arms[:, axis])
        return frame

    def _residuals(self, base, delta, rows):
        model = model_from(np.array([base[n] for n in FITTED_NAMES]), self.camera_start)
        return pose_residuals(model, self.frame, self.poses.subset(rows), self.lever,
                              turn=delta[:, :2], shift=delta[:, 2:5], rotate=delta[:, 5:])

    def residuals(self, base, delta, rows, context):
        return self._residuals(base, delta, rows)

    def _channel_jacobian(self, base, delta, rows):
        """The residuals (n, 6) and their derivative by each channel's term (n, 6, 8)."""
        r0 = self._residuals(base, delta, rows)
        jacobian = np.zeros(r0.shape + (len(self.channels),))
        for k in range(len(self.channels)):
            step = delta.copy()
            step[:, k] += CHANNEL_STEP
            jacobian[:, :, k] = (self._residuals(base, step, rows) - r0) / CHANNEL_STEP
        return r0, jacobian

    def channel_residuals(self, base, delta, rows, context):
        """Per pose, the angle turns and target shift (rad, m) that best explain its
        residual, and apart from them the target's turn (rad) that does: least squares
        per block of :attr:`channel_blocks` on the pose's channel Jacobian."""
        r0, jacobian = self._channel_jacobian(base, delta, rows)
        return np.einsum('nck,nk->nc', self.to_channels(jacobian), r0)

    def row_errors(self, residuals):
        """Per pose, the norm of the target origin's position error and the lever arm
        times its orientation error (m): both kinds of error, one number."""
        return np.linalg.norm(residuals, axis=1)
