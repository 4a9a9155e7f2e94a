"""A user's five-axis dispenser (issue 50): its camera, where the camera looks from, the
axes' strokes and the units the controller reads them in, how well the camera finds a
dot and the machine's repeatability, in one YAML file (``machine-align calibrate
five-axis --description``; examples ship in ``dispenser_calib/descriptions/``):

```yaml
kind: five_axis
geometry:
  focal_px: 7246.0               # the lens's focal length in pixels
  image_size_px: [2448, 2048]
  working_distance_m: 0.120      # camera to the board's centre with the axes at zero
  a_height_m: -0.030             # A's line below the board's surface
  board: {dots: [11, 9], pitch_m: 2.0e-3, dot_radius_m: 0.4e-3}   # the dot board on the table
instrument: {name: camera, centroid_sigma_px: 0.17}   # a dot's centre, 1 sigma per axis
actuators:                       # how the controller reads the axes
  linear_unit: mm                # m, mm, um, inch
  rotary_unit: deg               # rad, deg
  sigma_m: 1.0e-6                # positioning noise, 1 sigma
  sigma_rad: 5.0e-6
repeatability_m: 2.0e-6
workspace:                       # the strokes (m, rad): no stop is planned or simulated outside
  strokes: {x_m: [-0.2, 0.2], y_m: [-0.15, 0.15], z_m: [-0.05, 0.05],
            a_rad: [-1.5708, 1.5708], c_rad: [-6.2832, 6.2832]}
```

The gate then refuses a calibration by what was declared: a reprojection RMS above
:data:`calib_core.description.RESIDUAL_GATE_FACTOR` times what the camera, the axes and
the repeatability give (:meth:`FiveAxisDescription.expected_reprojection_px`), and, as
without a description, linear-axis scales further than
:data:`dispenser_calib.core.calibration.MAX_AXIS_SCALE_ERROR` from 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calib_core.description import (
    ANGLE_UNITS, LENGTH_UNITS, RESIDUAL_GATE_FACTOR, UNIT_SLIP, check_keys, described_number,
    read_description_file, unit_factor, unit_slip, workspace_numbers, workspace_section)
from calib_core.errors import InvalidInputError
from dispenser_calib.core.calibration import check_calibration
from dispenser_calib.core.data import (
    SHIPPED_BOARD, Board, Image, board_points, read_observations, write_observations)
from dispenser_calib.core.model import DispenserModel, nominal_frames, nominal_model
from dispenser_calib.core.procedure import STROKES, WORKING_DISTANCE, Workspace

GEOMETRY_KEYS = ('focal_px', 'image_size_px', 'working_distance_m', 'a_height_m', 'board')
BOARD_KEYS = ('dots', 'pitch_m', 'dot_radius_m')
INSTRUMENT_KEYS = ('name', 'centroid_sigma_px')
ACTUATOR_KEYS = ('linear_unit', 'rotary_unit', 'sigma_m', 'sigma_rad')
STROKE_KEYS = ('x_m', 'y_m', 'z_m', 'a_rad', 'c_rad')
# The shipped simulated dispenser (dispenser_calib.sim.machine): its camera, its dots found
# to 0.1 px, axes without positioning noise.
SHIPPED_GEOMETRY = {'focal_px': 7246.0, 'image_size_px': (2448, 2048),
                    'working_distance_m': WORKING_DISTANCE, 'a_height_m': -0.030}
SHIPPED_CENTROID_SIGMA_PX = 0.1
# A reading this many times what the camera saw is a unit slip: mm read as m (1000) or
# degrees read as radians (1/57.3 when rad are declared deg), and each the other way round
# (calib_core.description.unit_slip). The camera measures the board's travel to a few
# per cent, so only 1.4x either way of that counts.
SLIPS = {'linear': UNIT_SLIP, 'rotary': 180 / np.pi}
SLIP_WITHIN = 1.4


@dataclass(frozen=True)
class FiveAxisDescription:
    """A user's five-axis dispenser: camera, dot board, strokes (name -> (low, high) m or
    rad), the axes' units (SI per reading unit), their noise, the camera's dot noise (px)
    and the repeatability (m), and which sections were declared."""

    focal_px: float
    image_size: tuple
    working_distance_m: float
    a_height_m: float
    board: Board
    strokes: dict
    instrument_name: str
    centroid_sigma_px: float
    linear_unit: str
    rotary_unit: str
    sigma_m: float
    sigma_rad: float
    repeatability_m: float
    declared: tuple
    source: str

    def nominal(self) -> DispenserModel:
        """The described machine without errors (:func:`nominal_model`)."""
        return nominal_model(self.focal_px, self.image_size, self.working_distance_m,
                             self.a_height_m)

    def frames(self, pose) -> list:
        """The machine's frames at a commanded ``pose`` (5,) through the described nominal
        kinematics, for a viewer (:func:`nominal_frames`)."""
        return nominal_frames(pose, self.working_distance_m, self.a_height_m)

    def workspace(self) -> Workspace:
        """The strokes, working distance and board plans and simulations keep to."""
        return Workspace(dict(self.strokes), self.working_distance_m, self.board)

    def pose_scale(self) -> np.ndarray:
        """SI per reading unit for x, y, z, a, c (5,)."""
        return np.array([LENGTH_UNITS[self.linear_unit]] * 3 + [ANGLE_UNITS[self.rotary_unit]] * 2)

    def read(self, path) -> list[Image]:
        """An observations CSV whose poses are in the actuators' units, poses in m, rad.

        Raises
        ------
        InvalidInputError
            As :func:`read_observations`, a pose out of range saying which units it was
            read in."""
        try:
            return read_observations(path, self.pose_scale(), self.board)
        except InvalidInputError as exc:
            raise InvalidInputError(f'{exc} (the poses read in {self.linear_unit} and '
                                    f'{self.rotary_unit} as {self.source} declares, then '
                                    'converted)') from None

    def write(self, path, images: list[Image]) -> None:
        """``images`` (poses m, rad) as an observations CSV in the actuators' units."""
        write_observations(path, images, self.pose_scale())

    def pose_sigma(self) -> np.ndarray:
        """How far each axis stops from its reading, 1 sigma (5,) m, rad: the positioning
        noise and, on the linear axes, the repeatability."""
        linear = float(np.hypot(self.sigma_m, self.repeatability_m))
        return np.array([linear] * 3 + [self.sigma_rad] * 2)

    def lever_m(self) -> float:
        """How far a board dot lies from the rotary axes, RMS (m): the board's dots about
        its centre and A's line below it. An angle error of the axes moves a dot by this
        times the angle."""
        dots, _ = board_points(self.board)
        return float(np.sqrt(np.mean(np.sum(dots ** 2, axis=1)) + self.a_height_m ** 2))

    def expected_reprojection_px(self) -> float:
        """Reprojection RMS (px, per coordinate) the declared noise gives a sound fit: the
        dot noise, and the axes' positioning noise and the repeatability seen through the
        lens at the working distance (focal / distance px per m), in quadrature."""
        px_per_m = self.focal_px / self.working_distance_m
        moved = np.sqrt(self.sigma_m ** 2 + self.repeatability_m ** 2
                        + (self.sigma_rad * self.lever_m()) ** 2)
        return float(np.hypot(self.centroid_sigma_px, px_per_m * moved))

    def residual_limit_px(self) -> float:
        return RESIDUAL_GATE_FACTOR * self.expected_reprojection_px()

    def expected_text(self) -> str:
        undeclared = [k for k in ('instrument', 'actuators', 'repeatability_m')
                      if k not in self.declared]
        sources = ('declared in the description' if not undeclared else
                   f'{", ".join(undeclared)}: the shipped simulated machine\'s (not declared)')
        return (f'{self.instrument_name} finding dots to {self.centroid_sigma_px:.3g} px, axes '
                f'{self.sigma_m * 1e6:.3g} um and {self.sigma_rad * 1e6:.3g} urad, '
                f'repeatability {self.repeatability_m * 1e6:.3g} um at '
                f'{self.focal_px / self.working_distance_m * 1e-3:.4g} px/mm give '
                f'{self.expected_reprojection_px():.3g} px of reprojection RMS; the limit is '
                f'{RESIDUAL_GATE_FACTOR:g}x that ({sources})')

    def check(self, model: DispenserModel, report: dict, images: list[Image]) -> None:
        """:func:`check_calibration` against this description's limit, with the likely
        causes (:func:`likely_causes`, from ``images``) where the residual is above it.

        Raises
        ------
        CalibrationError"""
        above = not report['rms_reprojection_px'] <= self.residual_limit_px()
        check_calibration(model, report, self, likely_causes(images, self) if above else None)

    def gate_report(self) -> dict:
        """What a calibration's report says of the gate this description set."""
        return {'file': self.source, 'residual_limit_px': self.residual_limit_px(),
                'expected_reprojection_px': self.expected_reprojection_px(),
                'units': {'linear': self.linear_unit, 'rotary': self.rotary_unit},
                'expected': self.expected_text()}


