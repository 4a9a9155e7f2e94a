"""The rotary axes' location and orientation errors under their ISO 230-1 / 230-7 names, in
the machine frame of the linear axes.

The machine frame: x along the X axis's motion, y along Y's made perpendicular to x, z =
x cross y (so Z's own squareness does not enter). The directions come from M's columns
(X and Z move the camera, Y the table: the board moves by -M_X, +M_Y, -M_Z in the camera).
Origin: the board's centre at a = c = 0, the only point the camera ties the axes to.

Orientation errors (rad) are the small rotations about the named machine axis that carry
the nominal direction onto the axis's (right-hand rule): for A (nominal +x) E_B0A about y
and E_C0A about z; for C (nominal +z) E_A0C about x and E_B0C about y. Location errors
(m): where A's line crosses the plane x = 0 (E_Y0A, E_Z0A) and C's line the plane z = 0
(E_X0C, E_Y0C), from the board's centre; ``offset_C_from_A_y`` is E_Y0C - E_Y0A, the
distance of C's line from A's along y (0 when the axes meet, as designed)."""
from __future__ import annotations

import numpy as np

from dispenser_calib.core.model import DispenserModel

ORIENTATION = ('E_B0A', 'E_C0A', 'E_A0C', 'E_B0C')
LOCATION = ('E_Y0A', 'E_Z0A', 'E_X0C', 'E_Y0C', 'offset_C_from_A_y')


def machine_frame(model: DispenserModel) -> np.ndarray:
    """(3, 3) whose rows are the machine frame's x, y, z in the board-at-reset frame."""
    moves = model.rotation.T @ model.affine[:, :3] * np.array([-1.0, 1.0, -1.0])
    x = moves[:, 0] / np.linalg.norm(moves[:, 0])
    y = moves[:, 1] - x * (x @ moves[:, 1])
    y /= np.linalg.norm(y)
    return np.vstack([x, y, np.cross(x, y)])


def iso230_7(model: DispenserModel) -> dict:
    """The errors named in ORIENTATION (rad) and LOCATION (m), see the module's text."""
    frame = machine_frame(model)
    (va, ta), (vc, tc) = model.a_axis, model.c_axis
    va, ta, vc, tc = frame @ va, frame @ ta, frame @ vc, frame @ tc
    a_cross = ta - va * (ta[0] / va[0])          # A's line at x = 0
    c_cross = tc - vc * (tc[2] / vc[2])          # C's line at z = 0
    return {'E_B0A': float(-np.arctan2(va[2], va[0])), 'E_C0A': float(np.arctan2(va[1], va[0])),
            'E_A0C': float(-np.arctan2(vc[1], vc[2])), 'E_B0C': float(np.arctan2(vc[0], vc[2])),
            'E_Y0A': float(a_cross[1]), 'E_Z0A': float(a_cross[2]),
            'E_X0C': float(c_cross[0]), 'E_Y0C': float(c_cross[1]),
            'offset_C_from_A_y': float(c_cross[1] - a_cross[1])}


def iso230_7_report(model: DispenserModel, covariance: np.ndarray) -> dict:
    """:func:`iso230_7` with each value's 1-sigma from the parameters' covariance (first
    order, central differences), and the units."""
    values = iso230_7(model)
    gradient = np.zeros((len(values), len(model.values)))
    for j in range(len(model.values)):
        step = 1e-7 * max(1.0, abs(model.values[j]))
        shifted = model.values.copy()
        shifted[j] += step
        up = iso230_7(DispenserModel(shifted))
        shifted[j] -= 2 * step
        down = iso230_7(DispenserModel(shifted))
        gradient[:, j] = [(up[k] - down[k]) / (2 * step) for k in values]
    std = np.sqrt(np.clip(np.einsum('ij,jk,ik->i', gradient, covariance, gradient), 0, None))
    return {'values': values, 'std_devs': dict(zip(values, map(float, std))),
            'units': {k: 'rad' if k in ORIENTATION else 'm' for k in values},
            'frame': 'machine frame of the linear axes (x along X, y along Y made '
                     'perpendicular, z = x cross y), origin the board centre at a = c = 0'}
