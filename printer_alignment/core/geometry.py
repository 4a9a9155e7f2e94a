"""Camera-over-plate and XY gantry models of the vision screen printer.

Frames: ``plate`` is the reference frame (the calibration plate on the machine, m);
``camera2plate`` maps pixels of the gantry camera into it; ``gantry2plate`` maps the
gantry's motor angles (rev) to the camera's position in it. Pixels follow OpenCV.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NOMINAL_PIXEL_SIZE = 12.5e-6   # m/px, object-space pixel size of the paper's cameras
NOMINAL_LEAD_X = 0.016         # m/rev (Rx)
NOMINAL_LEAD_Y = 0.040         # m/rev (Ry)
# The drive's axis positions (commands and encoder readings, m) are motor angles times
# these nominal leads.
NOMINAL_LEADS = np.array([NOMINAL_LEAD_X, NOMINAL_LEAD_Y])


def rotation(angle: float) -> np.ndarray:
    """2x2 rotation matrix for ``angle`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def rotate_points(angle, points) -> np.ndarray:
    """``points`` (..., 2) rotated by ``angle`` (rad, scalar or broadcasting with the
    points' leading shape) about the origin."""
    c, s = np.cos(angle), np.sin(angle)
    points = np.asarray(points, dtype=float)
    return np.stack([c * points[..., 0] - s * points[..., 1],
                     s * points[..., 0] + c * points[..., 1]], -1)


@dataclass(frozen=True)
class CameraToPlate:
    """Pixel offsets to plate offsets: ``d = pixel_size * R(angle) (uv - principal)``.

    Attributes
    ----------
    pixel_size : float
        Object-space pixel size, m/px.
    angle : float
        Rotation of the image axes in the plate frame, rad.
    principal : (float, float)
        Pixel that looks straight down the optical axis, px.
    """

    pixel_size: float = NOMINAL_PIXEL_SIZE
    angle: float = 0.0
    principal: tuple[float, float] = (319.5, 239.5)

    def offset(self, uv: np.ndarray) -> np.ndarray:
        """Plate-frame offsets (m), shape (n, 2), of pixels ``uv`` (px, shape (n, 2)) from the
        camera position."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        return self.pixel_size * (uv - np.asarray(self.principal)) @ rotation(self.angle).T

    def pixels(self, offsets: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`offset`: pixels (px, (n, 2)) of plate offsets (m, (n, 2))."""
        offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
        return offsets @ rotation(self.angle) / self.pixel_size + np.asarray(self.principal)


@dataclass(frozen=True)
class GantryModel:
    """The paper's gantry model: camera position in the plate frame

    ``[xc, yc] = [[cos a, -sin(a + t)], [sin a, cos(a + t)]] [Rx px, Ry py] + [x0, y0]``

    with motor angles px, py (rev), leads Rx, Ry (m/rev), axis angle a (rad, of the gantry X
    axis in the plate frame) and non-orthogonality t (rad).
    """

    lead_x: float = NOMINAL_LEAD_X
    lead_y: float = NOMINAL_LEAD_Y
    axis_angle: float = 0.0
    non_orthogonality: float = 0.0
    offset_x: float = 0.0
    offset_y: float = 0.0

    def matrix(self) -> np.ndarray:
        a, t = self.axis_angle, self.non_orthogonality
        return np.array([[np.cos(a), -np.sin(a + t)], [np.sin(a), np.cos(a + t)]])

    def camera_position(self, revs: np.ndarray) -> np.ndarray:
        """Camera positions (m, shape (n, 2)) for motor angles ``revs`` (rev, shape (n, 2))."""
        revs = np.atleast_2d(np.asarray(revs, dtype=float))
        travel = revs * np.array([self.lead_x, self.lead_y])
        return travel @ self.matrix().T + np.array([self.offset_x, self.offset_y])

    def revs_for(self, positions: np.ndarray) -> np.ndarray:
        """Motor angles (rev, shape (n, 2)) that put the camera at ``positions`` (m, shape
        (n, 2)): the inverse of :meth:`camera_position`."""
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        travel = np.linalg.solve(self.matrix(), (positions - [self.offset_x, self.offset_y]).T).T
        return travel / np.array([self.lead_x, self.lead_y])

    def as_dict(self) -> dict:
        return {'lead_x': self.lead_x, 'lead_y': self.lead_y, 'axis_angle': self.axis_angle,
                'non_orthogonality': self.non_orthogonality, 'offset_x': self.offset_x,
                'offset_y': self.offset_y}
