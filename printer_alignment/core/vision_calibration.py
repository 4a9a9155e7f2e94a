"""The paper's vision system calibration: pixel size and image rotation from a dot plate,
then the gantry model (leads Rx, Ry, axis angle, non-orthogonality) by moving the camera
over the plate. Dots are identified by predicting their plate position with the nominal
model, so the nominal model must be right to better than half a pitch over the travel.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.least_squares import FitResult, fit
from calib_core.parameters import Parameter, ParameterSet
from printer_alignment.core.geometry import CameraToPlate, GantryModel

# The units of a vision calibration's parameters (SI), as its reports and results state
# them: the camera's scale and turn, then the gantry model's.
CAMERA_UNITS = {'pixel_size': 'm/px', 'camera_angle': 'rad'}
GANTRY_UNITS = {'lead_x': 'm/rev', 'lead_y': 'm/rev', 'axis_angle': 'rad',
                'non_orthogonality': 'rad', 'offset_x': 'm', 'offset_y': 'm'}
VISION_UNITS = {**CAMERA_UNITS, **GANTRY_UNITS}


def _check_uv(uv, what: str) -> np.ndarray:
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InvalidInputError(f'{what}: expected pixel centres of shape (n, 2), got {uv.shape}')
    if not np.all(np.isfinite(uv)):
        raise InvalidInputError(f'{what}: pixel centres contain NaN or infinite values')
    return uv


@dataclass(frozen=True)
class PixelSizeResult:
    """Pixel size (m/px) and image rotation (rad) with 1-sigma std devs; residuals in px."""

    camera2plate: CameraToPlate
    fit: FitResult
    num_marks: int

    def report(self) -> dict:
        return {'pixel_size_m': self.camera2plate.pixel_size,
                'pixel_size_std_m': self.fit.std_devs['pixel_size'],
                'angle_rad': self.camera2plate.angle,
                'angle_std_rad': self.fit.std_devs['angle'],
                'residual_rms_px': self.fit.rms,
                'residual_max_px': float(np.max(np.abs(self.fit.residuals))),
                'num_marks': self.num_marks, 'num_views': len(self.fit.parameters.names) // 2 - 1}


def _grid_indices(uv: np.ndarray, camera2plate: CameraToPlate, pitch: float) -> np.ndarray:
    """Lattice indices (n, 2) of dots relative to the dot nearest the principal point."""
    reference = uv[np.argmin(np.linalg.norm(uv - np.asarray(camera2plate.principal), axis=1))]
    offsets = camera2plate.offset(uv) - camera2plate.offset(reference[None])[0]
    return np.round(offsets / pitch).astype(int)


def calibrate_pixel_size(views: list, pitch: float, nominal: CameraToPlate = CameraToPlate(),
                         min_marks: int = 9) -> PixelSizeResult:
    """Pixel size and image rotation from images of a dot grid of known ``pitch`` (m).

    Parameters
    ----------
    views : list of ndarray, shape (n_i, 2)
        Dot centres (px) in each image; every view has its own unknown plate offset.
    nominal : CameraToPlate
        Prior pixel size and rotation, good enough to index the dots (error << pitch over
        the field of view); the principal point is kept fixed.
    """
    if pitch <= 0 or not np.isfinite(pitch):
        raise InvalidInputError(f'dot pitch must be a positive length in m, not {pitch}')
    views = [_check_uv(v, f'view {k}') for k, v in enumerate(views)]
    if not views or sum(len(v) for v in views) < min_marks:
        raise CalibrationError(f'pixel size needs at least {min_marks} dots; got '
                               f'{sum(len(v) for v in views)}')
    current = nominal
    for _ in range(2):  # index with the prior, refit, re-index with the refined model
        indices = [_grid_indices(v, current, pitch) for v in views]
        params = [Parameter('pixel_size', current.pixel_size, 'm/px'),
                  Parameter('angle', current.angle, 'rad')]
        for k, (v, ij) in enumerate(zip(views, indices)):
            start = np.mean(current.offset(v) - ij * pitch, axis=0)
            params += [Parameter(f'view{k}_x', start[0], 'm'), Parameter(f'view{k}_y', start[1], 'm')]

        def residual(p: ParameterSet) -> np.ndarray:
            c2p = CameraToPlate(p['pixel_size'], p['angle'], nominal.principal)
            out = []
            for k, (v, ij) in enumerate(zip(views, indices)):
                origin = np.array([p[f'view{k}_x'], p[f'view{k}_y']])
                out.append((c2p.pixels(ij * pitch - origin) - v).ravel())
            return np.concatenate(out)

        result = fit(residual, ParameterSet(params))
        current = CameraToPlate(result.parameters['pixel_size'], result.parameters['angle'],
                                nominal.principal)
    if result.rms > 0.25:
        raise CalibrationError(f'dot grid fit residual {result.rms:.2f} px RMS: the dots could not '
                               'be indexed (wrong pitch or nominal pixel size?)')
    return PixelSizeResult(current, result, sum(len(v) for v in views))


@dataclass(frozen=True)
class GantryObservation:
    """Dots seen (px, shape (n, 2)) with the gantry's motors at ``revs`` (rev, shape (2,))."""

    revs: np.ndarray
    uv: np.ndarray