def read_description(path) -> FiveAxisDescription:
    """A five-axis description YAML, validated (every error names the key)."""
    content = read_description_file(path, 'five_axis')
    where = str(path)
    geometry = check_keys(content['geometry'], GEOMETRY_KEYS, f'{where}: geometry')
    size = workspace_numbers(geometry.get('image_size_px', SHIPPED_GEOMETRY['image_size_px']),
                             2, 'image_size_px', f'{where}: geometry', True)
    if any(v != int(v) for v in size):
        raise InvalidInputError(f'{where}: geometry image_size_px must be whole pixels')
    a_height = geometry.get('a_height_m', SHIPPED_GEOMETRY['a_height_m'])
    if isinstance(a_height, bool) or not isinstance(a_height, (int, float)) \
            or not np.isfinite(a_height):
        raise InvalidInputError(f'{where}: geometry a_height_m must be a finite number')
    instrument = check_keys(content.get('instrument', {}), INSTRUMENT_KEYS,
                            f'{where}: instrument')
    actuators = check_keys(content.get('actuators', {}), ACTUATOR_KEYS, f'{where}: actuators')
    name = instrument.get('name', 'camera')
    if not isinstance(name, str):
        raise InvalidInputError(f'{where}: instrument name must be text')
    return FiveAxisDescription(
        focal_px=described_number(geometry, 'focal_px', f'{where}: geometry',
                                  SHIPPED_GEOMETRY['focal_px'], positive=True),
        image_size=tuple(int(v) for v in size),
        working_distance_m=described_number(geometry, 'working_distance_m',
                                            f'{where}: geometry',
                                            SHIPPED_GEOMETRY['working_distance_m'], True),
        a_height_m=float(a_height),
        board=_board(geometry, where),
        strokes=_strokes(content, where),
        instrument_name=name,
        centroid_sigma_px=described_number(instrument, 'centroid_sigma_px',
                                           f'{where}: instrument',
                                           SHIPPED_CENTROID_SIGMA_PX if not instrument
                                           else None, positive=True),
        linear_unit=unit_factor(actuators, 'linear_unit', LENGTH_UNITS,
                                f'{where}: actuators', 'm')[0],
        rotary_unit=unit_factor(actuators, 'rotary_unit', ANGLE_UNITS,
                                f'{where}: actuators', 'rad')[0],
        sigma_m=described_number(actuators, 'sigma_m', f'{where}: actuators', 0.0),
        sigma_rad=described_number(actuators, 'sigma_rad', f'{where}: actuators', 0.0),
        repeatability_m=described_number(content, 'repeatability_m', where, 0.0),
        declared=tuple(k for k in ('instrument', 'actuators', 'repeatability_m')
                       if k in content),
        source=where)


