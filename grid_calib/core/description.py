"""A user's 2-D stage self-calibrated with a grid plate (issue 50): the plate, the unit
the stage's readings are written in, how well the camera centres a mark and the stage
reads it, and the regions its travel is measured in, in one YAML file (``machine-align
calibrate grid --description``; examples ship in ``grid_calib/descriptions/``):

```yaml
kind: grid
geometry:
  pitch_m: 7.5e-3              # the plate's nominal pitch
  half: 4                      # 2 half + 1 marks a side
  certified_pitch_m: 7.50003e-3   # optional: the plate's certified mean pitch
instrument: {name: camera, position_sigma_m: 20.0e-9}   # a mark centred, 1 sigma per axis
actuators: {unit: mm, sigma_m: 10.0e-9}   # the stage's readings (x, y) and their noise
repeatability_m: 0.0
workspace: {regions: [3, 2]}   # columns, rows of plate placements over the travel
```

The gate then refuses a calibration by what was declared: a region's reading noise (its
residuals' scatter with the degrees of freedom counted) above
:data:`calib_core.description.RESIDUAL_GATE_FACTOR` times what the camera, the stage's
readings and the repeatability give (the built-in bound is 2 um of residual RMS, which
takes a fit 50x a 40 nm instrument's noise).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.description import (
    MAX_TRAVEL_RATIO, RESIDUAL_GATE_FACTOR, Instrument, Measurement, check_keys,
    described_number, is_unit_slip, read_description_file, read_measurement, workspace_numbers,
    workspace_section)
from calib_core.errors import InvalidInputError
from calib_core.files import read_csv_rows
from grid_calib.core.data import COLUMNS, read_marks, write_marks
from grid_calib.core.model import MAX_HALF, Grid
from grid_calib.errors import PlacementError

GEOMETRY_KEYS = ('pitch_m', 'half', 'certified_pitch_m')
# The shipped simulation (machine-align simulate grid): 20 nm readings, exact stage.
SHIPPED_INSTRUMENT = Instrument('the shipped simulated camera', 20e-9)


@dataclass(frozen=True)
class GridDescription:
    """A user's grid-plate setup: ``grid`` (half, nominal pitch m), the certified mean
    pitch (m) if known, the ``regions`` (columns, rows) and how it is measured."""

    grid: Grid
    certified_pitch: float | None
    regions: tuple
    measurement: Measurement
    source: str

    def expected_reading_rms(self) -> float:
        """A reading's noise (m, 1 sigma per axis) as declared: the camera's, the stage's
        readings' and the repeatability in quadrature; what a sound fit's residuals show
        with their degrees of freedom counted."""
        m = self.measurement
        return float(np.sqrt(m.instrument.position_sigma_m ** 2 + m.actuators.sigma_m ** 2
                             + m.repeatability_m ** 2))

    def residual_limit(self) -> float:
        return RESIDUAL_GATE_FACTOR * self.expected_reading_rms()

    def expected_text(self) -> str:
        m = self.measurement
        return (f'{m.instrument.name} at {m.instrument.position_sigma_m * 1e9:.3g} nm, '
                f'readings {m.actuators.sigma_m * 1e9:.3g} nm, repeatability '
                f'{m.repeatability_m * 1e9:.3g} nm give {self.expected_reading_rms() * 1e9:.3g} '
                f'nm of reading noise; the limit is {RESIDUAL_GATE_FACTOR:g}x that '
                f'({m.sources()})')

    @staticmethod
    def causes() -> str:
        """The likely causes of a reading residual above the limit, most likely first (a
        unit slip is refused when the file is read, :meth:`read`)."""
        return ('1. the camera or the stage\'s readings are noisier than declared; 2. the '
                'plate moved during a placement or was not placed as the method needs; 3. '
                'effects the self-calibration lacks (a stage growing as it warms: the grid '
                'calibrator\'s residual loop names it)')

    def gate_report(self) -> dict:
        """What a calibration's report says of the gate this description set (m)."""
        return {'file': self.source, 'residual_limit_m': self.residual_limit(),
                'expected_reading_rms_m': self.expected_reading_rms(),
                'unit': self.measurement.actuators.unit, 'expected': self.expected_text()}

    def read(self, path) -> tuple[Grid, dict]:
        """A marks CSV whose x, y are in the actuators' unit, as :func:`read_marks` gives it
        in m, of this plate's pitch.

        Raises
        ------
        InvalidInputError
            Neighbouring marks read more than 10x (or under a tenth of) a pitch apart:
            another unit (a slip of 1000x named as such) or another plate; as
            :func:`read_marks` otherwise."""
        scale = self.measurement.actuators.m_per_unit
        ratio = _pitch_ratio(path, scale, self.grid.pitch)
        if ratio is not None and not 1 / MAX_TRAVEL_RATIO <= ratio <= MAX_TRAVEL_RATIO:
            unit = self.measurement.actuators.unit
            raise InvalidInputError(
                f'{path}: neighbouring marks are read {ratio:.4g} pitches apart: the readings '
                + (f'are in a unit {"1000x smaller" if ratio > 1 else "1000x larger"} than '
                   f'the declared {unit}' if is_unit_slip(ratio) else
                   f'are not in the declared {unit}, or the pitch is not '
                   f'{self.grid.pitch:g} m') + f' ({self.source})')
        grid, regions = read_marks(path, self.grid.pitch, scale)
        if grid.half != self.grid.half:
            raise InvalidInputError(f'{path}: a {2 * grid.half + 1} x {2 * grid.half + 1} '
                                    f'plate, not the {2 * self.grid.half + 1} x '
                                    f'{2 * self.grid.half + 1} described in {self.source}')
        return grid, regions

    def write(self, path, regions: dict) -> None:
        """``regions`` as a marks CSV with x, y in the actuators' unit."""
        write_marks(path, self.grid, regions, self.measurement.actuators.m_per_unit)


