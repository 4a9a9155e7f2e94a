"""Sub-pixel fit of circular dots (and dots seen at an angle, as ellipses): each dot
candidate's edge band and starting values, and the fit of all of a frame's dots in one
compiled run (dot_fit)."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calib_core.errors import DetectionError
from calib_core.marks.config import DEGENERATE_FIT, EDGE_BAND_PX, MIN_BAND_PX, Mark
from calib_core.marks.dot_fit import band_levels, edge_band, fit_dots
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.pixels import centre_covariances, check_saturation, clipped_window
from calib_core.marks.segmentation import MomentShape

# edge_band's ``clear`` that keeps every pixel.
_EVERYWHERE = np.zeros((0, 0), dtype=bool)


@dataclass(frozen=True)
class CircleStart:
    """A dot candidate's edge-band pixels (px, image units) and starting parameters."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    # dot_edge_model's: (cu, cv, radius, blur, contrast, background, grad_u, grad_v), and
    # for an ellipse its shape (a, b).
    x: np.ndarray
    radius0: float  # from the candidate's area, px


def circle_start(pixels, x0, y0, w, h, area, centroid, polarity, full,
                  ellipse: MomentShape | None, segmentation) -> CircleStart:
    """The edge band and starting parameters of a dot of ``area`` px whose blob has its
    box at x0, y0, w, h and its centroid at ``centroid`` (px); a disk, or with
    ``ellipse`` the ellipse of those moments. ``segmentation``: the frame's labels and
    this blob's label, to keep other blobs out of the band."""
    radius0 = np.sqrt(area / np.pi)
    shape = ellipse.shape if ellipse is not None else (0.0, 0.0)
    # The ellipse's semi-axes are scale / sqrt(1 +- e), its mean radius radius0, and in
    # dot_edge_model's norm its radius is radius0 * scale.
    e = np.hypot(*shape)
    scale = (1 - e * e) ** 0.25
    semi_axes = radius0 * scale / np.sqrt([1 + e, 1 - e])
    pad = int(np.ceil(4 + 0.15 * semi_axes[1]))
    r0, r1, c0, c1 = clipped_window(pixels.shape, x0, y0, w, h, pad)
    radius = radius0 * scale
    clear = _clear_of_neighbours(segmentation, r0, r1, c0, c1)
    # The centre is in the edge; the flat interior adds nothing but time.
    u, v, z, distance = edge_band(pixels, r0, r1, c0, c1, centroid, radius, shape,
                                  EDGE_BAND_PX, _EVERYWHERE if clear is None else clear)
    if clear is not None and z.size < MIN_BAND_PX:
        raise DetectionError('crowded: other blobs are nearer than it to most of its edge')
    check_saturation(z, full)
    background, level, area, transition = band_levels(z, distance, polarity == 'dark')
    if level == background:
        raise DetectionError('no contrast between the Mark and its surroundings')
    # Starting radius and edge sigma from the band's intensities as fractions of the way
    # from background to Mark. Blur conserves area, so the fractions sum to the Mark's
    # area inside the band; and for an erf edge those between 16 and 84 % lie within one
    # sigma of the edge, a share sigma / EDGE_BAND_PX of the band's radial width.
    inner_axes = np.maximum(semi_axes - EDGE_BAND_PX, 0.0)
    radius_init = np.sqrt(max(area / np.pi + inner_axes[0] * inner_axes[1], radius0 ** 2 / 4))
    sigma0 = float(np.clip(EDGE_BAND_PX * transition / z.size, 0.3, 3.0))
    blur0 = np.sqrt(max(sigma0 ** 2 - PIXEL_APERTURE_VARIANCE, 0.1 ** 2))
    x = [*centroid, radius_init * scale, blur0, level - background, background, 0.0, 0.0]
    return CircleStart(u, v, z, np.array(x + list(shape) if ellipse is not None else x),
                       float(radius0))


def _clear_of_neighbours(segmentation, r0, r1, c0, c1):
    """Where the window rows r0:r1, columns c0:c1 are nearer to the blob than to any other
    (boolean, window-shaped), or None if no other blob is in it.

    A neighbour's blurred edge inside the band pulls the centre away from it: by 0.05 px
    in a dense grid seen at 50 degrees (14 px between dot centres). Halfway between two
    blobs, each one's edge has fallen to a few % of its contrast."""
    labels, label = segmentation
    window = labels[r0:r1, c0:c1]
    own = window == label
    others = (window != 0) & ~own
    if not others.any():
        return None
    # distanceTransform measures to the nearest zero pixel.
    to_own = cv2.distanceTransform((~own).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    to_others = cv2.distanceTransform((~others).view(np.uint8), cv2.DIST_L2,
                                      cv2.DIST_MASK_PRECISE)
    return to_own <= to_others


def fit_circles(starts: list[CircleStart]) -> list[Mark | DetectionError]:
    """The circles' fits, in the order of ``starts``: a Mark, or why there is none.

    The disks are fitted in one compiled run, the ellipses in another."""
    results: list = [None] * len(starts)
    for width in (8, 10):
        group = [k for k, start in enumerate(starts) if start.x.size == width]
        if group:
            for index, mark in zip(group, _fit_circle_group([starts[k] for k in group])):
                results[index] = mark
    return results


def _fit_circle_group(starts: list[CircleStart]) -> list[Mark | DetectionError]:
    """The fits of circles of one model (all disks or all ellipses)."""
    x = np.array([s.x for s in starts])
    reference = x[:, :2].copy()
    offsets = np.cumsum([0] + [s.z.size for s in starts])
    normals, costs, converged = fit_dots(
        x, np.concatenate([s.u for s in starts]), np.concatenate([s.v for s in starts]),
        np.concatenate([s.z for s in starts]), offsets, reference, 1e-6)
    counts = np.diff(offsets)
    covariances, determined = centre_covariances(
        normals, costs / np.maximum(counts - x.shape[1], 1))
    results: list[Mark | DetectionError] = []
    for k, xk in enumerate(x):
        cu, cv, radius, sigma, contrast = xk[:5]
        # An ellipse's mean radius; from e = 1 on, P is no longer positive definite and
        # the edge no ellipse.
        e = float(np.hypot(*xk[8:])) if xk.size > 8 else 0.0
        if e < 1:
            radius /= (1 - e * e) ** 0.25
        if (not converged[k] or e >= 1 or abs(sigma) > radius or radius <= 0
                or np.hypot(cu - reference[k, 0], cv - reference[k, 1]) > 0.5 * starts[k].radius0):
            results.append(DetectionError('circle fit did not converge'))
        elif not determined[k]:
            results.append(DetectionError(DEGENERATE_FIT))
        else:
            rms = float(np.sqrt(costs[k] / counts[k]))
            results.append(Mark('circle', float(cu), float(cv), covariances[k], float(radius),
                                float(contrast), float(np.clip(1 - rms / abs(contrast), 0, 1))))
    return results