def _board(geometry: dict, where: str) -> Board:
    """The declared dot board, else the shipped one: whole dots along x and y (at least 3
    each, a board the calibration can name), pitch and radius in m, the dots apart."""
    if 'board' not in geometry:
        return SHIPPED_BOARD
    where = f'{where}: geometry board'
    board = check_keys(geometry['board'], BOARD_KEYS, where)
    missing = [key for key in BOARD_KEYS if key not in board]
    if missing:
        raise InvalidInputError(f'{where} lacks {", ".join(missing)}')
    dots = workspace_numbers(board['dots'], 2, 'dots', where, True)
    pitch = described_number(board, 'pitch_m', where, None, positive=True)
    radius = described_number(board, 'dot_radius_m', where, None, positive=True)
    try:    # the board's own checks: whole dots, at least 3 a side, apart
        return Board(tuple(int(v) if v == int(v) else v for v in dots), pitch, radius)
    except InvalidInputError as exc:
        raise InvalidInputError(f'{where}: {exc}') from None


def _strokes(content: dict, where: str) -> dict:
    """The declared strokes as check_stroke's mapping (x, y, z m; a, c rad), else the
    shipped machine's."""
    section = workspace_section(content, where, ('strokes',))
    if section is None:
        return dict(STROKES)
    strokes = check_keys(section['strokes'], STROKE_KEYS, f'{where}: workspace strokes')
    result = {}
    for key in STROKE_KEYS:
        if key not in strokes:
            raise InvalidInputError(f'{where}: workspace strokes lack {key}')
        low, high = workspace_numbers(strokes[key], 2, f'strokes {key}', where, False)
        if not low < high:
            raise InvalidInputError(f'{where}: workspace strokes {key} must run from low to '
                                    f'high, not {strokes[key]!r}')
        result[key.split('_')[0]] = (low, high)
    return result


