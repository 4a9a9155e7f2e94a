"""Statics of a 6-SPS hexapod: the axial leg forces that hold a payload. Real nodes
need them (a calibrator computes the static force per leg for the closed loop's play and
compliance effects), so they live in core, not beside the simulator."""
from __future__ import annotations

import numpy as np

from hexapod_calib.core.geometry import HexapodGeometry, as_poses, rotation_matrices
from hexapod_calib.core.kinematics import jacobian

GRAVITY = 9.81  # m/s^2


def leg_forces(geometry: HexapodGeometry, poses, mass: float, centre) -> np.ndarray:
    """Static axial leg forces (N, compression positive) holding a payload of ``mass`` (kg)
    with centre of mass ``centre`` (platform frame, m), shape (n, 6)."""
    poses = as_poses(poses)
    lever = np.einsum('nij,j->ni', rotation_matrices(poses[:, 3:]), np.asarray(centre, float))
    weight = np.array([0.0, 0.0, -mass * GRAVITY])
    wrench = np.concatenate([np.broadcast_to(weight, lever.shape), np.cross(lever, weight)], 1)
    # Legs push along u_i: sum f_i [u_i, (R a_i) x u_i] + wrench = 0, i.e. J^T f = -wrench.
    return np.linalg.solve(np.swapaxes(jacobian(geometry, poses), 1, 2), -wrench[..., None])[..., 0]
