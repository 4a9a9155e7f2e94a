"""A user's hexapod (issue 50): its nominal geometry, the instrument that measures its
platform, how its legs are read and its repeatability, in one YAML file
(``machine-align calibrate hexapod --description``; an example ships as
``hexapod_calib/descriptions/hexapod_0.8m_motion_capture.yaml``):

```yaml
kind: hexapod
geometry: {base_joints: [[x, y, z], ...], platform_joints: [...], leg_length_offsets: [...]}
instrument: {name: motion capture, position_sigma_m: 0.4e-3, angle_sigma_rad: 2.0e-3}
actuators: {unit: rev, m_per_unit: 5.0e-3, sigma_m: 5.0e-6}
repeatability_m: 20.0e-6
workspace:          # where the machine works: plans and simulations stay in it
  home: [0, 0, 0.58, 0, 0, 0]         # m, rad
  translation_m: [0.06, 0.06, 0.04]   # half-widths of the box about home
  rotation_rad: [0.07, 0.07, 0.07]
  stroke_m: [0.03, 0.17]              # actuator readings (in m) the legs may take
```

The gate then refuses an identification by what was declared: a leg-length residual
above :data:`calib_core.description.RESIDUAL_GATE_FACTOR` times what the instrument,
actuators and repeatability give per leg, or a joint or offset further from the nominal
than a share of the machine's size.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.description import (
    RESIDUAL_GATE_FACTOR, Instrument, Measurement, read_description_file, read_measurement,
    workspace_numbers, workspace_section)
from calib_core.description import likely_causes as causes_from_travel
from calib_core.errors import InvalidInputError
from hexapod_calib.core.geometry import HexapodGeometry, as_poses
from hexapod_calib.core.kinematics import inverse_kinematics
from hexapod_calib.core.planning import ACTUATOR_NOISE, ANGLE_NOISE, POSITION_NOISE
from hexapod_calib.core.procedure import HexapodPlan

WORKSPACE_KEYS = ('home', 'translation_m', 'rotation_rad', 'stroke_m')
SHIPPED_INSTRUMENT = Instrument('the shipped simulated pose sensor', POSITION_NOISE, ANGLE_NOISE)
SHIPPED_ACTUATOR_SIGMA_M = ACTUATOR_NOISE
PARAMETER_BOUND_SHARE = 0.25
"""A joint centre or leg offset more than this share of the base radius from the nominal
is another machine (or another nominal): 102 mm on a 0.41 m base, 50 mm on a 0.2 m one."""
MIN_PARAMETER_BOUND_M = 10e-3


@dataclass(frozen=True)
class HexapodDescription:
    """A user's hexapod: nominal ``geometry`` and how it is measured."""

    geometry: HexapodGeometry
    measurement: Measurement
    source: str
    workspace: dict | None = None       # HexapodPlan's home, translation, rotation, stroke

    def plan(self, **settings) -> HexapodPlan:
        """A plan in this machine's workspace (the shipped machine's where none is
        declared); ``settings`` as :class:`HexapodPlan`'s."""
        return HexapodPlan(**(self.workspace or {}), **settings)

    def expected_leg_rms(self) -> float:
        """Leg-length residual (m, 1 sigma) the declared noise gives a sound fit: the
        instrument's position noise, its angle noise on the platform's radius, the
        actuators' noise and the repeatability, in quadrature."""
        m = self.measurement
        radius = float(np.mean(np.linalg.norm(self.geometry.platform_joints[:, :2], axis=1)))
        return float(np.sqrt(m.instrument.position_sigma_m ** 2
                             + (m.instrument.angle_sigma_rad * radius) ** 2
                             + m.actuators.sigma_m ** 2 + m.repeatability_m ** 2))

    def residual_limit(self) -> float:
        return RESIDUAL_GATE_FACTOR * self.expected_leg_rms()

    def parameter_bound(self) -> float:
        """How far (m) a joint centre or leg offset may lie from the nominal."""
        radius = float(np.mean(np.linalg.norm(self.geometry.base_joints[:, :2], axis=1)))
        return max(MIN_PARAMETER_BOUND_M, PARAMETER_BOUND_SHARE * radius)

    def gate_report(self) -> dict:
        """What a calibration's report says of the gate this description set: the file,
        the residual limit and expected residual and the parameter bound (m), in words too."""
        return {'file': self.source, 'residual_limit_m': self.residual_limit(),
                'parameter_bound_m': self.parameter_bound(),
                'expected_leg_rms_m': self.expected_leg_rms(), 'expected': self.expected_text()}

    def expected_text(self) -> str:
        m = self.measurement
        return (f'{m.instrument.name} at {m.instrument.position_sigma_m * 1e3:.3g} mm and '
                f'{m.instrument.angle_sigma_rad * 1e3:.3g} mrad, actuators '
                f'{m.actuators.sigma_m * 1e6:.3g} um, repeatability '
                f'{m.repeatability_m * 1e6:.3g} um give {self.expected_leg_rms() * 1e6:.4g} um '
                f'per leg; the limit is {RESIDUAL_GATE_FACTOR:g}x that ({m.sources()})')


def read_description(path) -> HexapodDescription:
    """A hexapod description YAML, validated (every error names the key)."""
    content = read_description_file(path, 'hexapod')
    where = str(path)
    geometry = HexapodGeometry.from_dict(content['geometry'], f'{where}: geometry')
    measurement = read_measurement(content, where, SHIPPED_INSTRUMENT, SHIPPED_ACTUATOR_SIGMA_M)
    return HexapodDescription(geometry, measurement, where, _workspace(content, where))


def _workspace(content: dict, where: str) -> dict | None:
    """The workspace section as :class:`HexapodPlan` settings, or None."""
    section = workspace_section(content, where, WORKSPACE_KEYS)
    if section is None:
        return None
    home = as_poses(workspace_numbers(section['home'], 6, 'home', where, False),
                    'workspace home')[0]
    stroke = workspace_numbers(section['stroke_m'], 2, 'stroke_m', where, False)
    if not stroke[0] < stroke[1]:
        raise InvalidInputError(f'{where}: workspace stroke_m must be [shortest, longest]')
    return {'home': tuple(home.tolist()),
            'translation': workspace_numbers(section['translation_m'], 3, 'translation_m', where, True),
            'rotation': workspace_numbers(section['rotation_rad'], 3, 'rotation_rad', where, True),
            'stroke': stroke}


def travel_ratio(data, description: HexapodDescription) -> float:
    """How far the legs' readings (m, as declared) travel against how far the measured
    poses need them to (the nominal's inverse kinematics), median over the legs: about 1
    for readings in the declared unit."""
    needed = inverse_kinematics(description.geometry, data.measured)
    return float(np.median(np.ptp(data.leg_lengths, axis=0)
                           / np.maximum(np.ptp(needed, axis=0), 1e-12)))


def likely_causes(data, description: HexapodDescription) -> str:
    """The likely causes of a residual far above the declared noise, most likely first
    (:func:`calib_core.description.likely_causes`, from :func:`travel_ratio`)."""
    return causes_from_travel(travel_ratio(data, description),
                              description.measurement.actuators, 'legs',
                              '42-parameter model', 'machine-align analyze hexapod')
