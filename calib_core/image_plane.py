"""A camera looking square down at a plane (a plate, a stage, a bed): pixels to plane
offsets by a pixel size and a rotation, the model of a telecentric or distant camera over
a flat scene. Shared by the machines whose camera rides on a gantry over a plate."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NOMINAL_PIXEL_SIZE = 12.5e-6   # m/px, object-space pixel size of the printer paper's cameras


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