def locate_camera(uv: np.ndarray, camera2plate: CameraToPlate, pitch: float,
                  predicted: np.ndarray, radius_px: float = 150.0) -> np.ndarray:
    """Camera position in the plate frame (m, shape (2,)) from dots near the image centre.

    Each dot is identified as the grid point nearest its predicted plate position
    (``predicted`` camera position plus its pixel offset)."""
    uv = _check_uv(uv, 'dots')
    near = np.linalg.norm(uv - np.asarray(camera2plate.principal), axis=1) < radius_px
    if not near.any():
        raise CalibrationError(f'no dot within {radius_px:.0f} px of the image centre')
    offsets = camera2plate.offset(uv[near])
    dots = np.round((predicted + offsets) / pitch) * pitch
    return np.mean(dots - offsets, axis=0)


@dataclass(frozen=True)
class GantryResult:
    """Identified gantry model with 1-sigma std devs; residuals are camera positions (m)."""

    model: GantryModel
    fit: FitResult
    num_positions: int

    def report(self) -> dict:
        residual = self.fit.residuals.reshape(-1, 2)
        norm = np.linalg.norm(residual, axis=1)
        return {'parameters': self.model.as_dict(),
                'std_devs': self.fit.std_devs,
                'units': dict(GANTRY_UNITS),
                'residual_rms_m': float(np.sqrt(np.mean(norm ** 2))),
                'residual_max_m': float(norm.max()),
                'condition_number': self.fit.condition_number,
                'num_positions': self.num_positions}


def measure_camera_positions(observations: list, camera2plate: CameraToPlate, pitch: float,
                             nominal: GantryModel) -> np.ndarray:
    """Camera positions (m, (n, 2)) in a plate frame anchored at the dot nearest the image
    centre of the first observation; dots are identified through the nominal model."""
    if not observations:
        raise CalibrationError('no gantry observations')
    first = observations[0]
    anchor_offset = locate_camera(first.uv, camera2plate, pitch, np.zeros(2))
    home = nominal.camera_position(first.revs)[0]
    positions = []
    for obs in observations:
        predicted = nominal.camera_position(obs.revs)[0] - home + anchor_offset
        positions.append(locate_camera(obs.uv, camera2plate, pitch, predicted))
    return np.array(positions)


def calibrate_gantry(observations: list, camera2plate: CameraToPlate, pitch: float,
                     nominal: GantryModel = GantryModel()) -> GantryResult:
    """Identify leads, axis angle, non-orthogonality and offset from dot images taken at
    several gantry positions (at least 4, spanning both axes)."""
    if len(observations) < 4:
        raise CalibrationError(f'the gantry model (6 parameters) needs at least 4 positions, '
                               f'got {len(observations)}')
    revs = np.array([np.asarray(o.revs, dtype=float) for o in observations])
    if not np.all(np.isfinite(revs)):
        raise InvalidInputError('gantry motor angles contain NaN or infinite values')
    for axis, name in ((0, 'X'), (1, 'Y')):
        if np.ptp(revs[:, axis]) == 0:
            raise CalibrationError(f'the gantry {name} axis never moved: its lead cannot be '
                                   'identified')
    positions = measure_camera_positions(observations, camera2plate, pitch, nominal)
    start = positions[0] - nominal.camera_position(revs[0])[0] + np.array(
        [nominal.offset_x, nominal.offset_y])
    initial = ParameterSet([
        Parameter('lead_x', nominal.lead_x, 'm/rev'), Parameter('lead_y', nominal.lead_y, 'm/rev'),
        Parameter('axis_angle', nominal.axis_angle, 'rad'),
        Parameter('non_orthogonality', nominal.non_orthogonality, 'rad'),
        Parameter('offset_x', start[0], 'm'), Parameter('offset_y', start[1], 'm')])

    def residual(p: ParameterSet) -> np.ndarray:
        return (GantryModel(**p.as_dict()).camera_position(revs) - positions).ravel()

    result = fit(residual, initial)
    return GantryResult(GantryModel(**result.parameters.as_dict()), result, len(observations))


def plate_position(model: GantryModel, camera2plate: CameraToPlate, revs: np.ndarray,
                   uv: np.ndarray) -> np.ndarray:
    """Plate-frame position (m, (n, 2)) of pixels ``uv`` seen with the motors at ``revs``:
    what the calibrated vision system measures."""
    return model.camera_position(revs)[0] + camera2plate.offset(uv)


