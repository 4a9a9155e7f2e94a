"""Sub-pixel fit of circular dots (and dots seen at an angle, as ellipses): the edge bands
and starting values of all of a frame's dot candidates, then their fits, each in one
compiled run (dot_fit)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from calib_core.errors import DetectionError
from calib_core.marks.config import (
    DEGENERATE_FIT, EDGE_BAND_PX, FLAT_MISFIT, MIN_BAND_PX, Mark)
from calib_core.marks.bands import band_levels, crowded_windows, edge_bands
from calib_core.marks.dot_fit import fit_dots, flat_costs
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.pixels import centre_covariances, clipped_window
from calib_core.marks.segmentation import MomentShape


@dataclass(frozen=True)
class DotCandidate:
    """A blob taken for a dot: its bounding box (x0, y0, width, height; px), area (px^2)
    and centroid (u, v; px), the ellipse of its moments where it is fitted as one (a dot
    seen at an angle), and its label in the frame's segmentation."""

    box: tuple[int, int, int, int]
    area: float
    centroid: tuple[float, float]
    ellipse: MomentShape | None
    label: int


def fit_circles(pixels, candidates: list[DotCandidate], labels, polarity: str,
                full: float | None, box_below: float) -> list[Mark | DetectionError]:
    """The dots' fits, in the order of ``candidates``: a Mark, or why there is none.

    ``labels``: the frame's segmentation, to keep other blobs out of each dot's band;
    ``full``: the frame's full scale where some pixels reach it, else None;
    ``box_below``: the starting blur (px) below which a dot's model sees the pixel's
    box as it is (DetectorConfig.box_aperture_below_blur_px)."""
    results: list = [None] * len(candidates)
    for ellipses in (False, True):
        group = [k for k, c in enumerate(candidates) if (c.ellipse is not None) == ellipses]
        if group:
            fits = _fit_group(pixels, [candidates[k] for k in group], labels, polarity, full,
                              box_below)
            for index, fit in zip(group, fits):
                results[index] = fit
    return results


