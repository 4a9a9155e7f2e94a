"""Intensity models of blurred Marks used by the detector's sub-pixel fit."""
from __future__ import annotations

import numpy as np
from scipy.special import erf, erfc

_SQRT2 = np.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)
# A pixel integrates the light over its 1 px box; the models fold that box into the edge
# blur as a Gaussian of the box's variance. Fitted blur sigmas are the optics' alone, and
# an edge can never be modelled sharper than a pixel sees it.
PIXEL_APERTURE_VARIANCE = 1.0 / 12.0  # px^2


def edge_sigma(blur_sigma):
    """Gaussian sigma (px) of optical blur ``blur_sigma`` (px) and pixel aperture combined."""
    return np.sqrt(blur_sigma * blur_sigma + PIXEL_APERTURE_VARIANCE)


def blurred_bar(coord: np.ndarray, half_width: float, sigma: float) -> np.ndarray:
    """Coverage of the band |coord| <= half_width blurred by a Gaussian of ``sigma`` (px)."""
    k = 1.0 / (_SQRT2 * sigma)
    return 0.5 * (erf((half_width - coord) * k) + erf((half_width + coord) * k))


def cross_coverage(du: np.ndarray, dv: np.ndarray, angle: float, half_length: float,
                   width: float, sigma: float) -> np.ndarray:
    """Coverage of a cross (two bars, union) blurred by an isotropic Gaussian; exact.

    ``du``, ``dv`` are offsets from the centre (px), ``angle`` the rotation (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    x = c * du + s * dv
    y = -s * du + c * dv
    long_x, long_y = blurred_bar(x, half_length, sigma), blurred_bar(y, half_length, sigma)
    thin_x, thin_y = blurred_bar(x, width / 2, sigma), blurred_bar(y, width / 2, sigma)
    return long_x * thin_y + thin_x * long_y - thin_x * thin_y


def _ellipse_norm(du, dv, a, b):
    """``P d`` (two arrays), the norm ``n = sqrt(d^T P d)`` and ``W = |P d| = n |grad n|``
    at offsets ``d = (du, dv)`` (px) for ``P = [[1 + a, b], [b, 1 - a]]``; n and W are
    held off zero, so that at the centre the distance below is -radius."""
    w_u, w_v = (1.0 + a) * du + b * dv, b * du + (1.0 - a) * dv
    norm = np.sqrt(np.maximum(du * w_u + dv * w_v, 1e-18))
    slope_norm = np.sqrt(np.maximum(w_u * w_u + w_v * w_v, 1e-18))
    return w_u, w_v, norm, slope_norm


def ellipse_edge_distance(du, dv, radius, shape):
    """Sampson's distance (px, negative inside) from the edge of dot_edge_model's ellipse
    of ``radius`` (px) and ``shape`` (a, b), centred at 0, at offsets ``du``, ``dv`` (px)."""
    _, _, norm, slope_norm = _ellipse_norm(du, dv, *shape)
    return (norm - radius) * norm / slope_norm


def dot_edge_model(params: np.ndarray, u: np.ndarray, v: np.ndarray, reference: np.ndarray):
    """Blurred disks or ellipses with a straight-edge (erfc) profile, lit by a linear
    illumination gradient; a stack of independent Marks, evaluated at once.

    ``(background + contrast * cover) * (1 + grad_u (u - u0) + grad_v (v - v0))``: the
    gradient multiplies the Mark as it does the background, as uneven light on a
    reflecting (or back-lit) plate does. With an additive background slope instead, the
    Mark's side in the brighter light reads too dark, and a 13 % fall-off across a
    640 px frame moves a 40 px Mark's centre by 0.008 px (0.028 px at 64 %).

    An ellipse (a dot seen at an angle) is the set ``n(p) = radius`` of the norm
    ``n(p)^2 = d^T P d``, ``d = p - centre``, ``P = [[1 + a, b], [b, 1 - a]]``; a pixel's
    distance from its edge is taken to first order (Sampson's distance,
    ``(n - radius) / |grad n|``). That distance is exact on the edge and, like the
    straight-edge profile, symmetric about the centre, so neither biases the centre.
    With ``a = b = 0`` it is the circle's ``rho - radius``.

    Parameters
    ----------
    params : ndarray, shape (m, 8) or (m, 10)
        Per Mark: centre cu, cv (px), radius (px), optical blur sigma (px; the pixel
        aperture is added, see ``edge_sigma``), contrast and background (intensity),
        and the relative illumination gradient grad_u, grad_v (1/px). Ten columns add
        the ellipse's shape a, b (dimensionless); its semi-axes are
        ``radius / sqrt(1 +- sqrt(a^2 + b^2))`` px.
    u, v : ndarray, shape (m, n)
        Pixel coordinates, px.
    reference : ndarray, shape (m, 2)
        Point (u0, v0) where the illumination factor is 1, px.

    Returns
    -------
    intensity : ndarray, shape (m, n)
    jacobian : ndarray, shape (m, 8 or 10, n)
        Derivatives of the intensity by each parameter, in the order of ``params``.
    """
    cu, cv, radius, sigma, contrast, background, gu, gv = (column[:, None] for column in params[:, :8].T)
    du, dv = u - cu, v - cv
    jac = np.empty((len(params), params.shape[1], u.shape[1]))
    if params.shape[1] == 8:
        # Not np.hypot: its care for overflow costs 8x here, and pixel offsets cannot overflow.
        rho = np.sqrt(du * du + dv * dv)
        inv_rho = 1.0 / np.maximum(rho, 1e-9)
        distance = rho - radius
        # The derivatives of -distance by cu, cv, radius.
        np.multiply(du, inv_rho, out=jac[:, 0])
        np.multiply(dv, inv_rho, out=jac[:, 1])
        jac[:, 2] = 1.0
    else:
        a, b = params[:, 8, None], params[:, 9, None]
        w_u, w_v, norm, slope_norm = _ellipse_norm(du, dv, a, b)
        distance = (norm - radius) * norm / slope_norm
        # d distance = ((2 n - radius) dn - n d radius) / W - distance dW / W, with W the
        # slope_norm; dn and dW by each parameter from n^2 = d^T P d and W^2 = |P d|^2.
        along = (2.0 * norm - radius) / (norm * slope_norm)
        across = distance / (slope_norm * slope_norm)
        pw_u, pw_v = (1.0 + a) * w_u + b * w_v, b * w_u + (1.0 - a) * w_v  # P^2 d
        np.subtract(along * w_u, across * pw_u, out=jac[:, 0])
        np.subtract(along * w_v, across * pw_v, out=jac[:, 1])
        np.multiply(norm, 1.0 / slope_norm, out=jac[:, 2])
        np.subtract(across * (w_u * du - w_v * dv), along * 0.5 * (du * du - dv * dv), out=jac[:, 8])
        np.subtract(across * (w_u * dv + w_v * du), along * du * dv, out=jac[:, 9])
    total = edge_sigma(sigma)
    z = distance * (1.0 / total)
    cover = 0.5 * erfc(z * (1.0 / _SQRT2))
    np.subtract(u, reference[:, :1], out=jac[:, 6])
    np.subtract(v, reference[:, 1:], out=jac[:, 7])
    light = 1.0 + gu * jac[:, 6] + gv * jac[:, 7]
    slope = np.exp(-0.5 * z * z)
    slope *= (_INV_SQRT_2PI * contrast / total) * light
    jac[:, :3] *= slope[:, None]
    if params.shape[1] == 10:
        jac[:, 8:] *= slope[:, None]
    np.multiply(slope, z * (sigma / total), out=jac[:, 3])
    np.multiply(cover, light, out=jac[:, 4])
    jac[:, 5] = light
    lit = background + contrast * cover
    jac[:, 6] *= lit
    jac[:, 7] *= lit
    return lit * light, jac
