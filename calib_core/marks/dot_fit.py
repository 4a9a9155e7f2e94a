"""The dot fit, compiled (numba): the blurred dot's intensity model and a
Levenberg-Marquardt solver per dot that sums the normal equations pixel by pixel.

Numpy spent 70-80 ns a pixel on the model's two dozen temporaries, and a batched solver
padded every dot to the largest one's pixels; here a pixel costs a square root, a
division, two polynomials (the edge's erfc and the Gaussian it shares with its slope) and
the products of its Jacobian, and each dot stops on its own. Written without libm calls
and without division checks, the pixel loops are vectorised by the compiler: the model
costs 3 ns a pixel, 9 ns with its normal equations (19 and 27 ns with libm's exp, which
kept them scalar)."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.normal import VECTOR as _VECTOR
from calib_core.marks.normal import normal_cdf_pdf as _normal_cdf_pdf

# Marquardt's damping: its start, and the bounds beyond which a dot's fit gives up or
# the damping stops shrinking.
_DAMPING_START, _DAMPING_MAX, _DAMPING_MIN = 1e-3, 1e12, 1e-12
# A fit stops, taking its last step unevaluated, when that step would move it by less
# than this share of its 1-sigma uncertainty (squared Mahalanobis length): what remains
# after it is second order in it, and another evaluation of all pixels would cost as much
# as an iteration.
STOP_SIGMAS = 0.1
# The box-aperture profile: the narrower of the box's two widths across an edge (px) is
# taken as at least this, where the profile's second differences over it would divide by
# zero (an edge along a pixel axis). The error is its square; the differences magnify the
# erfc fit's 1e-9 to 2e-8 of the contrast there (test_box_profile_matches_quadrature).
ALIGNED_EDGE = 1e-4
# ... and the optical blur it takes at least (px, added in quadrature), so that Phi(t /
# sigma) stays defined at blur 0, where the profile is the box's alone.
SHARPEST_BLUR = 1e-3
# ... and beyond this many sigma of the box it is 0 or 1 (to 1e-9 of the contrast), taken
# so: there the differences, of antiderivatives that grow as the distance squared, would
# leave their rounding (1e-11 at 30 px).
_FLAT_SIGMAS = 6.0


@njit(cache=True, inline='always', **_VECTOR)
def _antiderivatives(t, sigma):
    """Of Phi(t / sigma) by t: its first antiderivative G1 = t Phi + sigma phi and second
    G2 = ((t^2 + sigma^2) Phi + t sigma phi) / 2 (both from -infinity), with Phi and phi;
    d G2 / d sigma = sigma Phi and d G1 / d sigma = phi."""
    cdf, pdf = _normal_cdf_pdf(t / sigma)
    first = t * cdf + sigma * pdf
    return 0.5 * ((t * t + sigma * sigma) * cdf + t * sigma * pdf), first, cdf, pdf


@njit(cache=True, inline='always', **_VECTOR)
def _box_edge(distance, n_u, n_v, sigma):
    """A straight edge seen through the pixel's 1 px box and a Gaussian blur of ``sigma``
    (px): the share of the pixel's light from inside the edge at signed ``distance`` (px,
    positive outside) whose unit normal is (n_u, n_v); the density of that share's fall
    (minus its derivative by the distance, 1/px) and its derivative by sigma (1/px).

    Seen across the edge, the box is the sum of two uniforms |n_u| and |n_v| px wide, so
    the share is 1 - E Phi((distance + x + y) / sigma) over them: second differences of
    Phi's second antiderivative over their widths (the narrower at least ALIGNED_EDGE).
    Without branches (the flat regions are selected, not returned early), so that the
    compiler vectorises it."""
    wide, narrow = max(abs(n_u), abs(n_v)), min(abs(n_u), abs(n_v))
    # No direction (a pixel on the centre, a radius inside the edge; a unit normal's
    # wider part is at least sqrt(1/2)): any will do.
    directed = wide >= 0.5
    wide = wide if directed else 1.0
    narrow = max(narrow if directed else 0.0, ALIGNED_EDGE)
    outer, inner = 0.5 * (wide + narrow), 0.5 * (wide - narrow)
    g_a = _antiderivatives(distance + outer, sigma)
    g_b = _antiderivatives(distance + inner, sigma)
    g_c = _antiderivatives(distance - inner, sigma)
    g_d = _antiderivatives(distance - outer, sigma)
    scale = 1.0 / (wide * narrow)
    share = 1.0 - (g_a[0] - g_b[0] - g_c[0] + g_d[0]) * scale
    density = (g_a[1] - g_b[1] - g_c[1] + g_d[1]) * scale
    d_sigma = -sigma * (g_a[2] - g_b[2] - g_c[2] + g_d[2]) * scale
    flat = abs(distance) - outer > _FLAT_SIGMAS * sigma
    return ((0.0 if distance > 0.0 else 1.0) if flat else share, 0.0 if flat else density,
            0.0 if flat else d_sigma)


@njit(cache=True, **_VECTOR)
def _edge_columns(params, u, v, u0, v0, box, out):
    """Intensities of the pixels at (u, v) (n,), px, under ``params`` (see dot_edge_model)
    with the illumination factor 1 at (u0, v0) (px), into ``out[p]``; their derivatives by
    each parameter into ``out[:p]`` (p, n). ``box``: the pixel's aperture as its box, not
    as a Gaussian of its variance."""
    ellipse = params.size > 8
    shape = (params[8], params[9]) if ellipse else (0.0, 0.0)
    # The parameters as scalars, and each case its own loop with its flags constant in
    # it: so the compiler vectorises each loop.
    values = (params[0], params[1], params[2], params[3], params[4], params[5], params[6],
              params[7], shape[0], shape[1], u0, v0)
    if box and ellipse:
        for i in range(u.size):
            _store(out, i, pixel_columns(values, u[i], v[i], True, True), True)
    elif box:
        for i in range(u.size):
            _store(out, i, pixel_columns(values, u[i], v[i], True, False), False)
    elif ellipse:
        for i in range(u.size):
            _store(out, i, pixel_columns(values, u[i], v[i], False, True), True)
    else:
        for i in range(u.size):
            _store(out, i, pixel_columns(values, u[i], v[i], False, False), False)


@njit(cache=True, inline='always', **_VECTOR)
def pixel_columns(values, u, v, box, ellipse):
    """_edge_columns' work on one pixel at (u, v), px, with ``values`` its parameters
    (the ellipse's a, b zero for a disk) and reference point: its derivatives by cu, cv,
    radius, blur, contrast, background, grad_u, grad_v, a and b, and its intensity."""
    cu, cv, radius, blur, contrast, background, grad_u, grad_v, a, b, u0, v0 = values
    du, dv = u - cu, v - cv
    if not ellipse:
        rho = math.sqrt(du * du + dv * dv)
        inverse = 1.0 / max(rho, 1e-9)
        distance = rho - radius
        # The derivatives of -distance by cu, cv, radius; and the edge's unit normal.
        d_u, d_v, d_radius = du * inverse, dv * inverse, 1.0
        d_a = d_b = 0.0
        n_u, n_v = d_u, d_v
    else:
        w_u, w_v = (1.0 + a) * du + b * dv, b * du + (1.0 - a) * dv
        norm = math.sqrt(max(du * w_u + dv * w_v, 1e-18))
        slope_norm = math.sqrt(max(w_u * w_u + w_v * w_v, 1e-18))
        distance = (norm - radius) * norm / slope_norm
        # d distance = ((2 n - radius) dn - n d radius) / W - distance dW / W, with W
        # the slope_norm; dn and dW by each parameter from n^2 = d^T P d and
        # W^2 = |P d|^2.
        along = (2.0 * norm - radius) / (norm * slope_norm)
        across = distance / (slope_norm * slope_norm)
        pw_u, pw_v = (1.0 + a) * w_u + b * w_v, b * w_u + (1.0 - a) * w_v  # P^2 d
        d_u, d_v = along * w_u - across * pw_u, along * w_v - across * pw_v
        d_radius = norm / slope_norm
        d_a = across * (w_u * du - w_v * dv) - along * 0.5 * (du * du - dv * dv)
        d_b = across * (w_u * dv + w_v * du) - along * du * dv
        n_u, n_v = w_u / slope_norm, w_v / slope_norm
    eu, ev = u - u0, v - v0
    light = 1.0 + grad_u * eu + grad_v * ev
    if box:
        # The edge's normal: along the distance's gradient. How the profile changes
        # with the normal's direction is left out of the derivatives (see
        # dot_edge_model).
        optical = math.sqrt(blur * blur + SHARPEST_BLUR * SHARPEST_BLUR)
        cover, density, d_cover_d_sigma = _box_edge(distance, n_u, n_v, optical)
        slope = contrast * density * light
        d_blur = contrast * light * d_cover_d_sigma * (blur / optical)
    else:
        inverse_total = 1.0 / math.sqrt(blur * blur + PIXEL_APERTURE_VARIANCE)
        z = distance * inverse_total
        cdf, pdf = _normal_cdf_pdf(z)
        cover = 1.0 - cdf
        slope = pdf * (contrast * inverse_total) * light
        d_blur = slope * z * (blur * inverse_total)
    lit = background + contrast * cover
    return (d_u * slope, d_v * slope, d_radius * slope, d_blur, cover * light, light,
            eu * lit, ev * lit, d_a * slope, d_b * slope, lit * light)


@njit(cache=True, inline='always', **_VECTOR)
def _store(out, i, columns, ellipse):
    """A pixel's columns (see pixel_columns) into ``out[:, i]``, a disk's without a, b."""
    for row in range(8):
        out[row, i] = columns[row]
    if ellipse:
        out[8, i], out[9, i], out[10, i] = columns[8], columns[9], columns[10]
    else:
        out[8, i] = columns[10]


@njit(cache=True)
def dot_edge_model(params, u, v, reference, box=False):
    """Blurred disks or ellipses with a straight-edge profile, lit by a linear
    illumination gradient; a stack of independent Marks.

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

    The edge's profile is the Gaussian blur's and the pixel's aperture's. Folding the
    1 px box into the blur as a Gaussian of its variance (erfc of the distance over
    ``edge_sigma``) errs where the optics are sharp: dots rendered exactly through the
    box moved the fitted centre by up to 0.016 px at blur 0, 0.003 px at 0.3 px and
    3e-5 px at 1 px. With ``box`` the profile is the box's, seen across the edge at its
    direction (see _box_edge); it costs about 1.3 times as much a pixel. Its derivatives
    leave out how the profile changes with the edge's direction, a change of shape, not
    of position: noise-free fits still end on the truth, and the centre's derivatives
    err by up to 2 % at blur 0.05 px (test_dot_model_jacobian_matches_finite_differences).

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
    box : bool
        The pixel's aperture as its 1 px box; else folded into the blur as a Gaussian.

    Returns
    -------
    intensity : ndarray, shape (m, n)
    jacobian : ndarray, shape (m, 8 or 10, n)
        Derivatives of the intensity by each parameter, in the order of ``params``.
    """
    marks, width = params.shape
    columns = np.empty((marks, width + 1, u.shape[1]))
    for k in range(marks):
        _edge_columns(params[k], u[k], v[k], reference[k, 0], reference[k, 1], box,
                      columns[k])
    return columns[:, width], columns[:, :width]


@njit(cache=True, **_VECTOR)
def _normal_equations(params, u, v, z, flat, u0, v0, box, normal, gradient, columns):
    """The normal matrix J^T J and gradient J^T r of one dot's pixels at ``params``, into
    ``normal`` and ``gradient``, with ``columns`` (p + 1, n) as room: its edge band's
    (u, v, z: n; ``box``: see _edge_columns) and its flat pixels' (``flat``: their
    moments, see flat_terms). Returns the cost r^T r (r: model less intensity)."""
    _edge_columns(params, u, v, u0, v0, box, columns)
    columns[params.size] -= z
    return normal_products(columns, normal, gradient) + flat_terms(params, flat, normal,
                                                                   gradient)


@njit(cache=True, inline='always', **_VECTOR)
def normal_products(columns, normal, gradient):
    """From ``columns`` (p + 1, n), a fit's Jacobian's p columns and its residuals last:
    J^T J into ``normal`` (p, p) and J^T r into ``gradient`` (p,); returns r^T r."""
    width = normal.shape[0]
    cost = 0.0
    for a in range(width + 1):
        for b in range(a + 1):
            total = 0.0
            for i in range(columns.shape[1]):
                total += columns[a, i] * columns[b, i]
            if a < width:
                normal[a, b] = normal[b, a] = total
            elif b < width:
                gradient[b] = total
            else:
                cost = total
    return cost


@njit(cache=True)
def flat_terms(params, flat, normal, gradient):
    """Adds to ``normal`` and ``gradient`` the share of a dot's pixels beyond its edge
    band, where its model is flat: ``level * (1 + g . e)``, with the level the
    background outside and background + contrast inside, g the illumination gradient and
    e the pixel's offset from the reference point. Their sums are polynomials in the
    parameters and the pixels' moments (``flat``, (2, 10), outside and inside: see
    bands.edge_bands_range), so they cost the same for any number of pixels. Returns their
    cost."""
    contrast, background, grad_u, grad_v = params[4], params[5], params[6], params[7]
    cost = 0.0
    for region in range(2):
        count, s_u, s_v, s_uu, s_uv, s_vv, s_z, s_zu, s_zv, s_zz = flat[region]
        if count == 0.0:
            continue
        level = background + contrast * region
        # With f = 1 + g . e per pixel: the sums of f^2, f e and z f.
        see_g_u, see_g_v = s_uu * grad_u + s_uv * grad_v, s_uv * grad_u + s_vv * grad_v
        sum_ff = count + 2.0 * (grad_u * s_u + grad_v * s_v) + grad_u * see_g_u + grad_v * see_g_v
        sum_fu, sum_fv = s_u + see_g_u, s_v + see_g_v
        sum_zf = s_z + grad_u * s_zu + grad_v * s_zv
        cost += level * level * sum_ff - 2.0 * level * sum_zf + s_zz
        # The model's derivatives: f by the level, level e by the gradient.
        gradient[6] += level * (level * sum_fu - s_zu)
        gradient[7] += level * (level * sum_fv - s_zv)
        normal[6, 6] += level * level * s_uu
        normal[6, 7] += level * level * s_uv
        normal[7, 6] += level * level * s_uv
        normal[7, 7] += level * level * s_vv
        # The level is the background's (column 5) and, inside, the contrast's (4).
        for i in range(5 - region, 6):
            gradient[i] += level * sum_ff - sum_zf
            normal[i, 6] += level * sum_fu
            normal[6, i] += level * sum_fu
            normal[i, 7] += level * sum_fv
            normal[7, i] += level * sum_fv
            for j in range(5 - region, 6):
                normal[i, j] += sum_ff
    return cost


@njit(cache=True)
def solve_positive(matrix, rhs, out):
    """``out`` = matrix^-1 rhs by Cholesky; False if the matrix is not positive definite.

    Scalar loops: numpy's sums of row slices allocated a temporary each, about 90 for an
    8 x 8 matrix, and the solves (five a dot) cost more than the dot's model. Each sum is
    taken first and then subtracted, in the slices' order, as before."""
    n = rhs.size
    lower = np.empty((n, n))
    for j in range(n):
        total = 0.0
        for m in range(j):
            total += lower[j, m] * lower[j, m]
        diagonal = matrix[j, j] - total
        if not diagonal > 0.0:
            return False
        lower[j, j] = math.sqrt(diagonal)
        for i in range(j + 1, n):
            total = 0.0
            for m in range(j):
                total += lower[i, m] * lower[j, m]
            lower[i, j] = (matrix[i, j] - total) / lower[j, j]
    for i in range(n):
        total = 0.0
        for m in range(i):
            total += lower[i, m] * out[m]
        out[i] = (rhs[i] - total) / lower[i, i]
    for i in range(n - 1, -1, -1):
        total = 0.0
        for m in range(i + 1, n):
            total += lower[m, i] * out[m]
        out[i] = (out[i] - total) / lower[i, i]
    return True


