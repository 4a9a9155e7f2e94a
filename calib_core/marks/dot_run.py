"""A frame's dots from their windows to their fits, in one compiled run for each half of
them (halves.run_in_halves): each dot's edge band (bands), its starting values, its fit
(dot_fit), and its fit again through the pixel's box or on its band alone where the
first fit calls for it; then, apart, the local fit (local_fit) of the dots whose band
the plain model leaves misfit. Between those steps, in numpy, the interpreter had cost
about 0.25 ms a frame, and the band's levels were left to one core."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from calib_core.marks.bands import dot_levels, edge_bands_range, narrow_band
from calib_core.marks.config import (
    DEGENERATE_FIT, FLAT_MISFIT, GROSS_MISFIT, LOCAL_MISFIT, LOCAL_MISFIT_FLOOR,
    LOCAL_SIGNIFICANCE, MIN_BAND_PX, NARROW_BAND_MIN_PX, NARROW_BAND_SIGMAS,
    NARROW_BAND_SLACK_PX)
from calib_core.marks.dot_fit import fit_dot_range, flat_terms, solve_positive
from calib_core.marks.halves import run_in_halves
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.local_fit import (
    CONTRAST_ORDER, background_order, local_fit, parameter_count)

# Why a dot is no Mark, by its code (0: it is one): its band is not fitted (1-3), or its
# fit is not (4-5).
REASONS = ('crowded: other blobs are nearer than it to most of its edge',
           'saturated Mark (clipped intensities bias the centre)',
           'no contrast between the Mark and its surroundings',
           'circle fit did not converge', DEGENERATE_FIT)
_CROWDED, _SATURATED, _NO_CONTRAST, _NOT_CONVERGED, _DEGENERATE = 1, 2, 3, 4, 5
# The fit's relative tolerance (see dot_fit.fit_dot_range) and its most iterations.
_TOLERANCE, _MAX_ITERATIONS = 1e-6, 100
# Window pixels of a frame's dots above which a second thread takes half of the dots:
# handing it the work costs about 50 us, a window pixel about 30 ns (its band, 7 ns,
# and, as most of it is band, three evaluations of the model), and the thread saves
# half of that.
PARALLEL_ABOVE_WINDOW_PX = 5000


@njit(cache=True)
def dot_windows(boxes, areas, shapes, height, width, reaches):
    """The geometry of m dots from their blobs' boxes (m, 4: x0, y0, width, height; px),
    areas (m,; px^2), shapes (a, b) of dot_edge_model (m, 2) and edge bands' reaches (m,;
    px), in a frame ``height`` x ``width`` (px).

    Returns
    -------
    radius0 : ndarray, shape (m,)
        The mean radius from the area (px).
    scale, semi_axes : ndarray, shape (m,) and (m, 2)
        The ellipse's semi-axes are scale / sqrt(1 +- e), e = |(a, b)| (the smaller, the
        larger; px), its mean radius radius0, and in dot_edge_model's norm its radius is
        radius0 * scale.
    windows : ndarray of int, shape (m, 4)
        Rows r0:r1 and columns c0:c1 of the box grown by the reach less 2 px and 0.15 of
        the larger semi-axis, inside the frame (the 6 px band's window, tuned for speed,
        grew it by 4 px: its band is whole on the diagonals, a little short on the
        sides, where the blob's box lies about on the edge).
    offsets : ndarray of int, shape (m + 1,)
        Where each window's pixels begin, laid out one after another; the last, their
        count.
    """
    marks = len(boxes)
    radius0, scale, semi_axes = np.empty(marks), np.empty(marks), np.empty((marks, 2))
    windows = np.empty((marks, 4), dtype=np.int64)
    offsets = np.zeros(marks + 1, dtype=np.int64)
    for k in range(marks):
        radius0[k] = math.sqrt(areas[k] / math.pi)
        e = math.hypot(shapes[k, 0], shapes[k, 1])
        scale[k] = (1 - e * e) ** 0.25
        semi_axes[k, 0] = radius0[k] * scale[k] / math.sqrt(1 + e)
        semi_axes[k, 1] = radius0[k] * scale[k] / math.sqrt(1 - e)
        pad = math.ceil(reaches[k] - 2 + 0.15 * semi_axes[k, 1])
        x0, y0, w, h = boxes[k]
        windows[k, 0], windows[k, 1] = max(y0 - pad, 0), min(y0 + h + pad, height)
        windows[k, 2], windows[k, 3] = max(x0 - pad, 0), min(x0 + w + pad, width)
        offsets[k + 1] = (offsets[k] + (windows[k, 1] - windows[k, 0])
                          * (windows[k, 3] - windows[k, 2]))
    return radius0, scale, semi_axes, windows, offsets


def fit_dot_windows(pixels, geometry, centres, shapes, ellipses, clear, clear_first, dark,
                    full, box_below, noise, reaches, start=None, local_only=False):
    """The fits of m dots of one model (disks, or ellipses where ``ellipses``).

    Parameters
    ----------
    pixels : ndarray, shape (H, W)
    geometry : tuple
        The dots' dot_windows.
    centres : ndarray, shape (m, 2)
        Each dot's starting centre (u, v; px), also where its illumination factor is 1.
    shapes : ndarray, shape (m, 2)
        Each dot's shape (a, b) of dot_edge_model; zeros for disks.
    clear, clear_first :
        Masks of the pixels nearer to each dot than to other blobs (see bands.edge_bands_range).
    dark : bool
    full : float
        The frame's full scale where some pixels reach it, else infinity.
    box_below : float
        The starting blur (px) below which the model sees the pixel's box (see
        circle.fit_circles).
    noise : float
        The frame's noise sigma (intensity): a dot's band misfit beyond it calls for the
        local fit (local_fit, LOCAL_MISFIT).
    reaches : ndarray, shape (m,)
        How far each dot's edge band reaches from its edge (px; its windows' in
        ``geometry``).
    start : ndarray, shape (m, p), optional
        The fits start here (an earlier fit's parameters, on another band), not from
        the band's levels.
    local_only : bool
        Every dot is fitted locally (local_fit) from ``start``, an earlier pass's local
        fit, without a plain fit. A dot whose local fit fails is not ``local``.

    Returns
    -------
    status : ndarray of int, shape (m,)
        0 where the dot is a Mark, else 1 + the index of why not in REASONS.
    x : ndarray, shape (m, p)
        The fitted parameters (p = 10 for ellipses, 8 for disks; see dot_edge_model).
    covariance : ndarray, shape (m, 2, 2)
        The centre's covariance (px^2): (J^T J)^-1's by the fit's residual variance.
    radius : ndarray, shape (m,)
        The mean radius (px).
    quality : ndarray, shape (m,)
        1 less the RMS residual over the contrast, within [0, 1].
    band_alone : ndarray of bool, shape (m,)
        Whether the fit took the band alone, no flat pixels beyond it (an edge as wide as
        the band as its start read it, a misfit inside the dot, or none in the window).
    local : ndarray of bool, shape (m,)
        Whether the dot's outcome is its local fit's.
    """
    width = 10 if ellipses else 8
    radius0, scale, semi_axes, windows, offsets = geometry
    marks, size = len(windows), int(offsets[-1])
    bands = (np.empty(size), np.empty(size), np.empty(size), np.empty(size),
             np.empty((marks, 2), dtype=np.int64), np.zeros((marks, 2, 10)))
    x = np.zeros((marks, width)) if start is None else start.astype(float)
    box = np.zeros(marks, dtype=np.bool_)
    fits = (np.zeros((marks, width, width)), np.zeros(marks), np.zeros(marks, dtype=np.bool_))
    outcome = (np.zeros(marks, dtype=np.int64), np.zeros((marks, 2, 2)), np.zeros(marks),
               np.zeros(marks))
    misfit, local = np.zeros(marks, dtype=np.bool_), np.zeros(marks, dtype=np.bool_)
    run_in_halves(lambda dots: _dots_range(pixels, windows, centres, radius0, scale, shapes,
                                           semi_axes, reaches, clear, clear_first, offsets, dark,
                                           full, box_below, noise, start is not None,
                                           local_only, dots, *bands, x, box,
                                           *fits, *outcome, misfit),
                  np.diff(offsets), PARALLEL_ABOVE_WINDOW_PX)
    # Apart from the compiled run, which so stays the code it was for the frames that call
    # no local fit (most): a frame's first run after idle pays for the code it loads.
    if misfit.any():
        _local_refits(np.flatnonzero(misfit), local_only, pixels, windows, reaches, clear,
                      clear_first, offsets, centres, radius0, *bands, x, box, *fits, *outcome,
                      local)
    status, covariance, radius, quality = outcome
    return (status, x, covariance, radius, quality, bands[5][:, :, 0].sum(axis=1) == 0,
            local)


@njit(cache=True, nogil=True)
def _dots_range(pixels, windows, centres, radius0, scale, shapes, semi_axes, reaches, clear,
                clear_first, offsets, dark, full, box_below, noise, restart, local_only, dots,
                u, v, z, distance, spans, flat, x, box, normal, cost, converged, status,
                covariance, radius, quality, misfit):
    """fit_dot_windows' work on the dots of indices ``dots``; without the GIL. The dots
    whose band leaves misfit for the local fit (``misfit``) are left without an outcome;
    with ``local_only``, every dot, unfitted: the local fit starts from ``x``. With
    ``restart``, each fit starts from its parameters in ``x``."""
    edge_bands_range(pixels, windows, centres, radius0 * scale, shapes, reaches, clear,
                     clear_first, dots, offsets, u, v, z, distance, spans, flat)
    fitted = np.empty(len(dots), dtype=np.int64)
    count = 0
    for k in dots:
        first, end = spans[k]
        band, reach = end - first, reaches[k]
        background, level, fraction_sum, transition, clipped = dot_levels(
            z[first:end], distance[first:end], dark, full)
        # Starting radius and edge sigma from the band's intensities as fractions of the
        # way from background to Mark. Blur conserves area, so the fractions sum to the
        # Mark's area inside the band; and for an erf edge those between 16 and 84 % lie
        # within one sigma of the edge, a share sigma / reach of the band's radial width.
        inner_area = max(semi_axes[k, 0] - reach, 0.0) * max(semi_axes[k, 1] - reach, 0.0)
        radius_init = math.sqrt(max(fraction_sum / math.pi + inner_area, radius0[k] ** 2 / 4))
        sigma0 = min(max(reach * transition / max(band, 1), 0.3), reach / 2)
        blur0 = math.sqrt(max(sigma0 ** 2 - PIXEL_APERTURE_VARIANCE, 0.1 ** 2))
        if restart:
            blur0 = abs(x[k, 3])
            sigma0 = math.sqrt(blur0 ** 2 + PIXEL_APERTURE_VARIANCE)
        # The model is flat beyond the band only where the band holds the edge to 4
        # sigma; a wider edge's tails there would tilt the fit under uneven light (7e-4
        # px at 3 px blur), so such dots are fitted on their band alone. A sharper
        # dot's band is narrowed to its edge's reach: its pixels beyond are flat, and
        # cost the fit nothing as moments (0.5 px blur: 40 % fewer band pixels, the
        # same centres to 1e-9 px).
        if sigma0 > reach / 4:
            flat[k] = 0.0
        else:
            narrow = max(NARROW_BAND_SIGMAS * sigma0 + NARROW_BAND_SLACK_PX, NARROW_BAND_MIN_PX)
            if narrow < reach:
                narrow_band(k, narrow, centres, u, v, z, distance, spans, flat)
        if not restart:
            x[k, 0], x[k, 1] = centres[k, 0], centres[k, 1]
            x[k, 2], x[k, 3] = radius_init * scale[k], blur0
            x[k, 4], x[k, 5] = level - background, background
            x[k, 6] = x[k, 7] = 0.0  # the illumination gradient: even light
            if x.shape[1] == 10:
                x[k, 8], x[k, 9] = shapes[k, 0], shapes[k, 1]
        box[k] = blur0 < box_below
        if clear_first[k] >= 0 and band < MIN_BAND_PX:
            status[k] = _CROWDED
        elif clipped > 0.01 * band:
            status[k] = _SATURATED
        elif level == background:
            status[k] = _NO_CONTRAST
        else:
            fitted[count] = k
            count += 1
    fitted = fitted[:count]
    if local_only:
        # The start is the earlier pass's local fit: it starts this one, which alone
        # decides the outcome (a plain fit here cost a local dot 0.2 ms).
        for k in fitted:
            misfit[k] = converged[k] = True
        return
    fit_dot_range(x, u, v, z, spans, flat, box, centres, _TOLERANCE, _MAX_ITERATIONS, fitted,
                  normal, cost, converged)
    # The start's blur is rough (a 0.3 px blur reads 0.1-0.35 px on disks, more on
    # ellipses): a dot fitted through the Gaussian fold whose fitted blur is under the
    # limit is fitted again through the box, from there.
    again = fitted[(~box[fitted]) & (np.abs(x[fitted, 3]) < box_below)]
    box[again] = True
    fit_dot_range(x, u, v, z, spans, flat, box, centres, _TOLERANCE, _MAX_ITERATIONS, again,
                  normal, cost, converged)
    # The flat pixels are trusted where they are flat: a dot whose flat pixels leave a
    # mean squared residual over FLAT_MISFIT times its band's (a highlight or texture
    # inside it, a neighbour's halo around it) is fitted again on its band alone. A
    # highlight of half the contrast inside a 30 px dot had moved it by 0.0065 px.
    width = x.shape[1]
    scratch_normal, scratch_gradient = np.zeros((width, width)), np.zeros(width)
    rough = np.zeros(len(fitted), dtype=np.bool_)
    for i in range(len(fitted)):
        k = fitted[i]
        flat_cost = flat_terms(x[k], flat[k], scratch_normal, scratch_gradient)
        rough[i] = (flat_cost * (spans[k, 1] - spans[k, 0]) > FLAT_MISFIT
                    * max(cost[k] - flat_cost, 0.0) * (flat[k, 0, 0] + flat[k, 1, 0]))
    rough_dots = fitted[rough]
    for k in rough_dots:
        flat[k] = 0.0
    fit_dot_range(x, u, v, z, spans, flat, box, centres, _TOLERANCE, _MAX_ITERATIONS,
                  rough_dots, normal, cost, converged)
    for k in fitted:
        band = spans[k, 1] - spans[k, 0]
        band_cost = cost[k] - flat_terms(x[k], flat[k], scratch_normal, scratch_gradient)
        # Not where the edge is as wide as the band (see the flat pixels above): there
        # light across the band and the edge's profile are one. Unless the misfit is
        # gross: a plain fit takes a contrast fading across the dot for a wider blur.
        floor = LOCAL_MISFIT_FLOOR * x[k, 4]
        misfit[k] = (band_cost > LOCAL_MISFIT * (noise * noise + floor * floor) * band
                     and (x[k, 3] ** 2 + PIXEL_APERTURE_VARIANCE <= (reaches[k] / 4) ** 2
                          or band_cost > (GROSS_MISFIT * x[k, 4]) ** 2 * band))
        if not misfit[k]:
            _outcome(k, x, centres, radius0, spans, flat, normal[k], cost, converged, status,
                     covariance, radius, quality)


@njit(cache=True)
def _local_refits(dots, local_only, pixels, windows, reaches, clear, clear_first, offsets,
                  centres, radius0, u, v, z, distance, spans, flat, x, box, normal, cost,
                  converged, status, covariance, radius, quality, local):
    """The outcomes of the dots of indices ``dots``: their local fits' where taken (see
    _local_refit; where it converges to a dot, with ``local_only``), else their plain
    fits'. ``local``: whether each dot's outcome is its local fit's."""
    for k in dots:
        local[k] = _local_refit(k, local_only, pixels, windows, reaches, clear, clear_first,
                                offsets, x, u, v, z, distance, spans, flat, box, normal, cost,
                                converged, radius0, centres, status, covariance, radius,
                                quality)
        if not local[k]:
            _outcome(k, x, centres, radius0, spans, flat, normal[k], cost, converged, status,
                     covariance, radius, quality)


