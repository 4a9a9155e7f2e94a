"""A single positioning axis measured against a reference (laser interferometer, ISO 230-2).

Base model: ``measured = command + offset + scale * command`` (m). Everything else an
axis shows (backlash, lead-screw periodic error, drift with time or temperature) is left
for the closed loop to find.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.closed_loop import MachineModel, scalar_covariates, select_rows
from calib_core.datasets import read_columns, write_columns
from calib_core.errors import InvalidInputError
from calib_core.parameters import Parameter, ParameterSet

AXIS_COLUMNS = ('command', 'measured', 'direction')
# Covariates the effect library knows; other extra columns are kept but not used.


@dataclass(frozen=True)
class AxisData:
    """Axis positioning measurements.

    Attributes
    ----------
    command, measured : ndarray (n,)
        Target and reference-measured position, m.
    direction : ndarray (n,)
        +1 approached from below, -1 from above.
    covariates : dict of str to ndarray (n,)
        Extra columns (cycle, time in s, temperature in K, ...).
    """

    command: np.ndarray
    measured: np.ndarray
    direction: np.ndarray
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        arrays = [np.asarray(a, dtype=float).ravel() for a in (self.command, self.measured,
                                                              self.direction)]
        if len({a.size for a in arrays}) != 1:
            raise InvalidInputError('command, measured and direction must have equal lengths')
        for name, a in zip(AXIS_COLUMNS, arrays):
            if not np.all(np.isfinite(a)):
                raise InvalidInputError(f'{name} contains NaN or infinite values')
        if not np.all(np.isin(arrays[2], (-1.0, 1.0))):
            raise InvalidInputError('direction must be +1 or -1 in every row')
        for name, value in zip(AXIS_COLUMNS, arrays):
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return len(self.command)

    @classmethod
    def from_csv(cls, path, dropped: dict | None = None) -> 'AxisData':
        """Read the axis CSV of DESIGN.md section 6 (command, measured in m; direction)."""
        columns = read_columns(path, list(AXIS_COLUMNS), dropped)
        return cls(columns['command'], columns['measured'], columns['direction'],
                   {k: v for k, v in columns.items() if k not in AXIS_COLUMNS})

    def to_csv(self, path) -> None:
        names = list(AXIS_COLUMNS) + list(self.covariates)
        write_columns(path, names, [self.command, self.measured, self.direction]
                      + [self.covariates[k] for k in self.covariates])


class AxisModel(MachineModel):
    """The closed loop's view of one axis: one channel, the axis position."""

    name = 'axis'
    base_model = 'measured = command + offset + scale * command (m)'
    channels = ('axis',)
    candidates = ('reversal', 'reversal_by_position', 'periodic', 'lead_error', 'block_step',
                  'warm_up', 'drift_time', 'drift_temperature')

    def __init__(self, data: AxisData):
        self.data = data
        self._scalars = scalar_covariates(data.covariates)

    def __len__(self):
        return len(self.data)

    def initial(self) -> ParameterSet:
        return ParameterSet([Parameter('offset', 0.0, 'm'), Parameter('scale', 0.0, '1')])

    def context(self, base, rows):
        d = self.data
        context = {'position': d.command[rows, None], 'direction': d.direction[rows, None]}
        context.update(select_rows(self._scalars, rows))
        return context

    def replicates(self):
        """Rows at one target approached from one direction repeat one setting."""
        settings = np.column_stack([self.data.command, self.data.direction])
        return np.unique(settings, axis=0, return_inverse=True)[1].ravel()

    def residuals(self, base, delta, rows, context):
        d = self.data
        predicted = d.command[rows] * (1 + base['scale']) + base['offset'] + delta[:, 0]
        return (d.measured[rows] - predicted)[:, None]
