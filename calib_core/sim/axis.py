"""A simulated ball-screw axis measured by a laser interferometer in an ISO 230-2 test.

True position error of the carriage (m)::

    offset + scale x - (backlash + backlash_change x / travel)/2 * direction
    + A sin(2 pi x / pitch + phase) + drift_rate t + expansion x (T - T0)
    + block_step [second half of the test] + noise

The test approaches irregularly spaced targets (as ISO 230-2 recommends, so periodic errors
are not aliased) from below and from above, cycle after cycle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.axis import AxisData
from calib_core.errors import InvalidInputError


@dataclass(frozen=True)
class AxisTruth:
    """The simulated axis's true errors (SI units)."""

    offset: float = 3e-6
    scale: float = 25e-6
    backlash: float = 0.0
    periodic_amplitude: float = 0.0
    pitch: float = 0.016
    periodic_phase: float = 0.7
    drift_rate: float = 0.0           # m/s
    expansion: float = 0.0            # 1/K, of the position
    temperature_rise: float = 0.0     # K over the whole test, linear in time
    noise: float = 0.3e-6             # m, 1 sigma, interferometer + repeatability
    backlash_change: float = 0.0      # m, change of the backlash from one end to the other
    block_step: float = 0.0           # m, shift of the second measurement block (re-set-up)


@dataclass(frozen=True)
class AxisTest:
    """The measurement plan: ``targets`` in [0, travel] m, ``cycles`` bidirectional runs,
    ``dwell`` s per target; targets jittered by up to 0.4 of their spacing when
    ``irregular`` (as ISO 230-2 recommends), else a regular grid; ``blocks`` > 1 splits
    the cycles into measurement blocks (column ``block``)."""

    travel: float = 0.2
    targets: int = 41
    cycles: int = 5
    dwell: float = 4.0
    irregular: bool = True
    blocks: int = 1

    def __post_init__(self):
        if self.travel <= 0 or self.targets < 3 or self.cycles < 1 or self.dwell <= 0:
            raise InvalidInputError('an axis test needs travel > 0, >= 3 targets, '
                                    '>= 1 cycle, dwell > 0')


def simulate_axis_test(truth: AxisTruth, test: AxisTest = AxisTest(), seed: int = 0,
                       bidirectional: bool = True) -> AxisData:
    """Run the test on the simulated axis; returns the interferometer data with covariates
    ``cycle``, ``sequence`` (approach number, 0 first), ``time`` (s), ``temperature`` (K)
    and, with more than one block, ``block``."""
    rng = np.random.default_rng(seed)
    step = test.travel / (test.targets - 1)
    targets = np.linspace(0, test.travel, test.targets)
    if test.irregular:
        targets[1:-1] += rng.uniform(-0.4, 0.4, test.targets - 2) * step
    runs = [(targets, 1.0)] + ([(targets[::-1], -1.0)] if bidirectional else [])
    command, direction, cycle = [], [], []
    for k in range(test.cycles):
        for run, sign in runs:
            command.append(run)
            direction.append(np.full(len(run), sign))
            cycle.append(np.full(len(run), k + 1.0))
    command, direction, cycle = map(np.concatenate, (command, direction, cycle))
    time = np.arange(len(command)) * test.dwell
    temperature = 293.15 + truth.temperature_rise * time / time[-1]
    block = 1.0 + np.floor((cycle - 1) * test.blocks / test.cycles)
    backlash = truth.backlash + truth.backlash_change * command / test.travel
    error = (truth.offset + truth.scale * command - 0.5 * backlash * direction
             + truth.block_step * (block > 1)
             + truth.periodic_amplitude * np.sin(2 * np.pi * command / truth.pitch
                                                 + truth.periodic_phase)
             + truth.drift_rate * time
             + truth.expansion * command * (temperature - 293.15)
             + rng.normal(0, truth.noise, len(command)))
    covariates = {'cycle': cycle, 'sequence': np.arange(len(command), dtype=float),
                  'time': time, 'temperature': temperature}
    if test.blocks > 1:
        covariates['block'] = block
    return AxisData(command, command + error, direction, covariates)
