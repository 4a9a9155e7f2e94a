"""The printer's machines as seen by the closed loop: the camera gantry, the camera and
the XY-Theta stage.

Gantry base model (the paper's, without the non-orthogonality the loop may add as
``squareness``)::

    measured = R(a) [(1 + s_x) c_x + delta_x, (1 + s_y) c_y + delta_y] + [x0, y0]

with commanded axis positions c (m, converted from motor angles with the nominal leads),
scale errors s (the lead ratios Rx / Rx_nominal - 1), camera-axis angle a (rad) and the
effect terms delta acting on the axes. Squareness gamma equals minus the paper's
non-orthogonality t.

Camera base model: a pinhole camera (fx, fy, cx, cy in px; one pose per view) without
distortion; the effects act on normalised image coordinates exactly as OpenCV's
distortion model does.

Stage base model: the stage error model of :class:`~printer_alignment.core.stage.StageGeometry`
without backlash (lead ratios, structural and angle errors, mounting, the calibration
Marks' positions on the platform; the parametric calibration's gauge fixed), predicting
the two calibration Marks in the plate frame. Channels are the three chains: an effect
term is added to the chain's input (m), so chain backlash is ``reversal``, lead-screw
error is ``periodic`` in the chain input, thermal growth of a screw is
``drift_temperature``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calib_core.checks import MAX_ERROR_M, MAX_POSITION_M
from calib_core.closed_loop import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import directions_from_order, read_columns, write_columns
from calib_core.description import LENGTH_UNITS, si_per_unit
from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.parameters import Parameter, ParameterSet
from calib_core.schema import Column, Schema
from printer_alignment.core.camera_calibration import View, infer_image_size
from printer_alignment.core.geometry import rotate_points, rotation
from printer_alignment.core.stage import NOMINAL_D, StageGeometry
from printer_alignment.core.stage_calibration import (
    PARAMETRIC_GAUGE, StageData, mark_names, predict_marks, stepwise_calibration)

# The gantry CSV, declared: camera positions anywhere on a machine, errors up to 10 cm.
GANTRY_SCHEMA = Schema((
    *(Column(f'command_{a}', 'm', -MAX_POSITION_M, MAX_POSITION_M, f'commanded {a}')
      for a in 'xy'),
    *(Column(f'measured - command ({a})', 'm', -10 * MAX_ERROR_M, 10 * MAX_ERROR_M,
             f'gantry error in {a}') for a in 'xy')))
GANTRY_COLUMNS = ('command_x', 'command_y', 'measured_x', 'measured_y')
DIRECTION_COLUMNS = ('direction_x', 'direction_y')


@dataclass(frozen=True)
class GantryData:
    """Camera positions measured at commanded gantry positions.

    Attributes
    ----------
    command : ndarray (n, 2)
        Commanded axis positions, m.
    measured : ndarray (n, 2)
        Camera position in the plate frame measured through the camera, m.
    direction : ndarray (n, 2)
        Direction of approach per axis (+1 / -1).
    covariates : dict of str to ndarray (n,)
    """

    command: np.ndarray
    measured: np.ndarray
    direction: np.ndarray
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        for name in ('command', 'measured', 'direction'):
            value = np.atleast_2d(np.asarray(getattr(self, name), dtype=float))
            if value.ndim != 2 or value.shape[1] != 2:
                raise InvalidInputError(f'{name} must have shape (n, 2), got {value.shape}')
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} contains NaN or infinite values')
            object.__setattr__(self, name, value)
        if not (len(self.command) == len(self.measured) == len(self.direction)):
            raise InvalidInputError('command, measured and direction need the same rows')
        if not np.all(np.isin(self.direction, (-1.0, 1.0))):
            raise InvalidInputError('directions must be +1 or -1')

    def __len__(self) -> int:
        return len(self.command)

    @classmethod
    def from_csv(cls, path, dropped: dict | None = None, length_unit: str = 'm'
                 ) -> 'GantryData':
        """Columns command_x, command_y, measured_x, measured_y (m, or ``length_unit``: mm,
        um, inch); optional direction_x, direction_y (+1 / -1; without them, from the order
        of the rows), time (s), temperature (K)."""
        columns = read_columns(path, list(GANTRY_COLUMNS), dropped)
        per_unit = si_per_unit(length_unit, LENGTH_UNITS, f'{path}: the length unit')
        command = np.column_stack([columns['command_x'], columns['command_y']]) * per_unit
        measured = np.column_stack([columns['measured_x'], columns['measured_y']]) * per_unit
        error = measured - command
        GANTRY_SCHEMA.check({'command_x': command[:, 0], 'command_y': command[:, 1],
                             'measured - command (x)': error[:, 0],
                             'measured - command (y)': error[:, 1]}, path)
        present = [c for c in DIRECTION_COLUMNS if c in columns]
        if len(present) == 1:
            raise InvalidInputError(f'{path} has {present[0]} but not the other direction column')
        direction = (np.column_stack([columns[c] for c in DIRECTION_COLUMNS]) if present
                     else directions_from_order(command))
        used = set(GANTRY_COLUMNS) | set(DIRECTION_COLUMNS)
        return cls(command, measured, direction,
                   {k: v for k, v in columns.items() if k not in used})

    def to_csv(self, path) -> None:
        names = list(GANTRY_COLUMNS) + list(DIRECTION_COLUMNS) + list(self.covariates)
        write_columns(path, names, [self.command, self.measured, self.direction]
                      + [self.covariates[k] for k in self.covariates])


class GantryLoopModel(MachineModel):
    """The camera gantry for the closed loop; channels are the two axes."""

    name = 'gantry'
    base_model = ('measured = R(axis_angle) [(1 + scale_x) command_x, (1 + scale_y) command_y] '
                  '+ offset (m); the paper\'s model without non-orthogonality')
    channels = ('x', 'y')
    candidates = ('squareness', 'reversal', 'periodic', 'smooth_map', 'drift_time',
                  'drift_sequence', 'drift_temperature')

    def __init__(self, data: GantryData):
        self.data = data
        self._scalars = scalar_covariates(data.covariates)

    def __len__(self):
        return len(self.data)

    def initial(self) -> ParameterSet:
        d = self.data
        start = np.mean(d.measured - d.command, axis=0)
        return ParameterSet([Parameter('scale_x', 0.0, '1'), Parameter('scale_y', 0.0, '1'),
                             Parameter('axis_angle', 0.0, 'rad'),
                             Parameter('offset_x', float(start[0]), 'm'),
                             Parameter('offset_y', float(start[1]), 'm')])

    def context(self, base, rows):
        d = self.data
        context = {'position': d.command[rows], 'direction': d.direction[rows]}
        context.update(select_rows(self._scalars, rows))
        return context

    def _axes(self, base, delta, rows):
        scale = 1 + np.array([base['scale_x'], base['scale_y']])
        return self.data.command[rows] * scale + delta

    def residuals(self, base, delta, rows, context):
        offset = np.array([base['offset_x'], base['offset_y']])
        predicted = self._axes(base, delta, rows) @ rotation(base['axis_angle']).T + offset
        return self.data.measured[rows] - predicted

    def channel_residuals(self, base, delta, rows, context):
        return self.residuals(base, delta, rows, context) @ rotation(base['axis_angle'])

    def workspace(self):
        return self.data.command


def _rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors (n, 3), rad."""
    angle = np.linalg.norm(rvecs, axis=1)
    safe = np.where(angle > 0, angle, 1.0)
    k = rvecs / safe[:, None]
    kx = np.zeros((len(rvecs), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx = kx - np.swapaxes(kx, 1, 2)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


class CameraLoopModel(MachineModel):
    """A camera seen through planar-target correspondences; channels are the normalised
    image coordinates. The base model starts from OpenCV's calibration with every
    distortion coefficient held at zero."""

    name = 'camera'
    base_model = 'pinhole without distortion: fx, fy, cx, cy (px) and one pose per view'
    unit = 'px'
    min_effect = 0.01   # px
    channels = ('x_n', 'y_n')
    candidates = ('radial_distortion', 'radial_distortion_k3', 'tangential_distortion')

    def __init__(self, views: list[View], image_size: tuple[int, int] | None = None):
        if len(views) < 2:
            raise CalibrationError(f'camera intrinsics need at least 2 views, got {len(views)}')
        for i, view in enumerate(views):
            if len(view.model) < 6:
                raise CalibrationError(f'view {i} has {len(view.model)} points; at least 6 '
                                       'are needed')
        self.views = views
        self.image_size = image_size or infer_image_size(views)
        self.view_index = np.concatenate([np.full(len(v.model), i) for i, v in enumerate(views)])
        self.points = np.concatenate([np.column_stack([v.model, np.zeros(len(v.model))])
                                      for v in views])
        self.pixels = np.concatenate([v.pixels for v in views])
        self._last_context = None

    def __len__(self):
        return len(self.points)

    def initial(self) -> ParameterSet:
        flags = (cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
                 | cv2.CALIB_ZERO_TANGENT_DIST)
        objects = [np.column_stack([v.model, np.zeros(len(v.model))]).astype(np.float32)
                   for v in self.views]
        images = [v.pixels.astype(np.float32) for v in self.views]
        try:
            _, matrix, _, rvecs, tvecs = cv2.calibrateCamera(objects, images, self.image_size,
                                                             None, None, flags=flags)
        except cv2.error as error:
            raise CalibrationError(f'OpenCV could not calibrate the pinhole model: {error}') from None
        parameters = [Parameter('fx', matrix[0, 0], 'px'), Parameter('fy', matrix[1, 1], 'px'),
                      Parameter('cx', matrix[0, 2], 'px'), Parameter('cy', matrix[1, 2], 'px')]
        for i, (r, t) in enumerate(zip(rvecs, tvecs)):
            parameters += [Parameter(f'view{i}_r{a}', float(v), 'rad') for a, v in zip('xyz', r.ravel())]
            parameters += [Parameter(f'view{i}_t{a}', float(v), 'm') for a, v in zip('xyz', t.ravel())]
        return ParameterSet(parameters)

    def base_sparsity(self, base, rows):
        """Intrinsics move every point, a view's pose only its own view's points."""
        free = base.free_names
        view = self.view_index[rows]
        pattern = np.zeros((len(rows), 2, len(free)), bool)
        for j, name in enumerate(free):
            if name.startswith('view'):
                pattern[view == int(name[4:].split('_')[0]), :, j] = True
            else:
                pattern[:, :, j] = True
        return pattern.reshape(-1, len(free))

    def context(self, base, rows):
        poses = np.array([p.value for p in base.parameters[4:]]).reshape(len(self.views), 6)
        # A fit's finite differences step the intrinsics and the effects as often as the
        # poses; the points' normalised coordinates depend on the poses alone.
        cached = self._last_context
        if cached is not None and cached[0] is rows and np.array_equal(cached[1], poses):
            return cached[2]
        rotations, translations = _rodrigues(poses[:, :3]), poses[:, 3:]
        v = self.view_index[rows]
        camera = np.einsum('nij,nj->ni', rotations[v], self.points[rows]) + translations[v]
        if np.any(camera[:, 2] <= 0):
            raise CalibrationError('a target point lies behind the camera')
        context = {'normalized': camera[:, :2] / camera[:, 2:3]}
        self._last_context = (rows, poses, context)
        return context

    def _project(self, base, normalized):
        return np.column_stack([base['fx'] * normalized[:, 0] + base['cx'],
                                base['fy'] * normalized[:, 1] + base['cy']])

    def residuals(self, base, delta, rows, context):
        normalized = context['normalized'] + delta
        return self.pixels[rows] - self._project(base, normalized)

    def channel_residuals(self, base, delta, rows, context):
        return self.residuals(base, delta, rows, context) / self.channel_scale(base)

    def channel_scale(self, base):
        """px per unit of normalised image coordinate: the focal lengths."""
        return np.array([base['fx'], base['fy']])

    stratum_name = 'view'

    def strata(self):
        return self.view_index

    def stratum_label(self, stratum):
        return self.views[stratum].label or str(stratum)

    def workspace(self):
        return self.pixels


_STEP = 1e-6     # m, finite-difference step for the chains' effect on the Marks


class StageLoopModel(MachineModel):
    """The stage for the closed loop; residuals are the two Marks' (x, y) in m."""

    name = 'stage'
    linearise = True
    base_model = ('3-PRP error model without backlash: lead ratios R1..R3, d3, beta1, beta3, '
                  'alpha1, alpha2, stage mounting and the Marks\' platform positions; '
                  'Marks predicted in the plate frame (m)')
    channels = ('chain1', 'chain2', 'chain3')
    candidates = ('reversal', 'periodic', 'smooth_map', 'drift_time', 'drift_sequence',
                  'drift_temperature')

    def __init__(self, data: StageData, nominal_d=NOMINAL_D):
        self.data = data
        self._scalars = scalar_covariates(data.covariates)
        self._start = stepwise_calibration(data, nominal_d)[0].geometry
        self._translation_inputs = None

    def __len__(self):
        return len(self.data)

    def initial(self) -> ParameterSet:
        geometry = self._start
        home = self.data.marks[np.argmin(np.abs(self.data.q).sum(axis=1))]
        pose0 = geometry.stage_to_plate(geometry.forward(np.zeros((1, 3))))[0]
        marks0 = rotate_points(-pose0[2], home - pose0[:2])
        parameters = ParameterSet(geometry.as_parameters().parameters + [
            Parameter(n, float(v), 'm') for n, v in zip(mark_names(), marks0.ravel())])
        for name in list(PARAMETRIC_GAUGE) + ['backlash1', 'backlash2', 'backlash3']:
            parameters.set_free(name, False)
        return parameters

    def context(self, base, rows):
        # The platform's place in the plate frame (the Marks' mean as measured) and the
        # chain inputs that move it by a unit in x and in y: where a smooth map of the
        # platform's error is fitted, and how it reaches the chains.
        context = {'position': self.data.q[rows], 'direction': self.data.directions[rows],
                   'map_position': self.data.marks[rows].mean(axis=1),
                   'map_to_channels': self._plate_to_chains()[rows]}
        context.update(select_rows(self._scalars, rows))
        return context

    def _plate_to_chains(self) -> np.ndarray:
        """(N, 3, 2): the chain inputs (m) that move both Marks by 1 m in the plate's x and
        in its y, at each row's inputs under the starting model (the least-squares inverse of
        the Marks' sensitivity to the chains; it changes by parts per thousand over the
        stroke and with the parameters' corrections)."""
        if self._translation_inputs is None:
            base = self.initial()
            sensitivity = self._sensitivity(base, self.data.q)               # (N, 4, 3)
            translation = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
            self._translation_inputs = np.linalg.pinv(sensitivity) @ translation
        return self._translation_inputs

    def _sensitivity(self, base, q) -> np.ndarray:
        """The Marks' change per unit input of each chain at inputs ``q``, (n, 4, 3)."""
        columns = []
        for chain in range(3):
            step = np.zeros(3)
            step[chain] = _STEP
            columns.append((self._predict(base, q + step) - self._predict(base, q - step))
                           / (2 * _STEP))
        return np.stack(columns, axis=2)

    def _predict(self, base, q):
        values = base.as_dict()
        geometry = StageGeometry.from_parameters(values)
        marks = np.array([values[n] for n in mark_names()]).reshape(2, 2)
        return predict_marks(geometry, marks, q, np.ones_like(q)).reshape(len(q), 4)

    def residuals(self, base, delta, rows, context):
        return self.data.marks[rows].reshape(-1, 4) - self._predict(base, self.data.q[rows] + delta)

    def channel_residuals(self, base, delta, rows, context):
        """Residuals as chain inputs (m): least squares through the Marks' sensitivity to
        each chain at each row."""
        q = self.data.q[rows] + delta
        residual = self.data.marks[rows].reshape(-1, 4) - self._predict(base, q)
        return np.array([np.linalg.lstsq(s, r, rcond=None)[0]
                         for s, r in zip(self._sensitivity(base, q), residual)])

    def workspace(self):
        return self.data.marks.mean(axis=1)