def _pitch_ratio(path, scale: float, pitch: float) -> float | None:
    """The median distance between neighbouring marks (i and i + 1 in one row) of the
    file's first placement, in pitches; None where the file cannot say (read_marks then
    names what is wrong with it)."""
    rows = read_csv_rows(path, 'a grid marks CSV', COLUMNS, PlacementError)
    first = (rows[0]['region'], rows[0]['placement'])
    try:
        seen = {(int(r['i']), int(r['j'])): np.array([float(r['x']), float(r['y'])]) * scale
                for r in rows if (r['region'], r['placement']) == first}
    except (TypeError, ValueError):
        return None                 # read_marks names the bad value
    steps = [np.linalg.norm(seen[(i + 1, j)] - here) for (i, j), here in seen.items()
             if (i + 1, j) in seen]
    if not steps:
        return None
    return float(np.median(steps)) / pitch


def read_description(path) -> GridDescription:
    """A grid description YAML, validated (every error names the key)."""
    content = read_description_file(path, 'grid')
    where = str(path)
    geometry = check_keys(content['geometry'], GEOMETRY_KEYS, f'{where}: geometry')
    pitch = described_number(geometry, 'pitch_m', f'{where}: geometry', positive=True)
    half = geometry.get('half')
    if isinstance(half, bool) or not isinstance(half, int) or not 1 <= half <= MAX_HALF:
        raise InvalidInputError(f'{where}: geometry half must be a whole number 1..{MAX_HALF} '
                                f'(2 half + 1 marks a side), not {half!r}')
    certified = (described_number(geometry, 'certified_pitch_m', f'{where}: geometry',
                                  positive=True) if 'certified_pitch_m' in geometry else None)
    section = workspace_section(content, where, ('regions',))
    regions = (1, 1) if section is None else workspace_numbers(
        section['regions'], 2, 'regions', where, True)
    if any(v != int(v) or v > 10 for v in regions):
        raise InvalidInputError(f'{where}: workspace regions must be two whole numbers '
                                f'1..10 (columns, rows), not {section["regions"]!r}')
    measurement = read_measurement(content, where, SHIPPED_INSTRUMENT, 0.0)
    return GridDescription(Grid(half, pitch), certified, tuple(int(v) for v in regions),
                           measurement, where)
