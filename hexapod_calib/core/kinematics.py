"""Hexapod kinematics: inverse (leg vectors), the leg-length Jacobian and forward
kinematics by Newton iteration. All functions take batches of poses (n, 6), m and rad."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib_core.errors import InvalidInputError
from hexapod_calib.core.geometry import HexapodGeometry, as_poses, rotation_matrices
from hexapod_calib.errors import ConvergenceError, SingularPoseError

# Above this (dimensionless) condition number a pose counts as near-singular: a leg-length
# error of 1 um then moves the platform by more than ~1 mm in some direction.
MAX_CONDITION = 1000.0


def leg_vectors(geometry: HexapodGeometry, poses) -> np.ndarray:
    """Leg vectors p + R a_i - b_i in the base frame, m, shape (n, 6, 3)."""
    poses = as_poses(poses)
    rotated = np.einsum('nij,kj->nki', rotation_matrices(poses[:, 3:]), geometry.platform_joints)
    return poses[:, None, :3] + rotated - geometry.base_joints[None]


def inverse_kinematics(geometry: HexapodGeometry, poses) -> np.ndarray:
    """Commanded actuator lengths for platform poses, m, shape (n, 6)."""
    return np.linalg.norm(leg_vectors(geometry, poses), axis=2) - geometry.leg_length_offsets


def jacobian(geometry: HexapodGeometry, poses) -> np.ndarray:
    """Leg-length Jacobian, shape (n, 6, 6): row i is [u_i, (R a_i) x u_i].

    It maps the platform twist (velocity in m/s, angular velocity in rad/s, both in the
    base frame) to the leg length rates (m/s)."""
    poses = as_poses(poses)
    vectors = leg_vectors(geometry, poses)
    units = vectors / np.linalg.norm(vectors, axis=2, keepdims=True)
    rotated = np.einsum('nij,kj->nki', rotation_matrices(poses[:, 3:]), geometry.platform_joints)
    return np.concatenate([units, np.cross(rotated, units)], axis=2)


def characteristic_length(geometry: HexapodGeometry) -> float:
    """Mean platform joint radius, m: turns rotations into comparable displacements."""
    return float(np.mean(np.linalg.norm(geometry.platform_joints[:, :2], axis=1)))


def condition_numbers(geometry: HexapodGeometry, poses) -> np.ndarray:
    """Dimensionless condition number of the Jacobian at each pose, shape (n,).

    Angular columns are scaled by the platform radius so that the number does not depend
    on the unit of length."""
    jac = jacobian(geometry, poses).copy()
    jac[:, :, 3:] /= characteristic_length(geometry)
    return np.linalg.cond(jac)


def forward_kinematics(geometry: HexapodGeometry, lengths, initial=None,
                       tolerance: float = 1e-12, max_iterations: int = 30,
                       max_condition: float = MAX_CONDITION) -> np.ndarray:
    """Platform poses realised by commanded actuator lengths, by Newton iteration.

    Parameters
    ----------
    lengths : array_like, shape (6,) or (n, 6)
        Commanded actuator lengths, m.
    initial : array_like, shape (6,) or (n, 6), optional
        Starting poses (m, rad); default: straight above the base at the mean leg height.
    tolerance : float
        Largest leg-length residual accepted, m.

    Returns
    -------
    ndarray, shape (n, 6)

    Raises
    ------
    ConvergenceError
        No pose within ``tolerance`` after ``max_iterations`` (lengths no pose realises).
    SingularPoseError
        The solution is at or near a singularity.
    """
    lengths = np.atleast_2d(np.asarray(lengths, dtype=float))
    if lengths.ndim != 2 or lengths.shape[1] != 6 or not np.all(np.isfinite(lengths)):
        raise InvalidInputError(f'leg lengths must be finite, shape (n, 6); got {lengths.shape}')
    n = len(lengths)
    if initial is None:
        height = np.sqrt(np.maximum(np.mean(lengths + geometry.leg_length_offsets, axis=1) ** 2
                                    - np.mean(np.sum((geometry.base_joints[:, :2].mean(0)
                                                      - geometry.base_joints[:, :2]) ** 2, 1)), 0))
        poses = np.zeros((n, 6))
        poses[:, 2] = height
    else:
        poses = np.broadcast_to(as_poses(initial, 'initial pose'), (n, 6)).copy()
    for _ in range(max_iterations):
        error = inverse_kinematics(geometry, poses) - lengths
        if np.max(np.abs(error)) < tolerance:
            break
        try:
            step = np.linalg.solve(jacobian(geometry, poses), -error[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise ConvergenceError('forward kinematics met a singular Jacobian on the way: '
                                   'these leg lengths may not be realisable') from None
        poses[:, :3] += step[:, :3]
        rotation = Rotation.from_rotvec(step[:, 3:]) * Rotation.from_euler('xyz', poses[:, 3:])
        poses[:, 3:] = rotation.as_euler('xyz')
    else:
        worst = float(np.max(np.abs(inverse_kinematics(geometry, poses) - lengths)))
        raise ConvergenceError(f'forward kinematics did not converge in {max_iterations} '
                               f'iterations (leg-length residual {worst:.3g} m): these leg '
                               'lengths may not be realisable')
    condition = condition_numbers(geometry, poses)
    if np.any(condition > max_condition):
        raise SingularPoseError(f'pose near a singularity (condition number '
                                f'{condition.max():.3g} > {max_condition:g})')
    return poses
