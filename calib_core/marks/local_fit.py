"""A dot's fit under light the plate's own model does not describe (compiled, numba): a
specular highlight, a halo, a reflection's edge. The dot's edge band is fitted with a
background and a contrast of their own around the edge, smooth series in the angle about
the dot (and the background quadratic across the band), so that light varying along and
across the edge is told apart from the edge's position by the edge's sharp profile alone.

A highlight of +90 grey levels, 25 px wide, 6 px outside a 9 px dot had moved the dot's
plain fit (a level and a linear light) by 0.41 px, and its neighbour 45 px on by 0.09 px;
this fit leaves 0.004 px of it (mean over 20 seeds of the 'hot_spot' scene of
calib_core.sim.scenes), at an RMS error of 0.010 px on either dot against the plain fit's
0.007 px on clean dots: so it is fitted only where the plain fit leaves misfit, and taken
only where it moves the centre (see dot_run)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from calib_core.marks.config import EDGE_BAND_PX
from calib_core.marks.dot_fit import (
    AT_OPTIMUM, NOT_POSITIVE, marquardt_step, normal_products, pixel_columns)
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.normal import VECTOR as _VECTOR

# The contrast's series in the angle ends at this order: a highlight that multiplies the
# light changes the contrast along the edge as it does the background.
CONTRAST_ORDER = 2
# The background's series: at least this order, and one more for each this many px of
# the edge's circumference beyond (about 14 px a half-period at 9 px radius), at most the
# last: a highlight covers a smaller share of a larger dot's edge.
BACKGROUND_MIN_ORDER, BACKGROUND_ARC_PX, BACKGROUND_MAX_ORDER = 2, 28.0, 8
# Across the band the background is quadratic in the distance from the edge: a linear
# one had left 0.07 px of the highlight above.
BACKGROUND_DEGREE = 2
# Marquardt's damping: its start and the bound where the fit gives up.
_DAMPING_START, _DAMPING_MAX = 1e-3, 1e12


@njit(cache=True)
def background_order(radius):
    """The background series' order in the angle for a dot of ``radius`` px."""
    arcs = int(math.floor(2.0 * math.pi * abs(radius) / BACKGROUND_ARC_PX + 0.5))
    return min(max(BACKGROUND_MIN_ORDER, arcs), BACKGROUND_MAX_ORDER)


@njit(cache=True)
def parameter_count(geometry, order):
    """How many parameters the local fit has: ``geometry`` (4, or 6 for an ellipse) and
    the contrast's and background's series, the latter of ``order``."""
    return geometry + 2 * CONTRAST_ORDER + 1 + (2 * order + 1) * (BACKGROUND_DEGREE + 1)