def _fit_group(pixels, candidates, labels, polarity, full,
               box_below) -> list[Mark | DetectionError]:
    """The fits of dots of one model: all disks, or all ellipses."""
    ellipses = candidates[0].ellipse is not None
    boxes = np.array([c.box for c in candidates])
    centres = np.array([c.centroid for c in candidates], dtype=float)
    radius0 = np.sqrt(np.array([c.area for c in candidates]) / np.pi)
    shapes = np.array([c.ellipse.shape if ellipses else (0.0, 0.0) for c in candidates])
    # The ellipse's semi-axes are scale / sqrt(1 +- e), its mean radius radius0, and in
    # dot_edge_model's norm its radius is radius0 * scale.
    e = np.hypot(shapes[:, 0], shapes[:, 1])
    scale = (1 - e * e) ** 0.25
    semi_axes = (radius0 * scale)[:, None] / np.sqrt(1 + np.outer(e, [1.0, -1.0]))
    pad = np.ceil(4 + 0.15 * semi_axes[:, 1]).astype(int)
    windows = np.column_stack(clipped_window(pixels.shape, *boxes.T, pad))
    own = np.array([c.label for c in candidates])
    clear, clear_first = _clear_masks(labels, windows, own)
    # The model is evaluated on the edge band; the flat pixels beyond it enter the fit by
    # their moments: they pin the illumination gradient, which the band alone confuses
    # with a shift of the centre (10 % of the centre's error on 20-40 px dots).
    u, v, z, distance, spans, flat = edge_bands(pixels, windows, centres, radius0 * scale,
                                                shapes, EDGE_BAND_PX, clear, clear_first)
    band = spans[:, 1] - spans[:, 0]
    background, level, fraction_sum, transition, clipped = band_levels(
        z, distance, spans, polarity == 'dark', np.inf if full is None else float(full)).T
    # Starting radius and edge sigma from the band's intensities as fractions of the way
    # from background to Mark. Blur conserves area, so the fractions sum to the Mark's
    # area inside the band; and for an erf edge those between 16 and 84 % lie within one
    # sigma of the edge, a share sigma / EDGE_BAND_PX of the band's radial width.
    inner_axes = np.maximum(semi_axes - EDGE_BAND_PX, 0.0)
    radius_init = np.sqrt(np.maximum(fraction_sum / np.pi + inner_axes[:, 0] * inner_axes[:, 1],
                                     radius0 ** 2 / 4))
    sigma0 = np.clip(EDGE_BAND_PX * transition / np.maximum(band, 1), 0.3, 3.0)
    blur0 = np.sqrt(np.maximum(sigma0 ** 2 - PIXEL_APERTURE_VARIANCE, 0.1 ** 2))
    # The model is flat beyond the band only where the band holds the edge to 4 sigma;
    # a wider edge's tails there would tilt the fit under uneven light (7e-4 px at 3 px
    # blur), so such dots are fitted on their band alone.
    flat[sigma0 > EDGE_BAND_PX / 4] = 0.0
    even_light = np.zeros((len(candidates), 2))  # the starting illumination gradient
    x = np.column_stack([centres, radius_init * scale, blur0, level - background, background,
                         even_light] + ([shapes] if ellipses else []))
    problems = [_band_problem(*values) for values in
                zip(clear_first >= 0, band, clipped, level == background)]
    fitted = np.flatnonzero([problem is None for problem in problems])
    x_fit = x[fitted]
    box = blur0[fitted] < box_below
    flat_fit = flat[fitted]
    normals, costs, converged = fit_dots(x_fit, u, v, z, spans[fitted], flat_fit, box,
                                         centres[fitted], 1e-6)

    def fit_again(dots):
        """Fits the dots of indices ``dots`` (into ``fitted``) again, from where they are,
        with their ``box`` and ``flat_fit`` as they are now."""
        start = x_fit[dots]
        normals[dots], costs[dots], converged[dots] = fit_dots(
            start, u, v, z, spans[fitted[dots]], flat_fit[dots], box[dots],
            centres[fitted[dots]], 1e-6)
        x_fit[dots] = start

    # The start's blur is rough (a 0.3 px blur reads 0.1-0.35 px on disks, more on
    # ellipses): a dot fitted through the Gaussian fold whose fitted blur is under the
    # limit is fitted again through the box, from there.
    again = np.flatnonzero(~box & (np.abs(x_fit[:, 3]) < box_below))
    if again.size:
        box[again] = True
        fit_again(again)
    # The flat pixels are trusted where they are flat: a dot whose flat pixels leave a
    # mean squared residual over FLAT_MISFIT times its band's (a highlight or texture
    # inside it, a neighbour's halo around it) is fitted again on its band alone. A
    # highlight of half the contrast inside a 30 px dot had moved it by 0.0065 px.
    flat_cost = flat_costs(x_fit, flat_fit)
    rough = np.flatnonzero(flat_cost * band[fitted] > FLAT_MISFIT
                           * np.maximum(costs - flat_cost, 0.0) * flat_fit[:, :, 0].sum(axis=1))
    if rough.size:
        flat_fit[rough] = 0.0
        fit_again(rough)
    counts = band[fitted] + flat_fit[:, :, 0].sum(axis=1)
    covariances, determined = centre_covariances(
        normals, costs / np.maximum(counts - x.shape[1], 1))
    results: list[Mark | DetectionError] = [DetectionError(p) if p else None for p in problems]
    for k, index in enumerate(fitted):
        cu, cv, radius, sigma, contrast = x_fit[k, :5]
        # An ellipse's mean radius; from e = 1 on, P is no longer positive definite and
        # the edge no ellipse.
        e = math.hypot(*x_fit[k, 8:]) if ellipses else 0.0
        if e < 1:
            radius /= (1 - e * e) ** 0.25
        if (not converged[k] or e >= 1 or abs(sigma) > radius or radius <= 0
                or math.hypot(cu - centres[index, 0], cv - centres[index, 1])
                > 0.5 * radius0[index]):
            results[index] = DetectionError('circle fit did not converge')
        elif not determined[k]:
            results[index] = DetectionError(DEGENERATE_FIT)
        else:
            # Scalars by math, not numpy: numpy's call on a scalar costs 5 us a Mark.
            quality = min(max(1 - math.sqrt(costs[k] / counts[k]) / abs(contrast), 0.0), 1.0)
            results[index] = Mark('circle', float(cu), float(cv), covariances[k], float(radius),
                                  float(contrast), float(quality))
    return results


def _band_problem(crowded, size, clipped, no_contrast) -> str | None:
    """Why a dot's edge band cannot be fitted, or None."""
    if crowded and size < MIN_BAND_PX:
        return 'crowded: other blobs are nearer than it to most of its edge'
    if clipped > 0.01 * size:
        return 'saturated Mark (clipped intensities bias the centre)'
    if no_contrast:
        return 'no contrast between the Mark and its surroundings'
    return None


def _clear_masks(labels, windows, own):
    """edge_bands' ``clear`` and ``clear_first``: masks for the dots whose windows (k, 4)
    hold other blobs than their own (``own``: labels, k)."""
    masks, first, start = [], np.full(len(windows), -1), 0
    for k in np.flatnonzero(crowded_windows(labels, windows, own)):
        mask = _clear_of_neighbours(labels[slice(*windows[k, :2]), slice(*windows[k, 2:])],
                                    own[k])
        masks.append(mask.ravel())
        first[k], start = start, start + mask.size
    return (np.concatenate(masks) if masks else np.zeros(0, dtype=bool)), first


def _clear_of_neighbours(window, label):
    """Where a window of the frame's blob labels is nearer to blob ``label`` than to any
    other (boolean, window-shaped).

    A neighbour's blurred edge inside the band pulls the centre away from it: by 0.05 px
    in a dense grid seen at 50 degrees (14 px between dot centres). Halfway between two
    blobs, each one's edge has fallen to a few % of its contrast."""
    own = window == label
    others = (window != 0) & ~own
    # distanceTransform measures to the nearest zero pixel.
    to_own = cv2.distanceTransform((~own).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    to_others = cv2.distanceTransform((~others).view(np.uint8), cv2.DIST_L2,
                                      cv2.DIST_MASK_PRECISE)
    return to_own <= to_others
