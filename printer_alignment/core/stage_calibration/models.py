"""The calibrated stage models the aligner uses: ``forward(q)`` (plate-frame platform
pose) and ``inverse(pose)`` (inputs, every chain approached from below), and their
plain-type form for files and messages."""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError
from printer_alignment.core.geometry import rotate_points
from printer_alignment.core.stage import StageGeometry


UNIDIRECTIONAL = np.ones(3)          # the aligner approaches every target from below
# Triangulation in (x, y, theta): theta scaled by this length so a radian weighs like
# the platform's half width.
ANGLE_SCALE = 0.2                    # m/rad


class StageModel:
    """Common inverse/forward interface of a calibrated (or nominal) stage."""

    method = 'model'

    def inverse(self, plate_pose) -> np.ndarray:
        raise NotImplementedError

    def forward(self, q, iterations: int = 6) -> np.ndarray:
        """Plate-frame platform poses (n, 3) for inputs q (m, (n, 3)), by Newton on
        :meth:`inverse` with the geometric Jacobian."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pose = self.geometry.stage_to_plate(self.geometry.forward(q, UNIDIRECTIONAL))
        for _ in range(iterations):
            stage_pose = self.geometry.plate_to_stage(pose)
            jac = self.geometry.jacobian(stage_pose)
            step_stage = np.linalg.solve(jac, (q - self.inverse(pose))[..., None])[..., 0]
            a0 = self.geometry.stage2plate[2]
            step = np.column_stack([rotate_points(a0, step_stage[:, :2]), step_stage[:, 2]])
            pose = pose + step
            if np.max(np.abs(step)) < 1e-13:
                break
        return pose


class ParametricModel(StageModel):
    """The error model with identified parameters (inputs approached from below)."""

    method = 'parametric'

    def __init__(self, geometry: StageGeometry):
        self.geometry = geometry

    def inverse(self, plate_pose) -> np.ndarray:
        stage_pose = self.geometry.plate_to_stage(plate_pose)
        return self.geometry.inverse(stage_pose, UNIDIRECTIONAL)

    def forward(self, q, iterations: int = 6) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return self.geometry.stage_to_plate(self.geometry.forward(q, UNIDIRECTIONAL))


class StepwiseModel(StageModel):
    """The paper's stepwise model: identified kinematics, attitude table over q3 - q2 and
    interpolation of the remaining input error over the measured workspace."""

    method = 'stepwise'

    def __init__(self, geometry: StageGeometry, attitude_w, attitude_theta,
                 poses, corrections):
        self.geometry = geometry
        self.attitude_w = np.asarray(attitude_w, dtype=float)
        self.attitude_theta = np.asarray(attitude_theta, dtype=float)
        self.poses = np.asarray(poses, dtype=float)
        self.corrections = np.asarray(corrections, dtype=float)
        # Imported here: scipy.interpolate costs 0.2 s, which the machines' other loop
        # models and commands (the camera's, the gantry's) would pay for nothing.
        from scipy.interpolate import (
            LinearNDInterpolator, NearestNDInterpolator, PchipInterpolator)
        self._table = PchipInterpolator(self.attitude_theta, self.attitude_w, extrapolate=True)
        scaled = self._scaled(self.poses)
        self._linear = LinearNDInterpolator(scaled, self.corrections) if len(scaled) > 4 else None
        self._nearest = NearestNDInterpolator(scaled, self.corrections)

    def _scaled(self, plate_pose):
        plate_pose = np.atleast_2d(plate_pose)
        return np.column_stack([plate_pose[:, :2], plate_pose[:, 2] * ANGLE_SCALE])

    def _tabled(self, plate_pose) -> np.ndarray:
        """Inputs from the identified kinematics with q3 - q2 from the attitude table."""
        plate_pose = np.atleast_2d(plate_pose)
        q = self.geometry.inverse(self.geometry.plate_to_stage(plate_pose))
        mean = 0.5 * (q[:, 1] + q[:, 2])
        w = self._table(plate_pose[:, 2] - self.geometry.stage2plate[2])
        return np.column_stack([q[:, 0], mean - w / 2, mean + w / 2])

    def inverse(self, plate_pose) -> np.ndarray:
        plate_pose = np.atleast_2d(np.asarray(plate_pose, dtype=float))
        q = self._tabled(plate_pose)
        scaled = self._scaled(plate_pose)
        correction = self._linear(scaled) if self._linear is not None else np.full(q.shape, np.nan)
        outside = ~np.isfinite(correction).all(axis=1)
        correction[outside] = self._nearest(scaled[outside])
        return q + correction


def models_as_dict(models: dict) -> dict:
    """The calibrated models in plain YAML/JSON types (SI units), for files and messages."""
    out = {}
    for name, model in models.items():
        entry = {'method': model.method, 'geometry': model.geometry.as_dict()}
        if isinstance(model, StepwiseModel):
            entry.update(attitude_w=model.attitude_w.tolist(),
                         attitude_theta=model.attitude_theta.tolist(),
                         poses=model.poses.tolist(), corrections=model.corrections.tolist())
        out[name] = entry
    return out


def models_from_dict(content: dict) -> dict:
    """Inverse of :func:`models_as_dict`.

    Raises
    ------
    InvalidInputError
        A model entry is incomplete (names what is missing)."""
    models = {}
    for name, entry in content.items():
        try:
            geometry = StageGeometry.from_parameters(entry['geometry'])
            if entry['method'] == 'stepwise':
                models[name] = StepwiseModel(geometry, entry['attitude_w'],
                                             entry['attitude_theta'], entry['poses'],
                                             entry['corrections'])
            else:
                models[name] = ParametricModel(geometry)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInputError(f'stage model {name!r} is incomplete or malformed: '
                                    f'{exc!r}') from None
    return models