# marquardt_step's outcomes.
AT_OPTIMUM, STEP, NOT_POSITIVE = 0, 1, 2


@njit(cache=True, inline='always')
def marquardt_step(normal, gradient, cost, damping, damped, descent, step):
    """Marquardt's step (his diagonal scaling) of a least-squares fit at J^T J ``normal``
    (p, p), J^T r ``gradient`` (p,) and cost r^T r, damped by ``damping``, into ``step``
    (``damped``, ``descent``: scratch). Returns AT_OPTIMUM where the residual is already
    orthogonal to every Jacobian column (MINPACK's gtol; checked first, because there
    rounding may keep any step from lowering the cost), STEP, or NOT_POSITIVE where the
    damped matrix is not positive definite."""
    width = gradient.size
    largest = 0.0
    for a in range(width):
        largest = max(largest, abs(gradient[a]) / math.sqrt(max(normal[a, a], 1e-300)))
    if largest <= 1e-10 * math.sqrt(max(cost, 1e-300)):
        return AT_OPTIMUM
    damped[:] = normal
    for a in range(width):
        damped[a, a] += damping * max(normal[a, a], 1e-300)
        descent[a] = -gradient[a]
    return STEP if solve_positive(damped, descent, step) else NOT_POSITIVE


@njit(cache=True)
def _levenberg_marquardt(current, u, v, z, flat, u0, v0, box, tolerance, max_iterations,
                         normal, room):
    """Levenberg-Marquardt (Marquardt's diagonal scaling) of one dot from ``current``
    (p,), which it overwrites, against its band's pixels u, v, z (n,) and its flat
    pixels' moments (``flat``, see flat_terms); ``normal`` (p, p) receives
    J^T J at the end, ``room`` is scratch of at least (p + 1) n. Returns the cost there
    and whether the fit converged (see fit_dot_range)."""
    width = current.size
    columns = room[:(width + 1) * z.size].reshape(width + 1, z.size)
    gradient, descent, step, trial = (np.empty(width), np.empty(width), np.empty(width),
                                      np.empty(width))
    trial_normal, trial_gradient = np.empty((width, width)), np.empty(width)
    damped = np.empty((width, width))
    cost = _normal_equations(current, u, v, z, flat, u0, v0, box, normal, gradient, columns)
    degrees_of_freedom = max(z.size + flat[0, 0] + flat[1, 0] - width, 1.0)
    damping = _DAMPING_START
    for _ in range(max_iterations):
        outcome = marquardt_step(normal, gradient, cost, damping, damped, descent, step)
        if outcome == AT_OPTIMUM:
            return cost, True
        if outcome == NOT_POSITIVE:
            damping *= 10.0
            if damping > _DAMPING_MAX:
                return cost, False
            continue
        # The predicted decrease of the quadratic model is the step's squared Mahalanobis
        # length times the noise variance; a nearly Gauss-Newton step within STOP_SIGMAS
        # is taken without evaluating it, and the fit ends.
        # In loops: numpy's products of 8-vectors called BLAS and allocated.
        predicted = 0.0
        for a in range(width):
            curvature = 0.0
            for b in range(width):
                curvature += normal[a, b] * step[b]
            predicted -= step[a] * (2.0 * gradient[a] + curvature)
        variance = cost / degrees_of_freedom
        if damping <= _DAMPING_START and predicted <= STOP_SIGMAS ** 2 * variance:
            current += step
            return cost - max(predicted, 0.0), True
        for a in range(width):
            trial[a] = current[a] + step[a]
        trial_cost = _normal_equations(trial, u, v, z, flat, u0, v0, box, trial_normal,
                                       trial_gradient, columns)
        if not trial_cost <= cost:  # also when not finite
            # A step that raised the cost is tried again, shorter, from the same point.
            damping *= 10.0
            if damping > _DAMPING_MAX:
                return cost, False
            continue
        scaled_step = scaled_x = 0.0
        for a in range(width):
            column = max(normal[a, a], 1e-300)
            scaled_step += column * step[a] ** 2
            scaled_x += column * trial[a] ** 2
        decrease = cost - trial_cost
        current[:] = trial
        normal[:] = trial_normal
        gradient[:] = trial_gradient
        cost = trial_cost
        damping = max(damping * 0.1, _DAMPING_MIN)
        if (decrease <= tolerance * trial_cost
                or math.sqrt(scaled_step) <= tolerance * math.sqrt(scaled_x)):
            return cost, True
    return cost, False