@njit(cache=True, **_VECTOR)
def _local_columns(params, geometry, order, u, v, u0, v0, radius0, box, out):
    """The local model at the pixels (u, v) (n,), px: intensities into ``out[p]`` and
    their derivatives by each of the p parameters into ``out[:p]``.

    ``params``: cu, cv, radius, blur (and a, b of an ellipse when ``geometry`` is 6), the
    contrast's series (its mean, then cos and sin of each order), the background's (for
    each term of the contrast's kind up to ``order``, its value, slope and curvature
    across the band). The series are in the angle and distance about (u0, v0)
    (px) from a circle of ``radius0`` (px), fixed, so that they do not move with the
    centre. The contrast's terms of order k grow as (rho / radius0)^k across the band
    (solid harmonics, as light is: a linear light multiplies the contrast by 1 + g . e,
    whose first order is rho cos): so this model has the plain one among its own. With
    the order's terms flat across the band, a dot in a noise-free frame under uneven
    light moved by 0.003 px; with a slope of their own, free, the slope and the
    background's made a kink at the edge that the centre's shift resembles (6 times the
    error beside a highlight).

    The blur acts on the contrast times the dot, not on the dot alone: for a contrast c
    linear across the edge, a blur of variance s^2 (the optics' and the pixel's) gives
    ``c cover + s^2 grad c . grad cover``, to first order c times the cover at the pixel
    moved by s^2 grad c / c: the edge shifts towards the fainter side. The model takes
    the cover there (the shift at most the blur's sigma), so that its derivatives by the
    geometry are the cover's own. Without it, a 12 px dot whose contrast fell by 0.9 of
    itself across it was 0.08 px off its centre (a shift of up to 0.4 px at its faint
    side)."""
    ellipse = geometry == 6
    a, b = (params[4], params[5]) if ellipse else (0.0, 0.0)
    values = (params[0], params[1], params[2], params[3], 1.0, 0.0, 0.0, 0.0, a, b, u0, v0)
    first_contrast = geometry
    first_background = geometry + 2 * CONTRAST_ORDER + 1
    terms = BACKGROUND_DEGREE + 1
    spread = params[3] * params[3] + PIXEL_APERTURE_VARIANCE
    longest_shift = math.sqrt(spread)
    for i in range(u.size):
        du, dv = u[i] - u0, v[i] - v0
        rho = math.sqrt(du * du + dv * dv)
        inverse = 1.0 / max(rho, 1e-9)
        across = (rho - radius0) / EDGE_BAND_PX
        c1, s1 = du * inverse, dv * inverse
        # The contrast and its gradient, from the solid harmonics' gradients:
        # grad Re(w^k) = k (Re w^(k-1), -Im w^(k-1)) and grad Im(w^k) = k (Im w^(k-1),
        # Re w^(k-1)) for w = du + i dv.
        contrast, contrast_u, contrast_v = params[first_contrast], 0.0, 0.0
        ck, sk, solid = 1.0, 0.0, 1.0
        for k in range(1, CONTRAST_ORDER + 1):
            column = first_contrast + 2 * k - 1
            factor = k * solid / radius0
            contrast_u += factor * (params[column] * ck + params[column + 1] * sk)
            contrast_v += factor * (params[column + 1] * ck - params[column] * sk)
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
            solid *= rho / radius0
            contrast += (params[column] * ck + params[column + 1] * sk) * solid
        # The cover at the pixel moved by the blur of the varying contrast (see above);
        # where that would move it beyond the blur's sigma (a contrast fading to nothing),
        # by the sigma, and the shift's own derivatives are left out.
        relative = spread / contrast if contrast != 0.0 else 0.0
        shift_u, shift_v = relative * contrast_u, relative * contrast_v
        length = math.sqrt(shift_u * shift_u + shift_v * shift_v)
        moving = 1.0
        if length > longest_shift:
            shift_u *= longest_shift / length
            shift_v *= longest_shift / length
            moving = 0.0
        edge = pixel_columns(values, u[i] + shift_u, v[i] + shift_v, box, ellipse)
        cover = edge[4]
        cover_u, cover_v = -moving * edge[0], -moving * edge[1]
        # grad cover . grad c, and its share in each term's derivative:
        # d(c cover(x + shift)) / d(term) = term cover + s^2 (grad cover . grad term
        # - grad cover . grad c term / c).
        along = cover_u * contrast_u + cover_v * contrast_v
        share = along / contrast if contrast != 0.0 else 0.0
        out[first_contrast, i] = cover - spread * share
        background = 0.0
        for j in range(terms):
            power = across ** j
            out[first_background + j, i] = power
            background += params[first_background + j] * power
        ck, sk, solid = 1.0, 0.0, 1.0
        for k in range(1, order + 1):
            if k <= CONTRAST_ORDER:
                column = first_contrast + 2 * k - 1
                factor = k * solid / radius0
                along_c = factor * (ck * cover_u - sk * cover_v)
                along_s = factor * (sk * cover_u + ck * cover_v)
            ck, sk = ck * c1 - sk * s1, sk * c1 + ck * s1
            if k <= CONTRAST_ORDER:
                solid *= rho / radius0
                out[column, i] = ck * solid * (cover - spread * share) + spread * along_c
                out[column + 1, i] = sk * solid * (cover - spread * share) + spread * along_s
            base = first_background + (2 * k - 1) * terms
            for j in range(terms):
                power = across ** j
                out[base + j, i] = ck * power
                out[base + terms + j, i] = sk * power
                background += (params[base + j] * ck + params[base + terms + j] * sk) * power
        out[0, i], out[1, i] = edge[0] * contrast, edge[1] * contrast
        out[2, i] = edge[2] * contrast
        out[3, i] = edge[3] * contrast + 2.0 * params[3] * along
        if ellipse:
            out[4, i], out[5, i] = edge[8] * contrast, edge[9] * contrast
        out[params.size, i] = background + contrast * cover


