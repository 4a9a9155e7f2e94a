"""Pose repeatability statistics of ISO 9283 (section 7.2.3 and 7.6).

Positions in m, orientations in rad; each function returns SI values.
"""
from __future__ import annotations

import numpy as np

from calib_core.errors import InvalidInputError


def pose_repeatability(positions, orientations) -> dict:
    """Unidirectional pose repeatability of one pose visited n times the same way.

    ``RP_l = mean(l) + 3 S_l`` with ``l`` the distance of each attained position from their
    barycentre; orientation ``RP_a = 3 S_a`` (S: sample standard deviation).

    Parameters
    ----------
    positions : array_like (n, 2) or (n, 3), m
    orientations : array_like (n,) or (n, k), rad
    """
    positions = np.asarray(positions, dtype=float)
    orientations = np.asarray(orientations, dtype=float).reshape(len(positions), -1)
    if len(positions) < 3:
        raise InvalidInputError('repeatability needs at least 3 cycles (ISO 9283 uses 30)')
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(orientations))):
        raise InvalidInputError('attained poses contain NaN or infinite values')
    distances = np.linalg.norm(positions - positions.mean(axis=0), axis=1)
    spread = orientations.std(axis=0, ddof=1)
    return {'cycles': int(len(positions)),
            'RP_l_m': float(distances.mean() + 3 * distances.std(ddof=1)),
            'RP_a_rad': [float(3 * s) for s in spread],
            'barycentre_m': positions.mean(axis=0).tolist()}


def multidirectional_variation(groups) -> dict:
    """Multi-directional pose accuracy variation: ``vAP`` is the largest distance between
    the barycentres of the positions reached from different directions (m); ``vAP_a`` the
    largest spread of the mean orientations (rad). ``groups`` is a list of
    (positions (n, d), orientations (n,)) per approach direction."""
    if len(groups) < 2:
        raise InvalidInputError('multi-directional variation needs at least 2 approach '
                                'directions (ISO 9283 uses 3)')
    centres = np.array([np.mean(np.asarray(p, dtype=float), axis=0) for p, _ in groups])
    angles = np.array([np.mean(np.asarray(a, dtype=float)) for _, a in groups])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    return {'directions': int(len(groups)), 'vAP_m': float(gaps.max()),
            'vAP_a_rad': float(angles.max() - angles.min())}
