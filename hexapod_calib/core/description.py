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
    RESIDUAL_GATE_FACTOR, Instrument, Measurement, check_keys, read_measurement)
from calib_core.errors import InvalidInputError
from calib_core.files import read_yaml
from hexapod_calib.core.geometry import HexapodGeometry, as_poses
from hexapod_calib.core.kinematics import inverse_kinematics
from hexapod_calib.core.planning import ACTUATOR_NOISE, ANGLE_NOISE, POSITION_NOISE
from hexapod_calib.core.procedure import HexapodPlan

KEYS = ('kind', 'geometry', 'instrument', 'actuators', 'repeatability_m', 'workspace')
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

    def expected_text(self) -> str:
        m = self.measurement
        return (f'{m.instrument.name} at {m.instrument.position_sigma_m * 1e3:.3g} mm and '
                f'{m.instrument.angle_sigma_rad * 1e3:.3g} mrad, actuators '
                f'{m.actuators.sigma_m * 1e6:.3g} um, repeatability '
                f'{m.repeatability_m * 1e6:.3g} um give {self.expected_leg_rms() * 1e6:.4g} um '
                f'per leg; the limit is {RESIDUAL_GATE_FACTOR:g}x that ({m.sources()})')


def read_description(path) -> HexapodDescription:
    """A hexapod description YAML, validated (every error names the key)."""
    content = read_yaml(path, 'a hexapod description YAML')
    where = str(path)
    check_keys(content, KEYS, where)
    if content.get('kind') != 'hexapod':
        raise InvalidInputError(f'{where}: kind must be hexapod, not {content.get("kind")!r}')
    geometry = HexapodGeometry.from_dict(content.get('geometry'), f'{where}: geometry')
    measurement = read_measurement(content, where, SHIPPED_INSTRUMENT, SHIPPED_ACTUATOR_SIGMA_M)
    return HexapodDescription(geometry, measurement, where, _workspace(content, where))


def _triple(value, count: int, name: str, where: str, positive: bool) -> tuple:
    try:
        values = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InvalidInputError(f'{where}: workspace {name} must be {count} numbers') from None
    if values.shape != (count,) or not np.all(np.isfinite(values)) or (
            positive and not np.all(values > 0)):
        raise InvalidInputError(f'{where}: workspace {name} must be {count} finite '
                                f'{"positive " if positive else ""}numbers, not {value!r}')
    return tuple(float(v) for v in values)


def _workspace(content: dict, where: str) -> dict | None:
    """The workspace section as :class:`HexapodPlan` settings, or None."""
    section = content.get('workspace')
    if section is None:
        return None
    check_keys(section, WORKSPACE_KEYS, f'{where}: workspace')
    missing = [k for k in WORKSPACE_KEYS if k not in section]
    if missing:
        raise InvalidInputError(f'{where}: workspace lacks {", ".join(missing)}')
    home = as_poses(_triple(section['home'], 6, 'home', where, False), 'workspace home')[0]
    stroke = _triple(section['stroke_m'], 2, 'stroke_m', where, False)
    if not stroke[0] < stroke[1]:
        raise InvalidInputError(f'{where}: workspace stroke_m must be [shortest, longest]')
    return {'home': tuple(home.tolist()),
            'translation': _triple(section['translation_m'], 3, 'translation_m', where, True),
            'rotation': _triple(section['rotation_rad'], 3, 'rotation_rad', where, True),
            'stroke': stroke}


UNIT_SLIPS = ((1e3, 'the legs move 1000x as far as the measured poses need: the readings are '
                    'in a unit 1000x smaller than declared (mm read as m: actuators: '
                    '{unit: mm})'),
              (1e-3, 'the legs move 1/1000 as far as the measured poses need: the readings '
                     'are in a unit 1000x larger than declared (m read as mm: actuators: '
                     '{unit: m})'))


def likely_causes(data, description: HexapodDescription) -> str:
    """The likely causes of a residual far above the declared noise, most likely first: a
    unit slip where the legs' travel and the poses' disagree by about 1000x (and only
    then), a lead off where they disagree by more than 20 %, then the instrument, the
    nominal geometry and effects the model lacks."""
    needed = inverse_kinematics(description.geometry, data.measured)
    ratio = float(np.median(np.ptp(data.leg_lengths, axis=0)
                            / np.maximum(np.ptp(needed, axis=0), 1e-12)))
    causes = []
    for factor, text in UNIT_SLIPS:
        if factor / 3 < ratio < factor * 3:
            causes.append(text)
    if not causes and abs(ratio - 1) > 0.2:
        causes.append(f'the legs move {ratio:.3g}x as far as the measured poses need: the '
                      f'actuators\' m_per_unit ({description.measurement.actuators.m_per_unit:g}'
                      f' m per {description.measurement.actuators.unit}) is off')
    causes += ['the instrument is noisier than declared', 'the nominal geometry is not this '
               'machine\'s', 'effects the 42-parameter model lacks (machine-align analyze '
               'hexapod names them)']
    return '; '.join(f'{k + 1}. {c}' for k, c in enumerate(causes))
