"""Statics of a 6-SPS hexapod: the axial leg forces that hold a payload. Real nodes
need them (a calibrator computes the static force per leg for the closed loop's play and
compliance effects), so they live in core, not beside the simulator."""
from __future__ import annotations

import numpy as np

from calib_core.checks import MAX_POSITION_M, check_metres
from calib_core.errors import InvalidInputError
from hexapod_calib.core.geometry import HexapodGeometry, as_poses, rotation_matrices
from hexapod_calib.core.kinematics import jacobian

GRAVITY = 9.81  # m/s^2


def leg_forces(geometry: HexapodGeometry, poses, mass: float, centre) -> np.ndarray:
    """Static axial leg forces (N, compression positive) holding a payload of ``mass`` (kg)
    with centre of mass ``centre`` (platform frame, m), shape (n, 6).

    Raises
    ------
    InvalidInputError
        A mass that is not positive and finite, or a centre that is not 3 finite values
        within 10 m (larger values are likely mm)."""
    centre = np.asarray(centre, dtype=float)
    if not (np.isfinite(mass) and mass > 0):
        raise InvalidInputError(f'payload mass must be positive and finite (kg), not {mass}')
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise InvalidInputError(f'payload centre must be 3 finite values (m), not {centre}')
    check_metres(centre, 'the centre of mass', 'the payload', MAX_POSITION_M)
    poses = as_poses(poses)
    lever = np.einsum('nij,j->ni', rotation_matrices(poses[:, 3:]), centre)
    weight = np.array([0.0, 0.0, -mass * GRAVITY])
    wrench = np.concatenate([np.broadcast_to(weight, lever.shape), np.cross(lever, weight)], 1)
    # Legs push along u_i: sum f_i [u_i, (R a_i) x u_i] + wrench = 0, i.e. J^T f = -wrench.
    return np.linalg.solve(np.swapaxes(jacobian(geometry, poses), 1, 2), -wrench[..., None])[..., 0]
