"""The grid plate, its three placements and the stage error model (SI units).

A plate has N x N marks, N = 2K + 1 odd, indexed i, j in -K..K about its centre, nominal
pitch p (m). Each placement puts mark (i, j) over a stage site (m, n), nominal position
(m p, n p) in the region's frame:

- ``initial``: site (i, j);
- ``rotated``: turned 90 degrees counter-clockwise seen from above about the plate centre:
  site (-j, i), and the mark's own error (A_x, A_y) becomes (-A_y, A_x);
- ``shifted``: moved one pitch along +x: site (i + 1, j).

The stage reading minus the mark's nominal site position is
``V = G(site) + A'(mark) + E(site) + noise`` with the placement's misalignment
``E = (t_x - phi y, t_y + phi x)`` and the stage (measuring-system) error, in the
corrected form of the source (the scale term of G_y has the opposite sign)::

    G_x = O y + R x + F_x,    G_y = O x - R y + F_y

O is the non-orthogonality, R the difference of the x and y scales, F the residual field
with six zero moments (sum F, sum F x, sum F y, per component). A translation, rotation
or isotropic scale of G cannot be told from the plate's (or the placements') and is not
in G: the isotropic scale needs an external length.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grid_calib.errors import PlacementError

PLACEMENTS = ('initial', 'rotated', 'shifted')


# The largest plate solved in one piece: 101 x 101 sites (8 s, 0.6 GiB, bench_results/grid.md).
MAX_HALF = 50


@dataclass(frozen=True)
class Grid:
    """An N x N plate (N = 2 half + 1) of pitch ``pitch`` (m)."""

    half: int
    pitch: float

    def __post_init__(self):
        if int(self.half) != self.half or self.half < 1:
            raise PlacementError(f'the grid needs an odd N >= 3 marks per side (half '
                                 f'{float(self.half):g})')
        if self.half > MAX_HALF:
            raise PlacementError(f'a {2 * int(self.half) + 1} x {2 * int(self.half) + 1} plate is '
                                 f'beyond the {2 * MAX_HALF + 1} x {2 * MAX_HALF + 1} this '
                                 'solver is sized for (memory and time grow with N^2); '
                                 'calibrate it in regions')
        if not (np.isfinite(self.pitch) and self.pitch > 0):
            raise PlacementError(f'pitch must be a positive length (m), not '
                                 f'{float(self.pitch):g}')

    @property
    def marks(self) -> np.ndarray:
        """Mark indices (i, j), (N^2, 2), i fastest."""
        k = np.arange(-self.half, self.half + 1)
        j, i = np.meshgrid(k, k, indexing='ij')
        return np.column_stack([i.ravel(), j.ravel()])

    @property
    def sites(self) -> np.ndarray:
        """Every stage site a placement visits (m, n), (N (N + 1), 2): the N x N region and
        the column the shifted placement adds at m = K + 1."""
        m = np.arange(-self.half, self.half + 2)
        k = np.arange(-self.half, self.half + 1)
        nn, mm = np.meshgrid(k, m, indexing='ij')
        return np.column_stack([mm.ravel(), nn.ravel()])


def site_of(marks: np.ndarray, placement: str) -> np.ndarray:
    """The stage site (m, n) each mark (i, j) lies over in ``placement``, (k, 2)."""
    i, j = marks[:, 0], marks[:, 1]
    if placement == 'initial':
        return np.column_stack([i, j])
    if placement == 'rotated':
        return np.column_stack([-j, i])
    if placement == 'shifted':
        return np.column_stack([i + 1, j])
    raise PlacementError(f'unknown placement {placement!r}; the method uses {PLACEMENTS}')


def mark_error_seen(errors: np.ndarray, placement: str) -> np.ndarray:
    """A mark's own error (A_x, A_y) (k, 2) as the stage sees it in ``placement``."""
    if placement == 'rotated':
        return np.column_stack([-errors[:, 1], errors[:, 0]])
    return errors


def stage_error(positions: np.ndarray, non_orthogonality: float, scale_difference: float,
                residual: np.ndarray, scale_sign_y: float = -1.0) -> np.ndarray:
    """G (k, 2) at ``positions`` (k, 2) (m) from O (rad), R (1) and the residual F (k, 2).
    ``scale_sign_y`` +1 is the source's literal G_y, kept only to show it fails."""
    x, y = positions[:, 0], positions[:, 1]
    return np.column_stack([non_orthogonality * y + scale_difference * x + residual[:, 0],
                            non_orthogonality * x + scale_sign_y * scale_difference * y
                            + residual[:, 1]])


def misalignment(positions: np.ndarray, shift_x: float, shift_y: float,
                 angle: float) -> np.ndarray:
    """E (k, 2) of a placement moved by (shift_x, shift_y) (m) and turned by ``angle``
    (rad, small) about the region's origin."""
    x, y = positions[:, 0], positions[:, 1]
    return np.column_stack([shift_x - angle * y, shift_y + angle * x])


def linear_parts(positions: np.ndarray, error: np.ndarray) -> dict:
    """The least-squares affine fit of ``error`` (k, 2) m at ``positions`` (k, 2) m split
    into ``shift`` (2,) m, ``scale`` (isotropic, 1), ``rotation`` (rad),
    ``non_orthogonality`` O (rad) and ``scale_difference`` R (1), as in G's model."""
    basis = np.column_stack([np.ones(len(positions)), positions])
    c = np.linalg.lstsq(basis, error, rcond=None)[0]       # rows: 1, x, y; columns: x, y
    return {'shift': c[0], 'scale': (c[1, 0] + c[2, 1]) / 2,
            'rotation': (c[1, 1] - c[2, 0]) / 2,
            'non_orthogonality': (c[2, 0] + c[1, 1]) / 2,
            'scale_difference': (c[1, 0] - c[2, 1]) / 2}


def without_similarity(positions: np.ndarray, error: np.ndarray,
                       keep_scale: bool = False) -> np.ndarray:
    """``error`` (k, 2) m at ``positions`` (k, 2) m less the translation, rotation and
    (unless ``keep_scale``) isotropic scale of its least-squares affine fit: the part of a
    stage error the plate can determine. The shear (O) and scale difference (R) stay."""
    parts = linear_parts(positions, error)
    shift, rotation = parts['shift'], parts['rotation']
    scale = 0.0 if keep_scale else parts['scale']
    x, y = positions[:, 0], positions[:, 1]
    return error - np.column_stack([shift[0] + scale * x - rotation * y,
                                    shift[1] + scale * y + rotation * x])


def region_origins(grid: Grid, columns: int, rows: int) -> dict:
    """Region centres (m0, n0) for ``columns`` x ``rows`` regions that share one row and
    column of sites with their neighbours, centred on the travel, numbered row by row."""
    span = 2 * grid.half
    return {ix + columns * iy: (span * ix - span * (columns - 1) // 2,
                                span * iy - span * (rows - 1) // 2)
            for iy in range(rows) for ix in range(columns)}