@njit(cache=True)
def _local_refit(k, local_only, pixels, windows, reaches, clear, clear_first, offsets, x, u, v,
                 z, distance, spans, flat, box, normal, cost, converged, radius0, centres,
                 status, covariance, radius, quality):
    """Dot k fitted again with light of its own along and across its edge (local_fit),
    from its plain fit, on its whole edge band about that fit (a narrowed band had left
    the background's curvature across it less determined: 1.4 times the centre's error).
    Taken, and its outcome written, where it moves the centre further than the two fits'
    noise explains (see _centre_moved): a misfit the same all around the edge (its
    profile, not the light) leaves the centre, and the plain fit's smaller variance
    stands; with ``local_only`` (an earlier pass took it), where it converges. Returns
    whether it was taken."""
    geometry = 6 if x.shape[1] == 10 else 4
    around, radii, shapes = centres.copy(), np.zeros(len(centres)), np.zeros((len(centres), 2))
    around[k, 0], around[k, 1], radii[k] = x[k, 0], x[k, 1], x[k, 2]
    if geometry == 6:
        shapes[k, 0], shapes[k, 1] = x[k, 8], x[k, 9]
    # The plain fit's band and flat moments, which its outcome counts if this fit is not
    # taken; its pixels' room is taken by the whole band.
    plain_span, plain_flat = spans[k].copy(), flat[k].copy()
    flat[k] = 0.0
    edge_bands_range(pixels, windows, around, radii, shapes, reaches, clear, clear_first,
                     np.array([k]), offsets, u, v, z, distance, spans, flat)
    flat[k] = 0.0  # this fit takes the band alone
    first, end = spans[k]
    band = end - first
    order = background_order(x[k, 2])
    width = parameter_count(geometry, order)
    taken = band > 2 * width
    params, local_normal, local_cost = x[k], np.empty((0, 0)), 0.0
    if taken:
        params, local_normal, local_cost, taken = local_fit(
            x[k], geometry, order, u[first:end], v[first:end], z[first:end], box[k],
            _TOLERANCE, _MAX_ITERATIONS)
        plain_count = (plain_span[1] - plain_span[0] + plain_flat[0, 0] + plain_flat[1, 0])
        taken = taken and (local_only or _centre_moved(
            x[k], normal[k], cost[k] / max(plain_count - x.shape[1], 1.0), params,
            local_normal, local_cost / (band - width)))
    if not taken:
        spans[k], flat[k] = plain_span, plain_flat
        return False
    # A local fit that makes no sense as a dot (see _outcome) leaves the plain one.
    plain = x[k].copy()
    x[k, 0], x[k, 1], x[k, 2], x[k, 3] = params[0], params[1], params[2], params[3]
    if geometry == 6:
        x[k, 8], x[k, 9] = params[4], params[5]
    # The contrast and the background as their series' means; the light is theirs.
    x[k, 4], x[k, 5] = params[geometry], params[geometry + 2 * CONTRAST_ORDER + 1]
    x[k, 6] = x[k, 7] = 0.0
    plain_cost, cost[k] = cost[k], local_cost
    _outcome(k, x, centres, radius0, spans, flat, local_normal, cost, converged, status,
             covariance, radius, quality)
    if status[k] != 0:
        x[k], cost[k], status[k] = plain, plain_cost, 0
        spans[k], flat[k] = plain_span, plain_flat
        return False
    return True