@njit(cache=True, **_VECTOR)
def _local_normal(params, geometry, order, u, v, z, u0, v0, radius0, box, normal, gradient,
                  columns):
    """J^T J into ``normal`` and J^T r into ``gradient`` (r: model less ``z``) of the
    local model; returns r^T r. ``columns``: room of (p + 1, n)."""
    _local_columns(params, geometry, order, u, v, u0, v0, radius0, box, columns)
    columns[params.size] -= z
    return normal_products(columns, normal, gradient)


@njit(cache=True)
def local_fit(start, geometry, order, u, v, z, box, tolerance, max_iterations):
    """Levenberg-Marquardt of the local model against a dot's band pixels u, v, z (n,)
    from ``start``, the plain fit's parameters (dot_edge_model's: 8 for a disk, 10 for
    an ellipse): its geometry, its contrast as the series' mean and its background as
    the background's. The series are about the plain fit's centre and radius.

    Returns
    -------
    params : ndarray, shape (p,)
        See _local_columns; p = parameter_count(geometry, order).
    normal : ndarray, shape (p, p)
        J^T J at the fit.
    cost : float
        r^T r at the fit.
    converged : bool
    """
    width = parameter_count(geometry, order)
    current = np.zeros(width)
    current[0], current[1], current[2], current[3] = start[0], start[1], start[2], start[3]
    if geometry == 6:
        current[4], current[5] = start[8], start[9]
    current[geometry] = start[4]
    current[geometry + 2 * CONTRAST_ORDER + 1] = start[5]
    u0, v0, radius0 = start[0], start[1], start[2]
    columns = np.empty((width + 1, u.size))
    normal, gradient = np.empty((width, width)), np.empty(width)
    trial, step, descent = np.empty(width), np.empty(width), np.empty(width)
    trial_normal, trial_gradient = np.empty((width, width)), np.empty(width)
    damped = np.empty((width, width))
    cost = _local_normal(current, geometry, order, u, v, z, u0, v0, radius0, box, normal,
                         gradient, columns)
    damping = _DAMPING_START
    for _ in range(max_iterations):
        outcome = marquardt_step(normal, gradient, cost, damping, damped, descent, step)
        if outcome == AT_OPTIMUM:
            return current, normal, cost, True
        if outcome == NOT_POSITIVE:
            damping *= 10.0
            if damping > _DAMPING_MAX:
                return current, normal, cost, False
            continue
        for a in range(width):
            trial[a] = current[a] + step[a]
        trial_cost = _local_normal(trial, geometry, order, u, v, z, u0, v0, radius0, box,
                                   trial_normal, trial_gradient, columns)
        if not trial_cost <= cost:  # also when not finite
            damping *= 10.0
            if damping > _DAMPING_MAX:
                return current, normal, cost, False
            continue
        decrease = cost - trial_cost
        current[:] = trial
        normal[:] = trial_normal
        gradient[:] = trial_gradient
        cost = trial_cost
        damping = max(damping * 0.1, 1e-12)
        if decrease <= tolerance * trial_cost:
            return current, normal, cost, True
    return current, normal, cost, False
