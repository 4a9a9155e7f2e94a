"""A machine's residuals to first order about its base model's solution, so the closed
loop's hundreds of fits cost matrix products instead of forward kinematics.

The loop refits the base model with each candidate effect on every fold of every hold-out
split; on a machine whose prediction is an iterative solve (the stage's per-row Newton
forward kinematics, the rotary axes' pose chain) a finite-difference Jacobian over it cost
minutes. Effects move the channels by micrometres and the base parameters move by the
noise between subsets of the rows, so the first-order model

    r(b, delta) = r0 + J_b (b - b0) + J_delta delta        (per row, J_delta: k x C)

about the least-squares solution b0 of the base model on every row is exact to the square
of those changes (e.g. 0.1 um for a 100 um chain input on a 0.1 m lever). The effect
terms themselves stay exact: a period or a reversal is as nonlinear as before.
"""
from __future__ import annotations

import numpy as np

from calib_core.closed_loop.model import MachineModel, is_reference
from calib_core.errors import CalibrationError
from calib_core.parameters import ParameterSet

BASE_STEP = 1e-6
"""Relative central-difference step of the base parameters (times max(1, |value|))."""
CHANNEL_STEP = 1e-6
"""Central-difference step of the channels, in each channel's own unit (m or rad)."""


class LinearisedModel(MachineModel):
    """``machine`` linearised about ``base`` (its base model's least-squares solution).

    Everything but the residuals (names, channels, candidates, strata, replicates, row
    errors, workspace) is the machine's own; the context of every row is computed once at
    ``base``.

    Parameters
    ----------
    machine : MachineModel
    base : ParameterSet
        The expansion point: the base model fitted on every row.
    """

    def __init__(self, machine: MachineModel, base: ParameterSet):
        self.machine = machine
        self.expansion = base
        for name in ('name', 'base_model', 'unit', 'channels', 'channel_units',
                     'channel_blocks', 'effect_channels', 'candidates', 'min_effect'):
            setattr(self, name, getattr(machine, name))
        every = np.arange(len(machine))
        self._count = len(every)
        self._context = machine.context(base, every)
        width = len(machine.channels)
        zero = np.zeros((self._count, width))
        self._r0 = machine.residuals(base, zero, every, self._context)
        if not np.all(np.isfinite(self._r0)):
            raise CalibrationError('the base model\'s residuals are not finite at its solution')
        self._x0 = base.free_vector()
        columns = []
        for j, value in enumerate(self._x0):
            step = BASE_STEP * max(1.0, abs(value))
            shifted = []
            for sign in (1, -1):
                x = self._x0.copy()
                x[j] += sign * step
                shifted.append(machine.residuals(base.with_free_vector(x), zero, every,
                                                 self._context))
            columns.append((shifted[0] - shifted[1]) / (2 * step))
        self._base_jacobian = np.stack(columns, axis=-1) if columns else \
            np.zeros(self._r0.shape + (0,))                      # (N, k, P)
        columns = []
        for c in range(width):
            step = np.zeros((self._count, width))
            step[:, c] = CHANNEL_STEP
            columns.append((machine.residuals(base, step, every, self._context)
                            - machine.residuals(base, -step, every, self._context))
                           / (2 * CHANNEL_STEP))
        self._channel_jacobian = np.stack(columns, axis=-1)      # (N, k, C)
        # The channel shift that best explains a residual, as the machine defines it.
        self._to_channels = machine.to_channels(self._channel_jacobian)   # (N, C, k)

    def __len__(self):
        return self._count

    def __getattr__(self, name):
        # Anything else a report or plot asks of the machine (its data, geometry).
        if name == 'machine':
            raise AttributeError(name)
        return getattr(self.machine, name)

    def initial(self) -> ParameterSet:
        return self.expansion

    def context(self, base, rows):
        return {k: v if is_reference(k) or np.ndim(v) == 0 else np.asarray(v)[rows]
                for k, v in self._context.items()}

    def residuals(self, base, delta, rows, context):
        shift = base.free_vector() - self._x0
        return (self._r0[rows] + self._base_jacobian[rows] @ shift
                + np.einsum('nkc,nc->nk', self._channel_jacobian[rows], delta))

    def jacobian(self, effects: list, values: list, rows: np.ndarray,
                 context: dict) -> np.ndarray:
        """Jacobian of the residuals on ``rows`` (n k, P + effect parameters): the base
        block as stored, each effect's through the channels (its term differenced
        centrally, which costs no machine evaluation)."""
        n, k = len(rows), self._r0.shape[1]
        blocks = [self._base_jacobian[rows].reshape(n * k, -1)]
        channel_jacobian = self._channel_jacobian[rows]
        for effect, value in zip(effects, values):
            value = np.asarray(value, float)
            for j in range(len(value)):
                step = BASE_STEP * max(1.0, abs(value[j]))
                up, down = value.copy(), value.copy()
                up[j] += step
                down[j] -= step
                term = (effect.term(up, context) - effect.term(down, context)) / (2 * step)
                blocks.append(np.einsum('nkc,nc->nk', channel_jacobian, term).reshape(-1, 1))
        return np.hstack(blocks)

    def channel_residuals(self, base, delta, rows, context):
        residual = self.residuals(base, delta, rows, context)
        return np.einsum('nck,nk->nc', self._to_channels[rows], residual)

    def strata(self):
        return self.machine.strata()

    def replicates(self):
        return self.machine.replicates()

    def row_errors(self, residuals):
        return self.machine.row_errors(residuals)

    def workspace(self):
        return self.machine.workspace()

    def channel_scale(self, base):
        return self.machine.channel_scale(base)

    @property
    def stratum_name(self):
        return self.machine.stratum_name

    def stratum_label(self, stratum):
        return self.machine.stratum_label(stratum)
