"""Noise-free rendering of circular and cross Marks with sub-pixel exact geometry.

The continuous image is the Mark's indicator function convolved with an isotropic Gaussian
point-spread function; the pixel aperture (a 1 px box) is folded into the Gaussian as the
box's variance, 1/12 px^2. Both are point-symmetric about the Mark centre, so the rendered
centre of symmetry is the true centre to floating-point precision: any error a detector
shows on these images is the detector's. Pixel centres are at integer coordinates (OpenCV).

- circle of radius R: intensity at distance rho is P(|X| <= R), X ~ N((rho, 0), s^2 I), the
  non-central chi-square CDF with 2 degrees of freedom (scipy.stats.ncx2), exact.
- cross of half-length L and bar width w at angle theta: the union of two bars, rendered as
  bar1 + bar2 - overlap, each a separable product of erf differences, exact.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import ncx2

from printer_alignment.core.mark_models import cross_coverage, edge_sigma


@dataclass(frozen=True)
class MarkShape:
    """A Mark in image coordinates.

    Parameters
    ----------
    kind : str
        ``"circle"`` or ``"cross"``.
    u, v : float
        Centre, px.
    size : float
        Circle radius or cross half-length, px.
    width : float
        Cross bar width, px (ignored for circles).
    angle : float
        Cross rotation, rad (ignored for circles).
    """

    kind: str
    u: float
    v: float
    size: float
    width: float = 0.0
    angle: float = 0.0


def coverage(mark: MarkShape, u: np.ndarray, v: np.ndarray, blur_sigma: float) -> np.ndarray:
    """Blurred coverage in [0, 1] of ``mark`` at pixel coordinates ``u``, ``v`` (any shape)."""
    sigma = float(edge_sigma(blur_sigma))
    du = np.asarray(u, dtype=float) - mark.u
    dv = np.asarray(v, dtype=float) - mark.v
    if mark.kind == 'circle':
        rho2 = (du ** 2 + dv ** 2) / sigma ** 2
        return ncx2.cdf((mark.size / sigma) ** 2, 2, rho2)
    if mark.kind == 'cross':
        return cross_coverage(du, dv, mark.angle, mark.size, mark.width, sigma)
    raise ValueError(f'unknown Mark kind {mark.kind!r}; use "circle" or "cross"')


def render(marks: list[MarkShape], width: int, height: int, blur_sigma: float,
           background: float, contrast: float, gradient: tuple[float, float] = (0.0, 0.0),
           undistort=None) -> np.ndarray:
    """Render Marks on a uniform background, noise-free, as float64 (height, width).

    Parameters
    ----------
    background, contrast : float
        Intensity of the background and of (Mark - background), image units.
    gradient : (gx, gy)
        Relative illumination gradient per px from the image centre; the whole image
        (background and Marks) is multiplied by ``1 + gx (u - cx) + gy (v - cy)``.
    undistort : callable or None
        Maps distorted pixel grids (u, v) to ideal ones; Marks are defined in ideal pixels.
    """
    vv, uu = np.mgrid[0:height, 0:width].astype(float)
    ideal_u, ideal_v = (uu, vv) if undistort is None else undistort(uu, vv)
    image = np.full((height, width), float(background))
    sigma = float(edge_sigma(blur_sigma))
    for mark in marks:
        reach = mark.size + 6.0 * sigma + 2.0
        if undistort is None:
            rows = slice(max(int(mark.v - reach), 0), max(int(mark.v + reach) + 2, 0))
            cols = slice(max(int(mark.u - reach), 0), max(int(mark.u + reach) + 2, 0))
            image[rows, cols] += contrast * coverage(mark, uu[rows, cols], vv[rows, cols],
                                                     blur_sigma)
            continue
        # With distortion, the pixels that see the Mark are found in ideal coordinates.
        near = (np.abs(ideal_u - mark.u) < reach) & (np.abs(ideal_v - mark.v) < reach)
        if near.any():
            image[near] += contrast * coverage(mark, ideal_u[near], ideal_v[near], blur_sigma)
    if gradient != (0.0, 0.0):
        image *= 1.0 + gradient[0] * (uu - (width - 1) / 2) + gradient[1] * (vv - (height - 1) / 2)
    return image