@njit(cache=True)
def _centre_moved(plain, plain_normal, plain_variance, local, local_normal, local_variance):
    """Whether the local fit's centre (``local``: its parameters, J^T J and residual
    variance) lies further from the plain fit's than chance would put it with probability
    LOCAL_SIGNIFICANCE, were the plain model right (Hausman's test: the difference's
    covariance is the local centre's less the plain one's, the plain fit being the
    efficient one then; the local one's alone where that difference is not positive)."""
    local_centre, plain_centre = np.empty((2, 2)), np.empty((2, 2))
    if not (_centre_covariance(local_normal, local_variance, local_centre)
            and _centre_covariance(plain_normal, plain_variance, plain_centre)):
        return False
    uu = local_centre[0, 0] - plain_centre[0, 0]
    uv = local_centre[0, 1] - plain_centre[0, 1]
    vv = local_centre[1, 1] - plain_centre[1, 1]
    if not (uu > 0.0 and uu * vv - uv * uv > 0.0):
        uu, uv, vv = local_centre[0, 0], local_centre[0, 1], local_centre[1, 1]
    du, dv = local[0] - plain[0], local[1] - plain[1]
    distance = (vv * du * du - 2.0 * uv * du * dv + uu * dv * dv) / (uu * vv - uv * uv)
    return distance > -2.0 * math.log(LOCAL_SIGNIFICANCE)


