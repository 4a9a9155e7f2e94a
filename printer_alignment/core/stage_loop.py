"""The XY-Theta stage as seen by the closed loop.

Base model: the stage error model of :class:`~printer_alignment.core.stage.StageGeometry`
without backlash (lead ratios, structural and angle errors, mounting, the calibration
Marks' positions on the platform; the parametric calibration's gauge fixed), predicting
the two calibration Marks in the plate frame. Channels are the three chains: an effect
term is added to the chain's input (m), so chain backlash is ``reversal``, lead-screw
error is ``periodic`` in the chain input, thermal growth of a screw is
``drift_temperature``.
"""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop import MachineModel, scalar_covariates, select_rows
from calib_core.parameters import Parameter, ParameterSet
from printer_alignment.core.stage_calibration import (
    PARAMETRIC_GAUGE, StageData, _rotate, mark_names, predict_marks, stepwise_calibration)
from printer_alignment.core.stage import StageGeometry

_STEP = 1e-6     # m, finite-difference step for the chains' effect on the Marks


class StageLoopModel(MachineModel):
    """The stage for the closed loop; residuals are the two Marks' (x, y) in m."""

    name = 'stage'
    base_model = ('3-PRP error model without backlash: lead ratios R1..R3, d3, beta1, beta3, '
                  'alpha1, alpha2, stage mounting and the Marks\' platform positions; '
                  'Marks predicted in the plate frame (m)')
    channels = ('chain1', 'chain2', 'chain3')
    candidates = ('reversal', 'periodic', 'drift_time', 'drift_temperature')

    def __init__(self, data: StageData):
        self.data = data
        self._scalars = scalar_covariates(data.covariates)
        self._start = stepwise_calibration(data)[0].geometry

    def __len__(self):
        return len(self.data)

    def initial(self) -> ParameterSet:
        geometry = self._start
        home = self.data.marks[np.argmin(np.abs(self.data.q).sum(axis=1))]
        pose0 = geometry.stage_to_plate(geometry.forward(np.zeros((1, 3))))[0]
        marks0 = _rotate(-pose0[2], home - pose0[:2])
        parameters = ParameterSet(geometry.as_parameters().parameters + [
            Parameter(n, float(v), 'm') for n, v in zip(mark_names(), marks0.ravel())])
        for name in list(PARAMETRIC_GAUGE) + ['backlash1', 'backlash2', 'backlash3']:
            parameters.set_free(name, False)
        return parameters

    def context(self, base, rows):
        context = {'position': self.data.q[rows], 'direction': self.data.directions[rows]}
        context.update(select_rows(self._scalars, rows))
        return context

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
        columns = []
        for chain in range(3):
            step = np.zeros(3)
            step[chain] = _STEP
            columns.append((self._predict(base, q + step) - self._predict(base, q - step))
                           / (2 * _STEP))
        sensitivity = np.stack(columns, axis=2)                          # (n, 4, 3)
        return np.array([np.linalg.lstsq(s, r, rcond=None)[0]
                         for s, r in zip(sensitivity, residual)])

    def workspace(self):
        return self.data.marks.mean(axis=1)