def travel_ratios(images: list[Image], image_size) -> tuple[float, float]:
    """How far the axes' readings (as declared, in m and rad) say the board moved against
    how far the camera saw it move (each image's board pose by OpenCV's calibrateCamera,
    which reads no axis): the linear ratio over the stops with A and C at zero, the
    rotary one over the stops where one rotary axis turned by more than 2 degrees. 1 for
    readings in the declared unit; NaN where the images cannot say."""
    from dispenser_calib.core.calibration import ZERO_ANGLE, zhang
    _, _, rotations, translations = zhang(images, image_size)
    poses = np.array([im.pose for im in images])
    rest = np.all(np.abs(poses[:, 3:]) <= ZERO_ANGLE, axis=1)
    linear = rotary = float('nan')
    if rest.sum() >= 2:
        seen = np.array(translations)[rest]
        read = poses[rest, :3]
        moved = np.sum((seen - seen.mean(axis=0)) ** 2)
        if moved > 0:
            linear = float(np.sqrt(np.sum((read - read.mean(axis=0)) ** 2) / moved))
        reference = rotations[int(np.flatnonzero(rest)[0])]
        ratios = []
        for k in np.flatnonzero(~rest):
            turned = np.abs(np.angle(np.exp(1j * poses[k, 3:])))
            if np.count_nonzero(turned > ZERO_ANGLE) != 1:
                continue
            cosine = (np.trace(reference.T @ rotations[k]) - 1) / 2
            angle = float(np.arccos(np.clip(cosine, -1.0, 1.0)))
            if angle > np.deg2rad(2.0):
                ratios.append(turned.max() / angle)
        if ratios:
            rotary = float(np.median(ratios))
    return linear, rotary


def likely_causes(images: list[Image], description: FiveAxisDescription) -> str:
    """The likely causes of a reprojection RMS far above the declared noise, most likely
    first: a unit slip only where the readings travel about 1000x (linear) or 57.3x
    (rotary), or the inverse, as far as the camera saw the board move
    (:func:`travel_ratios`), then the camera noisier than declared, the described camera
    or distance not this machine's, effects the 31-parameter model lacks."""
    causes = []
    try:
        ratios = dict(zip(('linear', 'rotary'), travel_ratios(images, description.image_size)))
    except (cv2.error, ValueError, np.linalg.LinAlgError):
        ratios = {}         # the images cannot say; the causes must not hide the refusal
    declared = {'linear': description.linear_unit, 'rotary': description.rotary_unit}
    for axes, ratio in ratios.items():
        if not np.isfinite(ratio):
            continue
        slip = unit_slip(ratio, SLIPS[axes], SLIP_WITHIN)
        if slip is not None:
            actual = _unit_read_as(declared[axes], slip)
            causes.append(f'the {axes} axes\' readings travel {ratio:.4g}x as far as the '
                          f'camera saw the board move: they are in {actual}, not '
                          f'{declared[axes]} (actuators: {{{axes}_unit: {actual}}})')
        elif abs(ratio - 1) > 0.2:
            causes.append(f'the {axes} axes\' readings travel {ratio:.3g}x as far as the '
                          'camera saw the board move: a scale in the controller, or the '
                          'described focal length or distance, is off')
    causes += ['the camera finds the dots less well than declared',
               "the described camera or working distance is not this machine's",
               'effects the 31-parameter model lacks (a rotary axis\'s angle error: '
               'machine-align analyze rotary on a sweep)']
    return '; '.join(f'{k + 1}. {c}' for k, c in enumerate(causes))


def _unit_read_as(declared: str, factor: float) -> str:
    """The unit the readings are in when read as ``declared`` they travel ``factor`` times
    too far (m declared, factor 1000: mm; '1/factor of declared' if none is known)."""
    units = LENGTH_UNITS if declared in LENGTH_UNITS else ANGLE_UNITS
    wanted = units[declared] / factor
    return next((u for u, v in units.items() if np.isclose(v, wanted, rtol=1e-6)),
                f'a unit {factor:.4g}x smaller than {declared}')
