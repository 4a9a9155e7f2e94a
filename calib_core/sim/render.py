"""Noise-free rendering of circular and cross Marks with sub-pixel exact geometry.

The continuous image is the Mark's indicator function convolved with an isotropic Gaussian
point-spread function; the pixel aperture (a 1 px box) is folded into the Gaussian as the
box's variance, 1/12 px^2. Both are point-symmetric about the Mark centre, so the rendered
centre of symmetry is the true centre to floating-point precision: any error a detector
shows on these images is the detector's. Pixel centres are at integer coordinates (OpenCV).
The fold is within 2e-4 of the contrast of the box itself at 1 px blur, but not for sharp
optics; ``render_through_box`` renders circles and ellipses through the box exactly.

- circle of radius R: intensity at distance rho is P(|X| <= R), X ~ N((rho, 0), s^2 I), the
  non-central chi-square CDF with 2 degrees of freedom (scipy.special.chndtr), evaluated
  once per (R, s) on a radial table 400 knots per s across the edge and interpolated
  linearly (within 1e-6 of the contrast: test/test_render.py). The table is a function of
  rho alone, so the centre stays exact; a 640 x 480 dot-plate frame renders in 0.039 s
  instead of the 0.21 s it took with the CDF at every pixel.
- ellipse (a circular dot seen at an angle) of semi-axes A, B: P(X in ellipse) as a 1-D
  integral over the ellipse's chords, by Gauss-Legendre quadrature. At A = B it agrees with
  the circle's exact form to 2e-6 of the contrast (radius 3-80 px, blur 0-1.5 px); the
  quadrature is point-symmetric about the centre, so its error does not move the centre.
  Where the blur is not much narrower than the ellipse (sigma >= 0.03 A) 48 nodes stay
  within 1e-6 of the 96 that sharper edges need (a five-axis board frame then renders in
  0.77 s instead of 1.01 s).
- cross of half-length L and bar width w at angle theta: the union of two bars, rendered as
  bar1 + bar2 - overlap, each a separable product of erf differences, exact.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import chndtr, erf, ndtr

from calib_core.marks.intensity import cross_coverage, edge_sigma


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
        Circle radius (an ellipse's mean radius, sqrt(A B)) or cross half-length, px.
    width : float
        Cross bar width, px (ignored for circles).
    angle : float
        Cross rotation, or the direction of an ellipse's major axis, rad.
    aspect : float
        A circle's axis ratio A / B >= 1: above 1, the ellipse of a dot seen at an angle.
    """

    kind: str
    u: float
    v: float
    size: float
    width: float = 0.0
    angle: float = 0.0
    aspect: float = 1.0


def coverage(mark: MarkShape, u: np.ndarray, v: np.ndarray, blur_sigma: float) -> np.ndarray:
    """Blurred coverage in [0, 1] of ``mark`` at pixel coordinates ``u``, ``v`` (any shape)."""
    sigma = float(edge_sigma(blur_sigma))
    du = np.asarray(u, dtype=float) - mark.u
    dv = np.asarray(v, dtype=float) - mark.v
    if mark.kind == 'circle' and mark.aspect != 1.0:
        c, s = np.cos(mark.angle), np.sin(mark.angle)
        root = np.sqrt(mark.aspect)
        return ellipse_coverage(c * du + s * dv, -s * du + c * dv, mark.size * root,
                                mark.size / root, sigma)
    if mark.kind == 'circle':
        rho, profile = _circle_profile(float(mark.size), sigma)
        return np.interp(np.hypot(du, dv), rho, profile)
    if mark.kind == 'cross':
        return cross_coverage(du, dv, mark.angle, mark.size, mark.width, sigma)
    raise ValueError(f'unknown Mark kind {mark.kind!r}; use "circle" or "cross"')


# The circle's radial profile: knots per blur sigma, and the half-width of the edge band
# in sigma beyond which the coverage is 1 or 0 to within 1e-17.
_KNOTS_PER_SIGMA = 400
_EDGE_HALF_WIDTH = 9.0


