"""A user's XY-Theta stage (issue 50): where its guides lie, where the calibration Marks
sit on its platform, its stroke, the camera that measures the Marks and how well, how its
chains are read and how repeatably they land, in one YAML file (``machine-align calibrate
stage --description``; examples ship in ``printer_alignment/descriptions/``):

```yaml
kind: stage
geometry:
  d_m: [0.268, 0.0395, 0.4315]     # chain 1's guide at y = d1, chains 2 and 3 at x = d2, d3
  marks_m: [[0.18, 0.13], [0.30, 0.13]]   # the calibration Marks, platform frame
instrument: {name: camera, position_sigma_m: 0.3e-6}   # a Mark's plate coordinate, 1 sigma
actuators: {unit: rev, m_per_unit: 2.0e-3, sigma_m: 1.2e-6}   # chains in revolutions; landing
repeatability_m: 0.0
workspace: {stroke_m: 5.0e-3}      # each chain's input limit either way
```

A chain's input is its nut's travel in m (the readings times ``m_per_unit``, the nominal
lead for revolutions), so the model's leads stay ratios to the nominal one. The gate then
refuses a calibration by what was declared: a Mark residual RMS above
:data:`calib_core.description.RESIDUAL_GATE_FACTOR` times what the camera, the chains'
landing and the repeatability give; the leads and the axis skew keep their built-in bounds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.description import (
    RESIDUAL_GATE_FACTOR, Instrument, Measurement, check_keys, read_description_file,
    read_measurement, refuse_unit_slip, workspace_numbers, workspace_section)
from calib_core.description import likely_causes as causes_from_travel
from calib_core.errors import InvalidInputError
from printer_alignment.core.alignment import rigid_fit
from printer_alignment.core.stage import (
    CAMERA_NOISE, LANDING_SIGMA, NOMINAL_D, NOMINAL_STAGE, STROKE, StageGeometry)
from printer_alignment.core.stage_calibration import StageData

GEOMETRY_KEYS = ('d_m', 'marks_m')
# m: how far the taught Marks' spacing may differ from the described one. Jogging a camera
# over a Mark puts it within its field (a few mm) of where it is, but the pair keeps its
# spacing to far better than that.
MARK_SPACING_TOLERANCE = 3e-3
# The shipped simulated stage (printer_alignment.sim.stage): its Marks, camera and landing.
SHIPPED_MARKS = ((0.180, 0.130), (0.300, 0.130))
SHIPPED_INSTRUMENT = Instrument('the shipped simulated camera', CAMERA_NOISE)


@dataclass(frozen=True)
class StageDescription:
    """A user's stage: guide places ``d`` (3,) m, calibration ``marks`` (2, 2) m (platform
    frame), ``stroke`` m, and how it is measured."""

    d: tuple
    marks: np.ndarray
    stroke: float
    measurement: Measurement
    source: str

    def nominal(self, home_marks=None) -> StageGeometry:
        """The described stage without errors, mounted in the plate frame as the shipped
        drawing mounts the shipped stage; given ``home_marks`` (2, 2) m, the Marks' plate
        positions with the stage at home as taught by jogging the camera over them,
        mounted where they put it: the rigid motion that takes the described Marks onto
        them (at home the platform frame is the stage frame).

        Raises
        ------
        InvalidInputError
            The taught Marks lie more than :data:`MARK_SPACING_TOLERANCE` further apart
            or closer than the described ones: one of the two is not this stage's."""
        nominal = NOMINAL_STAGE.with_changes(d=tuple(self.d))
        if home_marks is None:
            return nominal
        home_marks = np.asarray(home_marks, dtype=float)
        taught, described = (float(np.linalg.norm(np.diff(m, axis=0)))
                             for m in (home_marks, self.marks))
        if abs(taught - described) > MARK_SPACING_TOLERANCE:
            raise InvalidInputError(
                f'the taught calibration Marks are {taught * 1e3:.3f} mm apart, those of '
                f'{self.source} {described * 1e3:.3f} mm: one of the two is not this '
                "stage's (teach them again, or correct the description's marks_m)")
        angle, shift = rigid_fit(self.marks, home_marks)
        return nominal.with_changes(stage2plate=(float(shift[0]), float(shift[1]), angle))

    def landing_sigma(self) -> float:
        """A chain's landing scatter, m (1 sigma): its positioning noise and the
        repeatability in quadrature."""
        m = self.measurement
        return float(np.hypot(m.actuators.sigma_m, m.repeatability_m))

    def noise(self) -> dict:
        """The planner's and the simulation's noise keywords (m)."""
        return {'landing_sigma': self.landing_sigma(),
                'camera_noise': self.measurement.instrument.position_sigma_m}

    def expected_mark_rms(self) -> float:
        """Mark residual RMS (m, per coordinate) the declared noise gives a sound fit: the
        camera's and a chain's landing (which moves the platform, Marks and all, by about
        as much) in quadrature."""
        return float(np.hypot(self.measurement.instrument.position_sigma_m,
                              self.landing_sigma()))

    def residual_limit(self) -> float:
        return RESIDUAL_GATE_FACTOR * self.expected_mark_rms()

    def expected_text(self) -> str:
        m = self.measurement
        return (f'{m.instrument.name} at {m.instrument.position_sigma_m * 1e6:.3g} um, chains '
                f'landing within {self.landing_sigma() * 1e6:.3g} um give '
                f'{self.expected_mark_rms() * 1e6:.3g} um of Mark residual; the limit is '
                f'{RESIDUAL_GATE_FACTOR:g}x that ({m.sources()})')

    def gate_report(self) -> dict:
        """What a calibration's report says of the gate this description set (m)."""
        return {'file': self.source, 'residual_limit_m': self.residual_limit(),
                'expected_mark_rms_m': self.expected_mark_rms(),
                'unit': self.measurement.actuators.unit, 'expected': self.expected_text()}

    def read(self, path, dropped: dict | None = None) -> StageData:
        """A stage CSV whose q1..q3 are in the actuators' unit, as :class:`StageData` in m.

        Raises
        ------
        InvalidInputError
            As :meth:`StageData.from_csv`; and readings that move the Marks about 1000x
            more or less than they say (:func:`travel_ratio`,
            :func:`calib_core.description.refuse_unit_slip`): a unit slip, named, before
            any fit or analysis is made of them."""
        data = StageData.from_csv(path, dropped, self.measurement.actuators.m_per_unit,
                                  self.stroke)
        refuse_unit_slip(travel_ratio(data), self.measurement.actuators, 'chains',
                         f'{path} read by {self.source}')
        return data

    def write(self, path, data: StageData) -> None:
        """``data`` as a stage CSV with q1..q3 in the actuators' unit."""
        data.to_csv(path, self.measurement.actuators.m_per_unit)


