"""The closed loop's view of the platform: rows are the identification's poses, channels
the three feeds, the base model the 18-parameter loop closure. An effect acting on a feed
(a ball screw's periodic error, backlash as the feed reverses, thermal drift) shifts the
slide from what the drive reports; the residual is the closure error in m, expressed in
each feed as the slide shift that would close it."""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop.model import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import directions_from_order
from calib_core.parameters import Parameter, ParameterSet
from platform_calib.core.geometry import UNITS, PlatformGeometry, parameter_names
from platform_calib.core.identification import PoseData, check_determined
from platform_calib.core.kinematics import feed_directions, joint_positions, slide_positions


class PlatformLoopModel(MachineModel):
    """A platform's pose data for the closed loop."""

    name = 'platform'
    linearise = True
    base_model = ('3-PRR, 18 parameters (per chain the feed zero, its direction, the link '
                  'and the platform joint); residual: loop closure |C_i - B_i| - L_i (m)')
    channels = ('feed1', 'feed2', 'feed3')
    candidates = ('periodic', 'reversal', 'scale', 'drift_temperature', 'drift_time',
                  'drift_sequence')

    def __init__(self, data: PoseData, nominal: PlatformGeometry):
        # What calibrate refuses, analyze refuses: the loop's base fit is the same.
        check_determined(data, nominal)
        self.data, self.nominal = data, nominal
        covariates = dict(data.covariates or {})
        direction = covariates.pop('direction', None)
        self.directions = (np.asarray(direction, dtype=float) if direction is not None
                           else directions_from_order(data.feeds))
        self._scalars = scalar_covariates(covariates)

    def __len__(self):
        return len(self.data)

    def initial(self) -> ParameterSet:
        return ParameterSet([Parameter(name, float(value), UNITS[name.rstrip('123')])
                             for name, value in zip(parameter_names(), self.nominal.vector())])

    def _geometry(self, base: ParameterSet) -> PlatformGeometry:
        return self.nominal.with_vector(np.array([base[n] for n in parameter_names()]))

    def context(self, base, rows):
        context = {'position': self.data.feeds[rows], 'direction': self.directions[rows]}
        context.update(select_rows(self._scalars, rows))
        return context

    def _gaps(self, base, delta, rows):
        geometry = self._geometry(base)
        feeds = self.data.feeds[rows] + delta
        d = joint_positions(geometry, self.data.poses[rows]) - slide_positions(geometry, feeds)
        return geometry, d

    def residuals(self, base, delta, rows, context):
        geometry, d = self._gaps(base, delta, rows)
        return np.linalg.norm(d, axis=-1) - geometry.length

    def channel_residuals(self, base, delta, rows, context):
        """The slide shift along each feed that would close each chain (m)."""
        geometry, d = self._gaps(base, delta, rows)
        distance = np.linalg.norm(d, axis=-1)
        along = np.sum(d * feed_directions(geometry), -1) / distance
        return (distance - geometry.length) / along

    def row_errors(self, residuals):
        """Closure errors, one per chain and pose (m)."""
        return np.abs(residuals).ravel()

    def workspace(self):
        return self.data.poses[:, :2]
