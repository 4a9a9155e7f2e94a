"""The hexapod as seen by the closed loop: the 42-parameter model with effects acting on
the six actuator lengths.

Residual per leg (m): the length the geometry needs for the measured pose minus the
commanded length plus the effect terms, ``|p + R a_i - b_i| - o_i - (l_i + delta_i)``.
Covariates per leg come from CSV columns ``force1..force6`` (static axial leg force, N,
compression positive; or computed from a known payload) and ``direction1..direction6``
(direction of the last move of each actuator; without them, from the order of the rows).
"""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import directions_from_order
from calib_core.errors import InvalidInputError
from hexapod_calib.core.calibration import PoseData
from hexapod_calib.core.geometry import LEGS, HexapodGeometry
from hexapod_calib.core.kinematics import inverse_kinematics

FORCE_NAMES = tuple(f'force{i + 1}' for i in range(LEGS))
DIRECTION_NAMES = tuple(f'direction{i + 1}' for i in range(LEGS))


def _leg_columns(data: PoseData, names: tuple, what: str) -> np.ndarray | None:
    present = [n for n in names if n in data.covariates]
    if not present:
        return None
    if len(present) != LEGS:
        raise InvalidInputError(f'the data have {", ".join(present)} but {what} needs all of '
                                f'{names[0]}..{names[-1]} (or none)')
    return np.column_stack([data.covariates[n] for n in names])


class HexapodLoopModel(MachineModel):
    """The closed loop's view of a 6-SPS hexapod; channels are the legs."""

    name = 'hexapod'
    linearise = True
    base_model = ('6-SPS, 42 parameters: per leg the actuator offset and the base and '
                  'platform joint centres; residual in leg length (m)')
    channels = tuple(f'leg{i + 1}' for i in range(LEGS))
    candidates = ('leg_play', 'compliance', 'reversal', 'scale', 'drift_temperature', 'drift_time',
                  'drift_sequence')

    def __init__(self, data: PoseData, nominal: HexapodGeometry, forces: np.ndarray | None = None):
        """``forces`` (n, 6; N, compression positive) override any force columns."""
        self.data = data
        self.nominal = nominal
        self.forces = _leg_columns(data, FORCE_NAMES, 'leg force') if forces is None \
            else np.asarray(forces, dtype=float)
        if self.forces is not None and self.forces.shape != (len(data), LEGS):
            raise InvalidInputError(f'leg forces must have shape ({len(data)}, 6)')
        directions = _leg_columns(data, DIRECTION_NAMES, 'the direction of approach')
        self.directions = directions if directions is not None \
            else directions_from_order(data.leg_lengths)
        self._scalars = scalar_covariates(data.covariates)

    def __len__(self):
        return len(self.data)

    def initial(self):
        return self.nominal.parameters()

    def context(self, base, rows):
        context = {'position': self.data.leg_lengths[rows], 'direction': self.directions[rows]}
        if self.forces is not None:
            context['load'] = self.forces[rows]
        context.update(select_rows(self._scalars, rows))
        return context

    def residuals(self, base, delta, rows, context):
        geometry = HexapodGeometry.from_parameters(base)
        return (inverse_kinematics(geometry, self.data.measured[rows])
                - self.data.leg_lengths[rows] - delta)

    def row_errors(self, residuals):
        """Leg-length errors, one per leg and pose (m)."""
        return np.abs(residuals).ravel()