def read_description(path) -> StageDescription:
    """A stage description YAML, validated (every error names the key)."""
    content = read_description_file(path, 'stage')
    where = str(path)
    geometry = check_keys(content['geometry'], GEOMETRY_KEYS, f'{where}: geometry')
    d = workspace_numbers(geometry.get('d_m', NOMINAL_D), 3, 'd_m', f'{where}: geometry', False)
    marks = workspace_numbers(geometry.get('marks_m', SHIPPED_MARKS), 4, 'marks_m',
                              f'{where}: geometry', False)
    if np.allclose(marks[:2], marks[2:]):
        raise InvalidInputError(f'{where}: geometry marks_m must be two different Marks')
    section = workspace_section(content, where, ('stroke_m',))
    stroke = (STROKE if section is None else
              workspace_numbers(section['stroke_m'], 1, 'stroke_m', where, True)[0])
    measurement = read_measurement(content, where, SHIPPED_INSTRUMENT, LANDING_SIGMA)
    return StageDescription(d, np.reshape(marks, (2, 2)), stroke, measurement, where)


def travel_ratio(data: StageData) -> float:
    """How far chain 1's readings (m, as declared) say it travelled against how far it
    moved the Marks: about 1 for readings in the declared unit. Chain 1 drives the
    platform along its guide one for one (q1 = x + (y - d1) tan theta), so the Marks'
    centroid, fitted linearly on the three inputs, moves by about 1 per unit of q1."""
    centroid = data.marks.mean(axis=1)
    design = np.column_stack([data.q, np.ones(len(data.q))])
    moved_per_input = np.linalg.lstsq(design, centroid, rcond=None)[0][0]
    return 1.0 / max(float(np.linalg.norm(moved_per_input)), 1e-12)


def likely_causes(data: StageData, description: StageDescription) -> str:
    """The likely causes of a Mark residual far above the declared noise or of leads far
    from the nominal, most likely first (:func:`calib_core.description.likely_causes`,
    from :func:`travel_ratio`)."""
    return causes_from_travel(travel_ratio(data), description.measurement.actuators,
                              'chains', 'stage model', 'machine-align analyze stage')
