"""Hexapod (6-SPS Gough-Stewart platform) geometry, poses and the YAML geometry file.

Conventions (DESIGN.md section 6): a pose is ``x, y, z, roll, pitch, yaw`` (m, rad) of the
platform frame in the base frame, with R = Rz(yaw) Ry(pitch) Rx(roll) (roll, pitch, yaw
about the fixed X, Y, Z axes). Leg i joins base joint b_i (base frame) to platform joint
a_i (platform frame); its commanded actuator length is
``|p + R a_i - b_i| - leg_length_offsets[i]``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from calib_core.checks import MAX_POSITION_M, check_metres
from calib_core.errors import InvalidInputError
from calib_core.files import read_yaml
from calib_core.parameters import Parameter, ParameterSet
from calib_core.storage import write_atomic

LEGS = 6
POSE_NAMES = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')
POSE_UNITS = ('m', 'm', 'm', 'rad', 'rad', 'rad')


def rotation_matrices(rpy: np.ndarray) -> np.ndarray:
    """Rotation matrices for roll-pitch-yaw angles (rad), shape (..., 3) -> (..., 3, 3)."""
    rpy = np.asarray(rpy, dtype=float)
    return Rotation.from_euler('xyz', rpy.reshape(-1, 3)).as_matrix().reshape(rpy.shape + (3,))


def rpy_from_matrices(matrices: np.ndarray) -> np.ndarray:
    """Roll-pitch-yaw angles (rad) of rotation matrices, shape (..., 3, 3) -> (..., 3)."""
    matrices = np.asarray(matrices, dtype=float)
    rpy = Rotation.from_matrix(matrices.reshape(-1, 3, 3)).as_euler('xyz')
    return rpy.reshape(matrices.shape[:-2] + (3,))


def as_poses(poses, name: str = 'pose') -> np.ndarray:
    """Validate poses: shape (6,) or (n, 6), finite; returned as float (n, 6)."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.ndim != 2 or poses.shape[1] != 6:
        raise InvalidInputError(f'{name} must be x, y, z, roll, pitch, yaw (shape (n, 6)), '
                                f'got shape {poses.shape}')
    if not np.all(np.isfinite(poses)):
        raise InvalidInputError(f'{name} contains NaN or infinite values')
    return poses


@dataclass(frozen=True, eq=False)
class HexapodGeometry:
    """Joint positions and actuator zero offsets of a hexapod.

    Attributes
    ----------
    base_joints : ndarray, shape (6, 3)
        Base joint centres b_i in the base frame, m.
    platform_joints : ndarray, shape (6, 3)
        Platform joint centres a_i in the platform frame, m.
    leg_length_offsets : ndarray, shape (6,)
        Physical leg length minus commanded actuator length, m.
    """

    base_joints: np.ndarray
    platform_joints: np.ndarray
    leg_length_offsets: np.ndarray

    def __post_init__(self):
        for name, shape in (('base_joints', (LEGS, 3)), ('platform_joints', (LEGS, 3)),
                            ('leg_length_offsets', (LEGS,))):
            try:
                value = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                raise InvalidInputError(f'{name} must be numbers') from None
            if value.shape != shape:
                raise InvalidInputError(f'{name} must have shape {shape}, got {value.shape}')
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f'{name} contains NaN or infinite values')
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def as_dict(self) -> dict:
        """The YAML form of DESIGN.md section 6 (m)."""
        return {'base_joints': self.base_joints.tolist(),
                'platform_joints': self.platform_joints.tolist(),
                'leg_length_offsets': self.leg_length_offsets.tolist()}

    @classmethod
    def from_dict(cls, content, source: str = 'geometry') -> 'HexapodGeometry':
        if not isinstance(content, dict):
            raise InvalidInputError(f'{source} must be a YAML mapping with base_joints and '
                                    'platform_joints')
        missing = [k for k in ('base_joints', 'platform_joints') if k not in content]
        if missing:
            raise InvalidInputError(f'{source} lacks {", ".join(missing)}')
        try:
            geometry = cls(content['base_joints'], content['platform_joints'],
                           content.get('leg_length_offsets', [0.0] * LEGS))
        except InvalidInputError as exc:
            raise InvalidInputError(f'{source}: {exc}') from None
        check_metres(np.concatenate([geometry.base_joints, geometry.platform_joints]),
                     'the joint centres', source, MAX_POSITION_M)
        return geometry

    def parameters(self) -> ParameterSet:
        """The 42 error-model parameters: per leg an offset and both joint centres (m)."""
        params = []
        for i in range(LEGS):
            params.append(Parameter(f'leg{i + 1}_offset', float(self.leg_length_offsets[i]), 'm'))
            params += [Parameter(f'base{i + 1}_{c}', float(self.base_joints[i, k]), 'm')
                       for k, c in enumerate('xyz')]
            params += [Parameter(f'platform{i + 1}_{c}', float(self.platform_joints[i, k]), 'm')
                       for k, c in enumerate('xyz')]
        return ParameterSet(params)

    @classmethod
    def from_parameters(cls, parameters: ParameterSet) -> 'HexapodGeometry':
        values = parameters.as_dict()
        return cls([[values[f'base{i + 1}_{c}'] for c in 'xyz'] for i in range(LEGS)],
                   [[values[f'platform{i + 1}_{c}'] for c in 'xyz'] for i in range(LEGS)],
                   [values[f'leg{i + 1}_offset'] for i in range(LEGS)])


