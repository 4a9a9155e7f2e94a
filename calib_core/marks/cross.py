"""Sub-pixel fit of a cross Mark by scipy.optimize.least_squares on its patch of pixels."""
from __future__ import annotations

import numpy as np

from calib_core.errors import DetectionError
from calib_core.marks.intensity import cross_coverage, edge_sigma
from calib_core.marks.config import (
    CROSS_MAX_EVALUATIONS, DEGENERATE_FIT, MIN_QUARTER_TURN_OVERLAP, Mark)
from calib_core.marks.pixels import (
    centre_covariances, check_saturation, outer_ring, pixel_patch, residual_variance,
    upper_median)


def fit_cross(pixels, x0, y0, component, area, polarity, noise, full) -> Mark:
    # Imported here: scipy.optimize costs 0.4 s, and most detections fit no cross.
    from scipy.optimize import least_squares
    h, w = component.shape
    rows, cols = np.nonzero(component)
    # A cross is itself turned by a quarter turn about its centre; touching dots or
    # debris with a cross's fill are not, and the fit would wander on them (see
    # CROSS_MAX_EVALUATIONS).
    turned_rows = np.rint(rows.mean() + cols - cols.mean()).astype(int)
    turned_cols = np.rint(cols.mean() - rows + rows.mean()).astype(int)
    inside = (turned_rows >= 0) & (turned_rows < h) & (turned_cols >= 0) & (turned_cols < w)
    common = np.count_nonzero(component[turned_rows[inside], turned_cols[inside]])
    overlap = common / (2 * rows.size - common)
    if overlap < MIN_QUARTER_TURN_OVERLAP:
        raise DetectionError(f'not a cross: it differs from itself turned by 90 degrees '
                             f'(overlap {overlap:.2f}; touching Marks, debris, or a dot '
                             'with a highlight on it?)')
    cu0, cv0 = x0 + cols.mean(), y0 + rows.mean()
    du, dv = x0 + cols - cu0, y0 + rows - cv0
    dist = np.hypot(du, dv)
    tips = dist > 0.8 * dist.max()
    # The arm tips give the orientation modulo 90 degrees (circular mean of 4 * angle).
    angle0 = np.angle(np.mean(np.exp(4j * np.arctan2(dv[tips], du[tips])))) / 4.0
    half0 = float(dist.max())
    width0 = float(np.clip(area / (4.0 * half0), 1.0, half0))
    pad = 4
    values, uu, vv = pixel_patch(pixels, x0, y0, w, h, pad)
    u, v, z = uu.ravel(), vv.ravel(), values.ravel()
    check_saturation(z, full)
    background = upper_median(outer_ring(values))
    level = upper_median(pixels[y0 + rows, x0 + cols])
    x_init = np.array([cu0, cv0, angle0, half0, width0, 0.8, level - background, background])

    def residual(p):
        cu, cv, angle, half, width, sigma, contrast, bg = p
        cover = cross_coverage(u - cu, v - cv, angle, half, width, edge_sigma(sigma))
        return bg + contrast * cover - z

    # A cross converges in 5-8 evaluations; a blob that is no cross (touching dots) can
    # wander for hundreds, at a few ms each.
    result = least_squares(residual, x_init, method='lm', x_scale='jac',
                           max_nfev=CROSS_MAX_EVALUATIONS)
    cu, cv, angle, half, width, sigma, contrast, _ = result.x
    if not result.success or half <= 0 or width <= 0 or np.hypot(cu - cu0, cv - cv0) > 0.5 * half0:
        raise DetectionError('cross fit did not converge')
    covariance, determined = centre_covariances((result.jac.T @ result.jac)[None],
                                          np.array([residual_variance(result.fun, x_init.size)]))
    if not determined[0]:
        raise DetectionError(DEGENERATE_FIT)
    rms = float(np.sqrt(np.mean(result.fun ** 2)))
    return Mark('cross', float(cu), float(cv), covariance[0],
                float(half), float(contrast), float(np.clip(1 - rms / abs(contrast), 0, 1)))
