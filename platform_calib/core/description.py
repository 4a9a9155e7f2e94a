"""A user's screen-registration platform (issue 50): its nominal geometry, the instrument
that measures the platform's pose, how its feeds are read and its repeatability, in one
YAML file (``machine-align calibrate platform --description``; examples ship in
``platform_calib/descriptions/``):

```yaml
kind: platform
geometry:                      # laid out as a platform geometry file (write_geometry)
  parameters: {x_A1: ..., y_A1: ..., alpha1: ..., L1: ..., x_C1: ..., y_C1: ..., ...}
  branch: [-1, -1, -1]
  stroke_m: [0.0, 0.04]        # the feeds' limits, m
instrument: {name: laser tracker, position_sigma_m: 10.0e-6, angle_sigma_rad: 20.0e-6}
actuators: {unit: rev, m_per_unit: 2.0e-3, sigma_m: 1.0e-6}   # feeds read in revolutions
repeatability_m: 2.0e-6
workspace:                     # where the platform works: plans and simulations stay in it
  home: [0, 0, 0]              # x m, y m, theta rad
  translation_m: [5.0e-3, 5.0e-3]   # half-widths of the box about home
  rotation_rad: 0.087
```

The gate then refuses an identification by what was declared: a closure residual above
:data:`calib_core.description.RESIDUAL_GATE_FACTOR` times what the instrument, feeds and
repeatability give, or a base or joint position further from the nominal than a share of
the platform's size.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.description import (
    RESIDUAL_GATE_FACTOR, Instrument, Measurement, read_description_file, read_measurement,
    workspace_numbers, workspace_section)
from calib_core.description import likely_causes as causes_from_travel
from platform_calib.core.geometry import PlatformGeometry, geometry_from_mapping
from platform_calib.core.identification import MAX_POSITION_SHIFT_M, PoseData
from platform_calib.core.kinematics import inverse

WORKSPACE_KEYS = ('home', 'translation_m', 'rotation_rad')
# The shipped simulation's tracker and feed sensors (platform_calib.sim.platform).
SHIPPED_INSTRUMENT = Instrument('the shipped simulated laser tracker', 10e-6, 20e-6)
SHIPPED_FEED_SIGMA_M = 1e-6
SHIPPED_WORKSPACE = {'home': (0.0, 0.0, 0.0), 'translation': (5e-3, 5e-3),
                     'rotation': float(np.deg2rad(5.0))}
PARAMETER_BOUND_SHARE = 0.1
"""A feed's zero or a joint more than this share of the platform's size (the joints' mean
distance from its centre) from the nominal is another machine (or another nominal): 14 mm
on the shipped 0.2 m platform, at least the built-in 10 mm."""


@dataclass(frozen=True)
class PlatformDescription:
    """A user's platform: nominal ``geometry`` and how it is measured."""

    geometry: PlatformGeometry
    measurement: Measurement
    source: str
    workspace: dict | None = None     # home (3,), translation (2,) m, rotation rad

    def box(self) -> dict:
        """The workspace: the declared one, else the shipped platform's."""
        return self.workspace or SHIPPED_WORKSPACE

    def random_poses(self, count: int, seed: int = 0) -> np.ndarray:
        """``count`` poses drawn uniformly in the workspace box, (count, 3)."""
        box = self.box()
        span = np.array([*box['translation'], box['rotation']])
        rng = np.random.default_rng(seed + 77)
        return np.asarray(box['home']) + rng.uniform(-1, 1, (count, 3)) * span

    def size(self) -> float:
        """The joints' mean distance from the platform's centre, m."""
        return float(np.mean(np.linalg.norm(self.geometry.joints, axis=1)))

    def expected_closure_rms(self) -> float:
        """Closure residual (m, 1 sigma) the declared noise gives a sound fit: the
        tracker's position noise, its angle noise on the platform's size, the feeds' noise
        and the repeatability, in quadrature."""
        m = self.measurement
        return float(np.sqrt(m.instrument.position_sigma_m ** 2
                             + (m.instrument.angle_sigma_rad * self.size()) ** 2
                             + m.actuators.sigma_m ** 2 + m.repeatability_m ** 2))

    def residual_limit(self) -> float:
        return RESIDUAL_GATE_FACTOR * self.expected_closure_rms()

    def position_bound(self) -> float:
        return max(MAX_POSITION_SHIFT_M, PARAMETER_BOUND_SHARE * self.size())

    def gate_report(self) -> dict:
        """What a calibration's report says of the gate this description set: the file,
        the residual limit and expected residual and the position bound (m), in words too."""
        return {'file': self.source, 'residual_limit_m': self.residual_limit(),
                'position_bound_m': self.position_bound(),
                'expected_closure_rms_m': self.expected_closure_rms(),
                'expected': self.expected_text()}

    def expected_text(self) -> str:
        m = self.measurement
        return (f'{m.instrument.name} at {m.instrument.position_sigma_m * 1e6:.3g} um and '
                f'{m.instrument.angle_sigma_rad * 1e6:.3g} urad, feeds '
                f'{m.actuators.sigma_m * 1e6:.3g} um, repeatability '
                f'{m.repeatability_m * 1e6:.3g} um give {self.expected_closure_rms() * 1e6:.4g} '
                f'um of closure residual; the limit is {RESIDUAL_GATE_FACTOR:g}x that '
                f'({m.sources()})')

    def read(self, path, dropped: dict | None = None) -> PoseData:
        """A poses CSV whose feeds are in the actuators' unit, as :class:`PoseData` in m."""
        return PoseData.from_csv(path, dropped, self.measurement.actuators.m_per_unit)


def read_description(path) -> PlatformDescription:
    """A platform description YAML, validated (every error names the key)."""
    content = read_description_file(path, 'platform')
    where = str(path)
    geometry = geometry_from_mapping(content['geometry'], f'{where}: geometry')
    measurement = read_measurement(content, where, SHIPPED_INSTRUMENT, SHIPPED_FEED_SIGMA_M)
    return PlatformDescription(geometry, measurement, where, _workspace(content, where))


def _workspace(content: dict, where: str) -> dict | None:
    section = workspace_section(content, where, WORKSPACE_KEYS)
    if section is None:
        return None
    return {'home': workspace_numbers(section['home'], 3, 'home', where, False),
            'translation': workspace_numbers(section['translation_m'], 2, 'translation_m',
                                             where, True),
            'rotation': workspace_numbers(section['rotation_rad'], 1, 'rotation_rad', where,
                                          True)[0]}


def travel_ratio(data: PoseData, description: PlatformDescription) -> float:
    """How far the feeds' readings (m, as declared) travel against how far the measured
    poses need them to (the nominal's inverse kinematics), median over the feeds: about 1
    for readings in the declared unit."""
    needed = inverse(description.geometry, data.poses, check=False)
    return float(np.median(np.ptp(data.feeds, axis=0)
                           / np.maximum(np.ptp(needed, axis=0), 1e-12)))


def likely_causes(data: PoseData, description: PlatformDescription) -> str:
    """The likely causes of a closure residual far above the declared noise, most likely
    first (:func:`calib_core.description.likely_causes`, from :func:`travel_ratio`)."""
    return causes_from_travel(travel_ratio(data, description),
                              description.measurement.actuators, 'feeds',
                              '18-parameter model', 'machine-align analyze platform')
