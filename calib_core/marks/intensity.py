"""The blurred cross's intensity model, and the pixel aperture both Mark models fold into
the edge blur (the dot's model is compiled, in dot_fit)."""
from __future__ import annotations

import numpy as np
from scipy.special import erf

_SQRT2 = np.sqrt(2.0)
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