def read_geometry(path) -> HexapodGeometry:
    """Read a geometry YAML file (DESIGN.md section 6), with clear errors."""
    return HexapodGeometry.from_dict(read_yaml(path, 'a hexapod geometry YAML'), str(path))


def write_geometry(path, geometry: HexapodGeometry, extra: dict | None = None) -> None:
    """Write ``geometry`` (plus optional extra keys) as YAML, atomically."""
    write_atomic(path, yaml.safe_dump({**geometry.as_dict(), **(extra or {})}, sort_keys=False))


def nominal_geometry(base_radius: float = 0.20, platform_radius: float = 0.10,
                     base_pair_angle: float = np.radians(15.0),
                     platform_pair_angle: float = np.radians(15.0)) -> HexapodGeometry:
    """A symmetric 6-6 Gough-Stewart platform (m, rad).

    Base joints sit in pairs at 0, 120 and 240 deg (+- ``base_pair_angle``), platform
    joints in pairs at 60, 180 and 300 deg, so each leg leans across to the neighbouring
    pair. Both joint planes are z = 0 of their frames."""
    base, platform = [], []
    for k in range(3):
        centre = np.radians(120.0 * k)
        for sign in (-1, 1):
            phi_b = centre + sign * base_pair_angle
            phi_p = centre + sign * (np.radians(60.0) - platform_pair_angle)
            base.append([base_radius * np.cos(phi_b), base_radius * np.sin(phi_b), 0.0])
            platform.append([platform_radius * np.cos(phi_p), platform_radius * np.sin(phi_p), 0.0])
    return HexapodGeometry(np.array(base), np.array(platform), np.zeros(LEGS))


def calibrated_frames(content: dict) -> list:
    """The frames a hexapod calibration file's ``content`` fixes, for ``/tf_static``:
    ``base`` -> ``base_joint<i>`` and ``platform`` -> ``platform_joint<i>``, i = 1..6, each
    joint centre (m) with the parent's axes."""
    geometry = HexapodGeometry.from_dict(content, 'the calibration in force')
    level = np.array([0.0, 0.0, 0.0, 1.0])
    return ([('base', f'base_joint{i + 1}', p, level) for i, p in enumerate(geometry.base_joints)]
            + [('platform', f'platform_joint{i + 1}', p, level)
               for i, p in enumerate(geometry.platform_joints)])
