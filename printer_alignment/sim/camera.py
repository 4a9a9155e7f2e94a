"""Simulated 640x480 gantry camera looking down at a plate, substrate or stencil."""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from printer_alignment.core.geometry import CameraToPlate
from calib_core.sim.render import MarkShape, render


@dataclass(frozen=True)
class CameraOptics:
    """True optics and sensor of the simulated camera.

    Attributes
    ----------
    camera2plate : CameraToPlate
        True pixel size (m/px), image rotation (rad) and principal point (px).
    distortion : (k1, k2, p1, p2)
        OpenCV radial/tangential coefficients on normalised coordinates
        (pixel offsets divided by ``focal_px``).
    focal_px : float
        Focal length in px, only used to normalise distortion.
    blur_sigma : float
        Optical blur, px (Gaussian sigma).
    background, contrast : float
        Background level and Mark-minus-background, DN (8-bit).
    read_noise : float
        Read noise sigma, DN.
    gain : float
        Electrons per DN; shot noise is Poisson in electrons.
    gradient : (gx, gy)
        Relative illumination gradient per px.
    """

    camera2plate: CameraToPlate = field(
        default_factory=lambda: CameraToPlate(pixel_size=12.3369e-6, angle=np.deg2rad(0.35)))
    distortion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    focal_px: float = 2000.0
    blur_sigma: float = 0.8
    background: float = 200.0
    contrast: float = -150.0
    read_noise: float = 1.5
    gain: float = 4.0
    gradient: tuple[float, float] = (0.0, 0.0)
    width: int = 640
    height: int = 480

    def camera_matrix(self) -> np.ndarray:
        u0, v0 = self.camera2plate.principal
        return np.array([[self.focal_px, 0, u0], [0, self.focal_px, v0], [0, 0, 1.0]])


class CameraSim:
    """Renders what the camera sees of ``scene`` when it is at a given plate position."""

    def __init__(self, scene, optics: CameraOptics = CameraOptics(), seed: int | None = None):
        self.scene = scene
        self.optics = optics
        self.rng = np.random.default_rng(seed)

    def _undistort(self, uu: np.ndarray, vv: np.ndarray):
        o = self.optics
        points = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
        ideal = cv2.undistortPointsIter(points, o.camera_matrix(), np.array(o.distortion),
                                        None, o.camera_matrix(),
                                        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9))
        ideal = ideal.reshape(-1, 2)
        return ideal[:, 0].reshape(uu.shape), ideal[:, 1].reshape(uu.shape)

    def true_marks(self, camera_position: np.ndarray) -> list[tuple[MarkShape, object]]:
        """Marks in view as (ideal-pixel shape, plate Mark) pairs."""
        o = self.optics
        c2p = o.camera2plate
        half = 0.5 * np.hypot(o.width, o.height) * c2p.pixel_size * 1.1
        cx, cy = camera_position
        shapes = []
        for mark in self.scene.marks_within(cx - half, cx + half, cy - half, cy + half):
            u, v = c2p.pixels(np.array([[mark.x - cx, mark.y - cy]]))[0]
            if -50 <= u <= o.width + 50 and -50 <= v <= o.height + 50:
                shapes.append((MarkShape(mark.kind, u, v, mark.size / c2p.pixel_size,
                                         mark.width / c2p.pixel_size,
                                         angle=-c2p.angle), mark))
        return shapes

    def true_pixel(self, u: float, v: float) -> tuple[float, float]:
        """Where an ideal pixel appears in the distorted image, px."""
        o = self.optics
        if not any(o.distortion):
            return u, v
        k = o.camera_matrix()
        point = cv2.undistortPoints(np.array([[[u, v]]]), k, None)  # ideal -> normalised
        projected, _ = cv2.projectPoints(np.array([[point[0, 0, 0], point[0, 0, 1], 1.0]]),
                                         np.zeros(3), np.zeros(3), k, np.array(o.distortion))
        return float(projected[0, 0, 0]), float(projected[0, 0, 1])

    def capture(self, camera_position: np.ndarray,
                rng: np.random.Generator | None = None) -> np.ndarray:
        """One 8-bit image (height, width) with blur, illumination, shot and read noise,
        drawn from ``rng`` (default: the camera's own generator, advanced per frame)."""
        rng = self.rng if rng is None else rng
        o = self.optics
        marks = [shape for shape, _ in self.true_marks(camera_position)]
        undistort = self._undistort if any(o.distortion) else None
        ideal = render(marks, o.width, o.height, o.blur_sigma, o.background, o.contrast,
                       o.gradient, undistort)
        electrons = rng.poisson(np.clip(ideal, 0, None) * o.gain) / o.gain
        noisy = electrons + rng.normal(0.0, o.read_noise, ideal.shape)
        return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def tilted_plate_views(camera_matrix: np.ndarray, distortion, image_size=(640, 480),
                       views: int = 12, grid=(9, 7), pitch: float = 0.01,
                       noise_px: float = 0.05, seed: int = 0) -> list:
    """Correspondences of a planar grid target (``grid`` points, ``pitch`` m) seen in
    ``views`` tilted poses (up to about 30 degrees) by a camera with OpenCV
    ``camera_matrix`` and ``distortion`` (k1, k2, p1, p2[, k3]); Gaussian pixel noise of
    ``noise_px``. Points outside the image are dropped. Returns
    :class:`printer_alignment.core.camera_calibration.View` objects."""
    from printer_alignment.core.camera_calibration import View
    rng = np.random.default_rng(seed)
    cols, rows = grid
    model = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2) * pitch
    model = model - model.mean(axis=0)
    focal = camera_matrix[0, 0]
    # Distance at which the target spans about 70 % of the image width.
    distance = focal * (cols - 1) * pitch / (0.7 * image_size[0])
    out = []
    while len(out) < views:
        rvec = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)])
        shift = rng.uniform(-0.15, 0.15, 2) * distance
        tvec = np.array([shift[0], shift[1], distance * rng.uniform(0.9, 1.2)])
        points = np.column_stack([model, np.zeros(len(model))])
        pixels = cv2.projectPoints(points, rvec, tvec, camera_matrix,
                                   np.asarray(distortion, float))[0].reshape(-1, 2)
        pixels = pixels + rng.normal(0, noise_px, pixels.shape)
        inside = ((pixels >= 0) & (pixels <= np.array(image_size) - 1)).all(axis=1)
        if inside.sum() >= 0.8 * len(model):
            out.append(View(model[inside], pixels[inside]))
    return out
