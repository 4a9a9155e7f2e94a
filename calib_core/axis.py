"""A single positioning axis measured against a reference (laser interferometer, ISO 230-2).

Base model: ``measured = command + offset + scale * command`` (m). Everything else an
axis shows (backlash, lead-screw periodic error, drift with time or temperature) is left
for the closed loop to find.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core import iso230_2
from calib_core.checks import MAX_ERROR_M, MAX_POSITION_M
from calib_core.closed_loop import (MachineModel, evaluate, refit, scalar_covariates,
                                    select_rows)
from calib_core.closed_loop.fitting import Fit, without_effects
from calib_core.datasets import read_columns, write_columns
from calib_core.description import LENGTH_UNITS, si_per_unit
from calib_core.effects import CATEGORICAL_COVARIATES
from calib_core.errors import InvalidInputError
from calib_core.parameters import Parameter, ParameterSet
from calib_core.schema import Column, Schema

# The axis CSV (DESIGN.md section 6), declared: what an axis of any machine here reads.
AXIS_SCHEMA = Schema((
    Column('command', 'm', -MAX_POSITION_M, MAX_POSITION_M, 'commanded axis position'),
    Column('measured - command', 'm', -MAX_ERROR_M, MAX_ERROR_M,
           'axis error, measured minus commanded')))

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
    def from_csv(cls, path, dropped: dict | None = None, length_unit: str = 'm',
                 error_unit: str | None = None) -> 'AxisData':
        """Read the axis CSV of DESIGN.md section 6: command, measured and direction; or
        command, error (measured - command, as a laser interferometer's software exports
        the deviation) and direction.

        Parameters
        ----------
        length_unit : str
            The unit of command and measured: m (the format's), mm, um or inch.
        error_unit : str, optional
            The unit of error; default ``length_unit``.

        Raises
        ------
        InvalidInputError
            Missing columns, both measured and error, an unknown unit, values outside what
            an axis reads (naming the likely unit mistake)."""
        columns = read_columns(path, ['command', 'direction'], dropped)
        given = [name for name in ('measured', 'error') if name in columns]
        if len(given) != 1:
            raise InvalidInputError(
                f'{path}: an axis CSV has a measured column (the position the reference read) '
                f'or an error column (measured - command); this one has '
                f'{"both" if given else "neither"}')
        per_unit = si_per_unit(length_unit, LENGTH_UNITS, f'{path}: the length unit')
        command = columns['command'] * per_unit
        if given == ['measured']:
            measured = columns['measured'] * per_unit
        else:
            measured = command + columns['error'] * si_per_unit(
                error_unit or length_unit, LENGTH_UNITS, f'{path}: the error unit')
        AXIS_SCHEMA.check({'command': command, 'measured - command': measured - command}, path)
        return cls(command, measured, columns['direction'],
                   {k: v for k, v in columns.items() if k not in AXIS_COLUMNS + ('error',)})

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
                  'warm_up', 'drift_time', 'drift_sequence', 'drift_temperature')

    def __init__(self, data: AxisData):
        self.data = data
        self._scalars = scalar_covariates(data.covariates)
        settings = np.column_stack([data.command, data.direction])
        self._replicates = np.unique(settings, axis=0, return_inverse=True)[1].ravel()

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
        return self._replicates

    def residuals(self, base, delta, rows, context):
        d = self.data
        predicted = d.command[rows] * (1 + base['scale']) + base['offset'] + delta[:, 0]
        return (d.measured[rows] - predicted)[:, None]


def predicted_error(model: AxisModel, fit, positions: np.ndarray, direction: float) -> np.ndarray:
    """The error (measured - command, m) ``fit`` predicts at ``positions`` (m) approached
    from ``direction``, in the reference state: time and temperature at the test's means,
    a start-up transient decayed, blocks and set-ups at their first level."""
    covariates = {}
    for key, values in model.data.covariates.items():
        values = np.asarray(values, float)
        if key in ('time', 'temperature'):
            covariates[key] = np.full(len(positions), values.mean())
        elif key == 'sequence':
            covariates[key] = np.full(len(positions), values.min() + 1e9)
        elif key in CATEGORICAL_COVARIATES:
            covariates[key] = np.full(len(positions), np.min(values))
    probe = AxisModel(AxisData(positions, positions, np.full(len(positions), direction),
                               covariates))
    # A drift over the run is zero at the run's mean approach; the sequence set past the
    # run's end for the transient's decay would extrapolate it.
    effects, values = without_effects(fit, ('drift_sequence',))
    steady = Fit(fit.base, effects, values, fit.residuals, fit.jacobian)
    return -evaluate(probe, steady, np.arange(len(positions)))[:, 0]


def iso230_2_before_after(model: AxisModel, fit) -> dict:
    """ISO 230-2 figures of the axis as measured, after the base model's linear
    compensation and after the extended model's, and the compensation table.

    The compensated deviations are predictions for data not fitted: each cycle is
    predicted by the model fitted to the other cycles (leave one cycle out), when the data
    have three or more cycles; otherwise in-sample, and the report says so.
    """
    data = model.data
    rows = np.arange(len(data))
    cycles = data.covariates.get('cycle')
    after_base = np.empty(len(data))
    after = np.empty(len(data))
    if cycles is not None and len(np.unique(cycles)) >= 3:
        method = 'leave one cycle out: each cycle predicted by the model fitted to the others'
        for cycle in np.unique(cycles):
            test, train = rows[cycles == cycle], rows[cycles != cycle]
            after_base[test] = evaluate(model, refit(model, fit, train, effects=False), test)[:, 0]
            after[test] = evaluate(model, refit(model, fit, train), test)[:, 0]
    else:
        method = 'in-sample (fewer than three cycles to leave one out)'
        after_base[:] = evaluate(model, refit(model, fit, rows, effects=False), rows)[:, 0]
        after[:] = evaluate(model, fit, rows)[:, 0]
    targets = np.unique(data.command)
    grid = np.union1d(targets, np.linspace(targets.min(), targets.max(), 101))
    table = iso230_2.compensation_table(grid, predicted_error(model, fit, grid, 1.0),
                                        predicted_error(model, fit, grid, -1.0))
    return {'method': method,
            'before': iso230_2.figures(data.command, data.measured - data.command, data.direction),
            'after_linear': iso230_2.figures(data.command, after_base, data.direction),
            'after': iso230_2.figures(data.command, after, data.direction),
            'compensation_table': table}


def write_compensation_table(path, table: list) -> None:
    """The table as CSV: position, correction_up, correction_down (m); add the correction
    to a command approached from below (up) or above (down)."""
    columns = np.array(table).T
    write_columns(path, ['position', 'correction_up', 'correction_down'], list(columns))
