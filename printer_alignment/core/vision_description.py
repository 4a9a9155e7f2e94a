"""A user's camera gantry (issue 50): the lens and screws the vision calibration is held to,
the camera, the dot plate it is calibrated on and the travel it may use, in one YAML file
(``vision_calibrator``'s ``description`` parameter, ``machine-align launch printer
--description``, ``machine-align calibrate vision --description``; examples ship in
``printer_alignment/descriptions/``):

```yaml
kind: vision
geometry:
  pixel_size_m: 12.5e-6            # the lens's nominal object-space pixel size, m/px
  leads_m_per_rev: [0.016, 0.040]  # the X and Y screws the drive converts motor angles with
  focal_px: 2000.0                 # the lens's focal length in px (for its distortion)
  image_size_px: [640, 480]
  dot_pitch_m: 0.5e-3              # the calibration dot plate's pitch
workspace: {x_range_m: [0.0, 0.2], y_range_m: [0.0, 0.15]}   # the travel the plan may use
```

The gate holds the identified pixel size within 20 % and the leads within 10 % of these,
and the fit starts from them. The gantry's residual keeps its built-in bound (50 um): the
paper's model leaves the screws' backlash and periodic error in it, which no declared
noise sizes; the closed loop (``analyze gantry``) names them.
"""
from __future__ import annotations

from dataclasses import dataclass

from calib_core.description import (
    check_keys, described_number, read_description_file, workspace_numbers,
    workspace_section)
from calib_core.errors import InvalidInputError
from printer_alignment.core.geometry import CameraToPlate, GantryModel

GEOMETRY_KEYS = ('pixel_size_m', 'leads_m_per_rev', 'focal_px', 'image_size_px',
                 'dot_pitch_m')


@dataclass(frozen=True)
class VisionDescription:
    """A user's camera gantry: nominal ``pixel_size`` (m/px) and ``leads`` (m/rev, X and
    Y), the camera's ``focal_px`` and ``image_size`` (px), the dot plate's ``pitch`` (m) and
    the travel ``x_range``, ``y_range`` (m)."""

    pixel_size: float
    leads: tuple
    focal_px: float
    image_size: tuple
    pitch: float
    x_range: tuple
    y_range: tuple
    source: str

    def nominal_camera(self) -> CameraToPlate:
        return CameraToPlate(self.pixel_size)

    def nominal_gantry(self) -> GantryModel:
        return GantryModel(lead_x=self.leads[0], lead_y=self.leads[1])

    def node_parameters(self) -> dict:
        """vision_calibrator's parameters this description sets, by name."""
        return {'nominal_pixel_size': self.pixel_size, 'nominal_leads': list(self.leads),
                'focal_px': self.focal_px, 'image_size': list(self.image_size),
                'pitch': self.pitch, 'x_range': list(self.x_range),
                'y_range': list(self.y_range)}


def read_description(path) -> VisionDescription:
    """A camera-gantry description YAML, validated (every error names the key).

    Raises
    ------
    InvalidInputError
        Unknown keys or sections, a value missing, not finite or not positive, a range the
        wrong way round."""
    content = read_description_file(path, 'vision')
    where = str(path)
    extra = sorted(set(content) - {'kind', 'geometry', 'workspace'})
    if extra:
        raise InvalidInputError(f'{where}: a vision description holds geometry and '
                                f'workspace, not {", ".join(extra)} (the gantry\'s residual '
                                'bound is the model\'s own, docs/machine_description.md)')
    geometry = check_keys(content['geometry'], GEOMETRY_KEYS, f'{where}: geometry')
    size = workspace_numbers(geometry.get('image_size_px'), 2, 'image_size_px',
                             f'{where}: geometry', True)
    if any(v != int(v) for v in size):
        raise InvalidInputError(f'{where}: geometry image_size_px must be whole pixels')
    leads = workspace_numbers(geometry.get('leads_m_per_rev'), 2, 'leads_m_per_rev',
                              f'{where}: geometry', True)
    section = workspace_section(content, where, ('x_range_m', 'y_range_m')) or {
        'x_range_m': (0.0, 0.200), 'y_range_m': (0.0, 0.150)}
    ranges = {}
    for key in ('x_range_m', 'y_range_m'):
        low, high = workspace_numbers(section[key], 2, key, where, False)
        if not low < high:
            raise InvalidInputError(f'{where}: workspace {key} must run from low to high, '
                                    f'not {section[key]!r}')
        ranges[key] = (low, high)
    return VisionDescription(
        pixel_size=described_number(geometry, 'pixel_size_m', f'{where}: geometry',
                                    positive=True),
        leads=leads,
        focal_px=described_number(geometry, 'focal_px', f'{where}: geometry', positive=True),
        image_size=tuple(int(v) for v in size),
        pitch=described_number(geometry, 'dot_pitch_m', f'{where}: geometry', positive=True),
        x_range=ranges['x_range_m'], y_range=ranges['y_range_m'], source=where)
