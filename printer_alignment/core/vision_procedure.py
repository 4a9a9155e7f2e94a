"""The vision calibration run: where to move, and how the recorded observations turn into
a calibration. Hardware access is injected, so the live node, the offline CLI (from a bag)
and the tests run the same code."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from calib_core.checks import (
    MAX_COUNT, MAX_POSITION_M, check_metres, positive_length, whole_number)
from calib_core.errors import InvalidInputError
from calib_core.sanity import SanityGate
from printer_alignment.core.geometry import CameraToPlate, GantryModel
from printer_alignment.core.vision_calibration import (
    GantryObservation, calibrate_gantry, calibrate_pixel_size)

MAX_PITCH_M = 0.05   # a dot plate's pitch; 0.5 written in mm would read as 0.5 m


@dataclass(frozen=True)
class VisionPlan:
    """Gantry positions of a calibration run (m) and how they are approached.

    Targets form an ``nx`` x ``ny`` grid inset by ``margin`` from the travel; each is
    approached from below (pre-position ``overshoot`` lower on both axes) so backlash
    always acts the same way and does not enter the fit.
    """

    x_range: tuple[float, float] = (0.0, 0.200)
    y_range: tuple[float, float] = (0.0, 0.150)
    nx: int = 5
    ny: int = 4
    margin: float = 0.002
    overshoot: float = 0.001
    pitch: float = 0.5e-3

    def __post_init__(self):
        # Checked here, before anything moves: a bad plan is refused, not found out after
        # the run.
        object.__setattr__(self, 'nx', whole_number(self.nx, 'nx', 2))
        object.__setattr__(self, 'ny', whole_number(self.ny, 'ny', 2))
        object.__setattr__(self, 'pitch', positive_length(self.pitch, 'pitch', MAX_PITCH_M))
        for name in ('margin', 'overshoot'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not 0 <= value < 0.1:
                raise InvalidInputError(f'{name} must be a length in [0, 0.1) m, not {value!r}')
        for name in ('x_range', 'y_range'):
            try:
                span = np.asarray(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                span = np.array([])
            if span.shape != (2,) or not np.all(np.isfinite(span)) or span[1] <= span[0]:
                raise InvalidInputError(f'{name} must be (low, high) in m, not '
                                        f'{getattr(self, name)!r}')
            check_metres(span, name, 'the plan', MAX_POSITION_M)
            object.__setattr__(self, name, (float(span[0]), float(span[1])))
        if self.overshoot > self.margin:
            raise InvalidInputError('overshoot must not exceed margin (pre-positions would '
                                    'leave the travel)')
        if self.nx * self.ny > MAX_COUNT:
            raise InvalidInputError(
                f'nx x ny = {self.nx * self.ny} positions, more than the {MAX_COUNT} a plan may '
                f'ask for (at about 4 positions a second, {self.nx * self.ny / 4 / 3600:.3g} h '
                'of the machine)')
        if self.x_range[1] - self.x_range[0] <= 2 * self.margin or \
                self.y_range[1] - self.y_range[0] <= 2 * self.margin:
            raise InvalidInputError('travel too short for the margin')

    def targets(self) -> np.ndarray:
        xs = np.linspace(self.x_range[0] + self.margin, self.x_range[1] - self.margin, self.nx)
        ys = np.linspace(self.y_range[0] + self.margin, self.y_range[1] - self.margin, self.ny)
        # Serpentine order keeps moves short.
        return np.array([(x, y) for j, y in enumerate(ys)
                         for x in (xs if j % 2 == 0 else xs[::-1])])


@dataclass(frozen=True)
class VisionCalibration:
    camera2plate: CameraToPlate
    gantry: GantryModel
    report: dict


def run_vision_calibration(plan: VisionPlan, move: Callable[[float, float], np.ndarray],
                           observe: Callable[[], np.ndarray],
                           progress: Callable[[int, int, str], None] = lambda *a: None,
                           nominal_camera: CameraToPlate = CameraToPlate(),
                           nominal_gantry: GantryModel = GantryModel()) -> tuple[list, VisionCalibration]:
    """Drive the gantry over the plan, observe dots, and calibrate.

    ``move(x, y)`` returns the motor angles reached (rev, shape (2,)); ``observe()`` returns
    dot centres (px, shape (n, 2)) in the current image."""
    observations = []
    targets = plan.targets()
    for k, (x, y) in enumerate(targets):
        move(x - plan.overshoot, y - plan.overshoot)
        revs = np.asarray(move(x, y), dtype=float)
        uv = np.asarray(observe(), dtype=float)
        observations.append(GantryObservation(revs, uv))
        progress(k + 1, len(targets), f'position {k + 1}/{len(targets)}: {len(uv)} dots')
    return observations, calibrate_from_observations(observations, plan.pitch, nominal_camera,
                                                     nominal_gantry)


def calibrate_from_observations(observations: list, pitch: float,
                                nominal_camera: CameraToPlate = CameraToPlate(),
                                nominal_gantry: GantryModel = GantryModel()) -> VisionCalibration:
    """Pixel size from every view, then the gantry model; the same code for live and
    recorded runs. The report keeps the nominal lens and screws the gate held it to, so a
    recorded run is solved again against the same."""
    pixel = calibrate_pixel_size([o.uv for o in observations], pitch, nominal_camera)
    gantry = calibrate_gantry(observations, pixel.camera2plate, pitch, nominal_gantry)
    report = {'pixel_size': pixel.report(), 'gantry': gantry.report(), 'pitch_m': pitch,
              'nominal': {'pixel_size_m': nominal_camera.pixel_size,
                          'leads_m_per_rev': [nominal_gantry.lead_x, nominal_gantry.lead_y]}}
    check_vision_calibration(report, nominal_camera, nominal_gantry)
    return VisionCalibration(pixel.camera2plate, gantry.model, report)


# The sanity gate's bounds: a lens within 20 % of its stated magnification; ball screws
# within 10 % of their lead; axes within 0.1 rad of the plate's and of square; the camera
# positions fitted to a few um (the paper's model leaves backlash and screw error, < 20 um).
MAX_PIXEL_SIZE_CHANGE = 0.20
MAX_LEAD_CHANGE = 0.10
MAX_ANGLE_RAD = 0.1
MAX_POSITION_RESIDUAL_RMS_M = 50e-6


def check_vision_calibration(report: dict, nominal_camera: CameraToPlate,
                             nominal_gantry: GantryModel) -> None:
    """Refuse a vision calibration (``calibrate_from_observations``'s report) that cannot
    be the machine, before it is written or put in force.

    Raises
    ------
    CalibrationError
        Every failure named."""
    gate = SanityGate('the vision calibration')
    gantry = report['gantry']
    gate.residual(gantry['residual_rms_m'] * 1e6, MAX_POSITION_RESIDUAL_RMS_M * 1e6, 'um',
                  'the paper\'s model fits the camera positions to a few um')
    size = nominal_camera.pixel_size
    gate.within('pixel_size', report['pixel_size']['pixel_size_m'],
                size * (1 - MAX_PIXEL_SIZE_CHANGE), size * (1 + MAX_PIXEL_SIZE_CHANGE), 'm/px',
                f'within {MAX_PIXEL_SIZE_CHANGE:.0%} of the nominal')
    for name in ('lead_x', 'lead_y'):
        lead = getattr(nominal_gantry, name)
        gate.within(name, gantry['parameters'][name], lead * (1 - MAX_LEAD_CHANGE),
                    lead * (1 + MAX_LEAD_CHANGE), 'm/rev',
                    f'within {MAX_LEAD_CHANGE:.0%} of the nominal lead')
    for name in ('axis_angle', 'non_orthogonality'):
        gate.within(name, gantry['parameters'][name], -MAX_ANGLE_RAD, MAX_ANGLE_RAD, 'rad',
                    'a built gantry is square to a fraction of a degree')
    gate.finite_std_devs({**gantry['std_devs'],
                          'pixel_size': report['pixel_size']['pixel_size_std_m']})
    gate.enforce()


def check_vision_parameters(values: dict, residual_rms_m: float) -> None:
    """The gate's checks a vision calibration received from another node can be held to
    without its nominal lens and screws (which only vision_calibrator knows): a positive
    pixel size and leads, axes within MAX_ANGLE_RAD of the plate's and of square, the
    camera positions fitted to MAX_POSITION_RESIDUAL_RMS_M.

    Raises
    ------
    CalibrationError
        Every failure named."""
    gate = SanityGate('the vision calibration received')
    gate.residual(residual_rms_m * 1e6, MAX_POSITION_RESIDUAL_RMS_M * 1e6, 'um',
                  'the paper\'s model fits the camera positions to a few um')
    for name, unit in (('pixel_size', 'm/px'), ('lead_x', 'm/rev'), ('lead_y', 'm/rev')):
        gate.within(name, values[name], 1e-12, np.inf, unit, 'positive')
    for name in ('axis_angle', 'non_orthogonality'):
        gate.within(name, values[name], -MAX_ANGLE_RAD, MAX_ANGLE_RAD, 'rad',
                    'a built gantry is square to a fraction of a degree')
    gate.enforce()


def observation_from_message(msg) -> GantryObservation:
    """A GantryObservation from an alignment_msgs/VisionObservation, live (rclpy) or decoded
    from a bag (rosbags): only attribute access is used, so no ROS import is needed.

    Raises InvalidInputError on NaN or infinite motor angles or Mark centres."""
    revs = np.array([msg.gantry.x_rev, msg.gantry.y_rev], dtype=float)
    uv = np.array([[m.u, m.v] for m in msg.marks.marks], dtype=float).reshape(-1, 2)
    if not (np.all(np.isfinite(revs)) and np.all(np.isfinite(uv))):
        raise InvalidInputError('observation has NaN or infinite motor angles or Mark centres')
    return GantryObservation(revs, uv)