@lru_cache(maxsize=256)
def _circle_profile(radius: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Knots ``rho`` (px, from 0) and the exact coverage at them of a circle of
    ``radius`` blurred by ``sigma`` (px). Linear interpolation between knots sigma / 400
    apart errs by about h^2 / 8 max|f''| = 0.242 / (8 * 400^2) ~ 2e-7 of the contrast on a
    straight edge; a small circle's curvature adds to f'', and 1e-6 holds down to a 0.5 px
    radius (test/test_render.py)."""
    low = max(radius - _EDGE_HALF_WIDTH * sigma, 0.0)
    high = radius + _EDGE_HALF_WIDTH * sigma
    band = np.linspace(low, high, int(np.ceil((high - low) / sigma * _KNOTS_PER_SIGMA)) + 1)
    values = chndtr((radius / sigma) ** 2, 2, (band / sigma) ** 2)
    # Knots at 0 (inside) and far outside hold the flat parts of the profile.
    rho = np.r_[0.0, band, 2 * high + 1e6] if low > 0 else np.r_[band, 2 * high + 1e6]
    profile = np.r_[1.0, values, 0.0] if low > 0 else np.r_[values, 0.0]
    rho.flags.writeable = profile.flags.writeable = False
    return rho, profile


# Gauss-Legendre nodes over each pixel's chords (see ellipse_coverage): 96 for sharp edges,
# 48 where sigma / major >= COARSE_ABOVE (measured: within 1e-6 of 96 over radius 3-80 px,
# blur 0.05-1.5 px, aspect 1-3; test/test_render.py).
_CHORD_NODES = np.polynomial.legendre.leggauss(96)
_CHORD_NODES_COARSE = np.polynomial.legendre.leggauss(48)
COARSE_ABOVE = 0.03


def ellipse_coverage(x: np.ndarray, y: np.ndarray, major: float, minor: float,
                     sigma: float) -> np.ndarray:
    """P(p + X in ellipse), X ~ N(0, sigma^2 I): the coverage of the ellipse of semi-axes
    ``major`` along x and ``minor`` along y (px), centred at 0, blurred by an isotropic
    Gaussian of ``sigma`` (px), at points ``(x, y)`` (px, any shape).

    Integrated over the ellipse's chords at heights t = minor sin(theta), where the
    chord is |x| <= major cos(theta) and the Gaussian in x integrates exactly to erfs;
    only heights within 8 sigma of y carry weight. The sharpest feature in theta is a
    chord's end passing x near the poles, sigma / major wide; 96 nodes hold the error
    to 2e-6 (see the module docstring); 48 do where sigma >= 0.03 major."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    nodes, weights = _CHORD_NODES_COARSE if sigma >= COARSE_ABOVE * major else _CHORD_NODES
    low = np.arcsin(np.clip((y - 8 * sigma) / minor, -1, 1))[..., None]
    high = np.arcsin(np.clip((y + 8 * sigma) / minor, -1, 1))[..., None]
    theta = low + (high - low) * (nodes + 1) / 2
    height, half_chord = minor * np.sin(theta), major * np.cos(theta)
    k = 1.0 / (np.sqrt(2.0) * sigma)
    across = 0.5 * (erf((half_chord - x[..., None]) * k) + erf((half_chord + x[..., None]) * k))
    along = np.exp(-0.5 * ((height - y[..., None]) / sigma) ** 2) / (np.sqrt(2 * np.pi) * sigma)
    # dt = minor cos(theta) dtheta, and the nodes span theta's interval of width high - low.
    return np.sum(weights * across * along * minor * np.cos(theta), axis=-1) * (high - low)[..., 0] / 2


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
        # An ellipse reaches out to its major semi-axis.
        reach = mark.size * np.sqrt(mark.aspect) + 6.0 * sigma + 2.0
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


def render_through_box(marks: list[MarkShape], width: int, height: int, blur_sigma: float,
                       background: float, contrast: float, step: float = 1 / 400) -> np.ndarray:
    """Render circles and ellipses as a pixel sees them through its 1 px box, noise-free,
    as float64 (height, width): the Mark's indicator convolved with the optics' Gaussian
    (``blur_sigma``, px, 0 allowed) and the box, sampled at the pixel centres.

    ``render`` folds the box into the Gaussian as its variance, as the detector's fast
    model does; this is the reference for how far that is off, where the optics are
    sharp. The kernel is separable, a Gaussian convolved with the box along each axis,
    so each pixel is a 1-D integral over the kernel's x of the y-kernel's closed-form
    integral over the Mark's chord at that x. The integral is the midpoint rule at
    ``step`` px (1/400 moves a 3 px disk's centre by under 1e-6 px at blur 0 against
    1/1600). Slow: for tests and benchmarks of the aperture, not for whole scenes.
    """
    sigma = float(blur_sigma)
    reach = 0.5 + 6.0 * sigma
    offsets = np.arange(-reach, reach, step) + step / 2
    weights = _box_blur_density(offsets, sigma) * step
    image = np.full((height, width), float(background))
    for mark in marks:
        if mark.kind != 'circle':
            raise ValueError(f'render_through_box draws circles and ellipses, not {mark.kind!r}')
        c, s = np.cos(mark.angle), np.sin(mark.angle)
        major, minor = mark.size * np.sqrt(mark.aspect), mark.size / np.sqrt(mark.aspect)
        # The ellipse as alpha dv^2 + 2 beta du dv + gamma du^2 <= 1 about its centre.
        alpha = (s / major) ** 2 + (c / minor) ** 2
        beta = c * s * (1 / major ** 2 - 1 / minor ** 2)
        gamma = (c / major) ** 2 + (s / minor) ** 2
        extent = major + reach + 1
        rows = np.arange(max(int(mark.v - extent), 0), min(int(mark.v + extent) + 2, height))
        for col in range(max(int(mark.u - extent), 0), min(int(mark.u + extent) + 2, width)):
            du = col - offsets - mark.u
            discriminant = (beta * du) ** 2 - alpha * (gamma * du * du - 1)
            half = np.sqrt(np.clip(discriminant, 0, None)) / alpha
            middle = mark.v - beta * du / alpha
            chord = (_box_blur_cdf(rows[:, None] - middle + half, sigma)
                     - _box_blur_cdf(rows[:, None] - middle - half, sigma))
            image[rows, col] += contrast * (np.where(discriminant > 0, chord, 0.0) @ weights)
    return image


def _box_blur_density(x: np.ndarray, sigma: float) -> np.ndarray:
    """The 1 px box convolved with a Gaussian of ``sigma`` (px; 0: the box), at x (px)."""
    if sigma == 0:
        return (np.abs(x) < 0.5).astype(float)
    return ndtr((x + 0.5) / sigma) - ndtr((x - 0.5) / sigma)


def _box_blur_cdf(x: np.ndarray, sigma: float) -> np.ndarray:
    """The integral of _box_blur_density from -infinity to x."""
    def ramp(t):  # the integral of the Gaussian's CDF
        if sigma == 0:
            return np.maximum(t, 0.0)
        return t * ndtr(t / sigma) + sigma * np.exp(-0.5 * (t / sigma) ** 2) / np.sqrt(2 * np.pi)
    return ramp(x + 0.5) - ramp(x - 0.5)
