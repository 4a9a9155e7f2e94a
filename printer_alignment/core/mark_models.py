"""Intensity models of blurred Marks used by the detector's sub-pixel fit."""
from __future__ import annotations

import numpy as np
from scipy.special import erf, erfc

_SQRT2 = np.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


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


def circle_edge_model(params: np.ndarray, u: np.ndarray, v: np.ndarray, u0: float, v0: float):
    """Blurred disk with a straight-edge (erfc) profile and a linear background.

    Parameters
    ----------
    params : (cu, cv, radius, sigma, contrast, background, grad_u, grad_v)
        Centre (px), radius (px), edge sigma (px), intensities and background slope per px.
    u, v : ndarray, shape (n,)
        Pixel coordinates.
    u0, v0 : float
        Reference point of the background slope.

    Returns
    -------
    intensity : ndarray, shape (n,)
    jacobian : ndarray, shape (n, 8)
    """
    cu, cv, radius, sigma, contrast, background, gu, gv = params
    du, dv = u - cu, v - cv
    rho = np.hypot(du, dv)
    rho_safe = np.where(rho > 1e-9, rho, 1e-9)
    z = (rho - radius) / sigma
    cover = 0.5 * erfc(z / _SQRT2)
    density = _INV_SQRT_2PI * np.exp(-0.5 * z * z)
    intensity = background + gu * (u - u0) + gv * (v - v0) + contrast * cover
    jac = np.empty((u.size, 8))
    slope = contrast * density / sigma
    jac[:, 0] = slope * du / rho_safe
    jac[:, 1] = slope * dv / rho_safe
    jac[:, 2] = slope
    jac[:, 3] = slope * z
    jac[:, 4] = cover
    jac[:, 5] = 1.0
    jac[:, 6] = u - u0
    jac[:, 7] = v - v0
    return intensity, jac