@njit(cache=True, inline='always')
def _centre_covariance(fit_normal, variance, out):
    """The centre's covariance (2, 2; px^2) into ``out`` from a fit's J^T J (p, p; its
    first two rows the centre's) and residual variance; False where J^T J is not
    positive definite."""
    width = fit_normal.shape[0]
    unit, column = np.zeros(width), np.empty(width)
    for axis in range(2):
        unit[:] = 0.0
        unit[axis] = 1.0
        if not solve_positive(fit_normal, unit, column):
            return False
        out[0, axis], out[1, axis] = column[0] * variance, column[1] * variance
    return True


@njit(cache=True)
def _outcome(k, x, centres, radius0, spans, flat, fit_normal, cost, converged, status,
             covariance, radius, quality):
    """Dot k's mean radius, quality and centre covariance from its fit, and its status:
    not converged, or converged where it makes no sense (an ellipse past e = 1, an edge
    blurred beyond the radius, the centre moved by over half the starting radius), or
    with a centre the pixels do not determine (J^T J not positive definite).
    ``fit_normal``: the fit's J^T J (p, p), its first two rows the centre's."""
    width = fit_normal.shape[0]
    counts = spans[k, 1] - spans[k, 0] + flat[k, 0, 0] + flat[k, 1, 0]
    # An ellipse's mean radius; from e = 1 on, P is no longer positive definite and the
    # edge no ellipse.
    e = math.hypot(x[k, 8], x[k, 9]) if x.shape[1] == 10 else 0.0
    radius[k] = x[k, 2] / math.sqrt(math.sqrt(abs(1 - e * e))) if e < 1 else x[k, 2]
    quality[k] = min(max(1 - math.sqrt(cost[k] / counts) / max(abs(x[k, 4]), 1e-300), 0.0), 1.0)
    if (not converged[k] or e >= 1 or abs(x[k, 3]) > radius[k] or radius[k] <= 0
            or math.hypot(x[k, 0] - centres[k, 0], x[k, 1] - centres[k, 1]) > 0.5 * radius0[k]):
        status[k] = _NOT_CONVERGED
        return
    if not _centre_covariance(fit_normal, cost[k] / max(counts - width, 1.0), covariance[k]):
        status[k] = _DEGENERATE
        return
    uu, uv, vv = covariance[k, 0, 0], covariance[k, 0, 1], covariance[k, 1, 1]
    if not (math.isfinite(uu) and math.isfinite(uv) and math.isfinite(vv) and uu > 0
            and uu * vv - uv * uv > 0):
        status[k] = _DEGENERATE
