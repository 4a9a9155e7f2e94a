"""The compensation map of a self-calibrated region: the stage error G at the sites,
bilinear between them. The measuring system reads ``reading = true + G``, so the true
position is ``reading - G`` (the source's ``c' + G`` has the sign the wrong way round and
doubles the error)."""
from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from calib_core.errors import InvalidInputError, OutOfTravelError


class StageErrorMap:
    """G (m) anywhere inside the calibrated sites' rectangle; refused outside it.

    Parameters
    ----------
    sites : (s, 2) int
        Site indices (a full rectangle of them), e.g. a region's or a stitched travel's.
    stage_error : (s, 2) float
        G at the sites, m.
    pitch : float
        Site pitch, m.
    """

    def __init__(self, sites: np.ndarray, stage_error: np.ndarray, pitch: float):
        self.ms, self.ns = np.unique(sites[:, 0]), np.unique(sites[:, 1])
        grid = np.full((len(self.ms), len(self.ns), 2), np.nan)
        grid[np.searchsorted(self.ms, sites[:, 0]), np.searchsorted(self.ns, sites[:, 1])] = \
            stage_error
        if np.isnan(grid).any():
            raise InvalidInputError('the sites do not fill a rectangle: the map would have holes')
        self.x, self.y = self.ms * pitch, self.ns * pitch
        # A reading at an edge site lies off the rectangle by the stage error (um): let it
        # through, clipped to the edge, up to a hundredth of a pitch.
        self.edge_tolerance = 0.01 * pitch
        self._interpolate = RegularGridInterpolator((self.x, self.y), grid, method='linear')

    def error_at(self, points) -> np.ndarray:
        """G at ``points`` (k, 2) m, bilinear between sites.

        Raises
        ------
        OutOfTravelError
            A point outside the calibrated rectangle: the map does not extrapolate."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        t = self.edge_tolerance
        outside = ((points[:, 0] < self.x[0] - t) | (points[:, 0] > self.x[-1] + t)
                   | (points[:, 1] < self.y[0] - t) | (points[:, 1] > self.y[-1] + t))
        if np.any(outside):
            raise OutOfTravelError(f'{int(outside.sum())} point(s) outside the calibrated '
                                   f'area x {self.x[0]:.4g}..{self.x[-1]:.4g} m, y '
                                   f'{self.y[0]:.4g}..{self.y[-1]:.4g} m')
        clipped = np.column_stack([np.clip(points[:, 0], self.x[0], self.x[-1]),
                                   np.clip(points[:, 1], self.y[0], self.y[-1])])
        return self._interpolate(clipped)

    def true_position(self, readings) -> np.ndarray:
        """The true position (k, 2) m of stage readings (k, 2) m: reading - G(reading)."""
        readings = np.atleast_2d(np.asarray(readings, dtype=float))
        return readings - self.error_at(readings)