@njit(cache=True, nogil=True)
def fit_dot_range(x, u, v, z, spans, flat, box, reference, tolerance, max_iterations, dots,
                  normal, cost, converged):
    """Least squares of dot_edge_model against the pixels of each of the dots of indices
    ``dots``, one after another: its edge band's, and by their moments those beyond it,
    where the model is flat. Without the GIL: each dot writes only its own rows, so two
    threads can take the dots in two halves.

    Levenberg-Marquardt (Marquardt's diagonal scaling) stops when a nearly Gauss-Newton
    step would move the fit by less than STOP_SIGMAS of its uncertainty (the step is
    taken), the cost fell by less than ``tolerance`` relatively, the step, scaled by the
    Jacobian's column norms as MINPACK does, is below ``tolerance`` of x, or the residual
    is orthogonal to the Jacobian. (A rough fit on a subset of the pixels and one
    Gauss-Newton step on all, Le Cam's one-step estimator, was as fast and is not used: on
    dots seen at a steep angle, whose centres the pixels determine poorly, it left up to
    twice the full fit's error.)

    Parameters
    ----------
    x : ndarray, shape (m, p)
        Starting parameters (p = 8 or 10, see dot_edge_model); overwritten by the fits.
    u, v, z : ndarray, shape (n,)
        The dots' band pixels (px) and intensities.
    spans : ndarray of int, shape (m, 2)
        Dot k's band pixels are ``spans[k, 0]:spans[k, 1]``.
    flat : ndarray, shape (m, 2, 10)
        Each dot's flat pixels' moments about its reference point
        (bands.edge_bands_range); zeros where only the band is fitted.
    box : ndarray of bool, shape (m,)
        Whether each dot's model sees the pixel's aperture as its box (see
        dot_edge_model).
    reference : ndarray, shape (m, 2)
        Each dot's point where the illumination factor is 1, px.
    tolerance : float
    max_iterations : int
    dots : ndarray of int

    Outputs
    -------
    normal : ndarray, shape (m, p, p)
        J^T J at the fit (before its last step where that was taken unevaluated).
    cost : ndarray, shape (m,)
        Sum of squared residuals at the fit (predicted by the quadratic model where its
        last step was taken unevaluated).
    converged : ndarray of bool, shape (m,)
    """
    width = x.shape[1]
    largest = 0
    for k in dots:
        largest = max(largest, spans[k, 1] - spans[k, 0])
    # Scratch for the largest dot's Jacobian columns and residuals; each dot's are a
    # C-contiguous prefix of it, so that the compiled sums are vectorised.
    room = np.empty((width + 1) * largest)
    for k in dots:
        first, end = spans[k]
        cost[k], converged[k] = _levenberg_marquardt(
            x[k], u[first:end], v[first:end], z[first:end], flat[k], reference[k, 0],
            reference[k, 1], box[k], tolerance, max_iterations, normal[k], room)
