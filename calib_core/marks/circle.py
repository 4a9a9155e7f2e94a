"""Sub-pixel fit of circular dots (and dots seen at an angle, as ellipses): the edge bands
and starting values of all of a frame's dot candidates, then their fits, each in one
compiled run (dot_fit)."""
from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

from calib_core.errors import DetectionError
from calib_core.marks.config import (
    DEGENERATE_FIT, EDGE_BAND_PX, FLAT_MISFIT, MIN_BAND_PX, Mark)
from calib_core.marks.bands import band_levels, crowded_windows, edge_bands
from calib_core.marks.dot_fit import fit_dots, flat_costs
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE
from calib_core.marks.pixels import centre_covariances, clipped_window


@dataclass(frozen=True)
class DotCandidates:
    """A frame's blobs taken for dots, as arrays of m rows: their indices among the
    frame's blobs, bounding boxes (x0, y0, width, height; px), areas (px^2) and centroids
    (u, v; px); the shape (a, b) of their moments' ellipse (see dot_edge_model), where
    ``ellipse`` says they are fitted as ellipses (dots seen at an angle), else 0; and
    their labels in the frame's segmentation."""

    index: np.ndarray
    box: np.ndarray
    area: np.ndarray
    centroid: np.ndarray
    shape: np.ndarray
    ellipse: np.ndarray
    label: np.ndarray

    def subset(self, rows) -> DotCandidates:
        return DotCandidates(*(getattr(self, f.name)[rows] for f in fields(self)))


def fit_circles(pixels, candidates: DotCandidates, labels, blob_boxes, polarity: str,
                full: float | None, box_below: float) -> list[Mark | DetectionError]:
    """The dots' fits, in the order of ``candidates``: a Mark, or why there is none.

    ``labels`` and ``blob_boxes``: the frame's segmentation and its blobs' bounding boxes
    (b, 4: x0, y0, width, height; px; the candidates' are ``blob_boxes[candidates.index]``),
    to keep other blobs out of each dot's band;
    ``full``: the frame's full scale where some pixels reach it, else None;
    ``box_below``: the starting blur (px) below which a dot's model sees the pixel's
    box as it is (DetectorConfig.box_aperture_below_blur_px)."""
    results: list = [None] * len(candidates.index)
    for ellipses in (False, True):
        group = np.flatnonzero(candidates.ellipse == ellipses)
        if group.size:
            fits = _fit_group(pixels, candidates.subset(group), ellipses, labels, blob_boxes,
                              polarity, full, box_below)
            for index, fit in zip(group.tolist(), fits):
                results[index] = fit
    return results


def _fit_group(pixels, candidates, ellipses, labels, blob_boxes, polarity, full,
               box_below) -> list[Mark | DetectionError]:
    """The fits of dots of one model: all disks, or all ellipses (``ellipses``)."""
    boxes = candidates.box
    centres = candidates.centroid.astype(float)
    radius0 = np.sqrt(candidates.area / np.pi)
    shapes = candidates.shape.astype(float)
    # The ellipse's semi-axes are scale / sqrt(1 +- e), its mean radius radius0, and in
    # dot_edge_model's norm its radius is radius0 * scale.
    e = np.hypot(shapes[:, 0], shapes[:, 1])
    scale = (1 - e * e) ** 0.25
    semi_axes = (radius0 * scale)[:, None] / np.sqrt(1 + np.outer(e, [1.0, -1.0]))
    pad = np.ceil(4 + 0.15 * semi_axes[:, 1]).astype(int)
    windows = np.column_stack(clipped_window(pixels.shape, *boxes.T, pad))
    own = candidates.label
    clear, clear_first = _clear_masks(labels, blob_boxes, windows, own, candidates.index)
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
    even_light = np.zeros((len(boxes), 2))  # the starting illumination gradient
    x = np.column_stack([centres, radius_init * scale, blur0, level - background, background,
                         even_light] + ([shapes] if ellipses else []))
    problems = _band_problems(clear_first >= 0, band, clipped, level == background)
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
    cu, cv, radius, sigma, contrast = x_fit[:, :5].T
    # An ellipse's mean radius; from e = 1 on, P is no longer positive definite and the
    # edge no ellipse.
    e = np.hypot(x_fit[:, 8], x_fit[:, 9]) if ellipses else np.zeros(len(fitted))
    radius = np.where(e < 1, radius / np.sqrt(np.sqrt(np.abs(1 - e * e))), radius)
    with np.errstate(invalid='ignore'):
        failed = (~converged | (e >= 1) | (np.abs(sigma) > radius) | (radius <= 0)
                  | (np.hypot(cu - centres[fitted, 0], cv - centres[fitted, 1])
                     > 0.5 * radius0[fitted]))
        quality = np.clip(1 - np.sqrt(costs / counts) / np.abs(contrast), 0.0, 1.0)
    results: list[Mark | DetectionError] = [DetectionError(p) if p else None for p in problems]
    # Python floats, not numpy scalars: numpy's call on a scalar costs 5 us a Mark.
    marks = zip(cu.tolist(), cv.tolist(), covariances, radius.tolist(), contrast.tolist(),
                quality.tolist())
    for index, fit_failed, fit_determined, mark in zip(fitted.tolist(), failed.tolist(),
                                                       determined.tolist(), marks):
        if fit_failed:
            results[index] = DetectionError('circle fit did not converge')
        elif not fit_determined:
            results[index] = DetectionError(DEGENERATE_FIT)
        else:
            results[index] = Mark('circle', *mark)
    return results


def _band_problems(crowded, size, clipped, no_contrast) -> list[str | None]:
    """Why each dot's edge band cannot be fitted, or None (arrays of its crowding, band
    size, clipped pixels and whether it shows no contrast)."""
    why = np.select([crowded & (size < MIN_BAND_PX), clipped > 0.01 * size, no_contrast],
                    ['crowded: other blobs are nearer than it to most of its edge',
                     'saturated Mark (clipped intensities bias the centre)',
                     'no contrast between the Mark and its surroundings'], '')
    return [reason or None for reason in why.tolist()]


def _clear_masks(labels, blob_boxes, windows, own, own_box):
    """edge_bands' ``clear`` and ``clear_first``: masks for the dots whose windows (k, 4)
    hold other blobs than their own (``own``: labels, k; ``own_box``: their indices into
    the frame's ``blob_boxes``)."""
    masks, first, start = [], np.full(len(windows), -1), 0
    for k in np.flatnonzero(crowded_windows(labels, windows, own, blob_boxes, own_box)):
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
    # distanceTransform measures to the nearest zero pixel. Its precise distances are the
    # roots of whole squared distances, but their float32 roots differ in the last bit
    # from one process to the next (0.0003 px in centres of the hexagonal-grid photos):
    # compared as whole squares, a pixel halfway between two blobs is always its own.
    to_own = cv2.distanceTransform((~own).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    to_others = cv2.distanceTransform((~others).view(np.uint8), cv2.DIST_L2,
                                      cv2.DIST_MASK_PRECISE)
    return (np.rint(np.square(to_own, dtype=np.float64))
            <= np.rint(np.square(to_others, dtype=np.float64)))
