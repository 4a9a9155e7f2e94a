"""Sub-pixel fit of circular dots (and dots seen at an angle, as ellipses): each dot
candidate's window and the pixels in it clear of other blobs, then the edge bands,
starting values and fits of all of a frame's, in one compiled run (dot_run)."""
from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

from calib_core.errors import DetectionError
from calib_core.marks.bands import crowded_windows
from calib_core.marks.config import (
    EDGE_BAND_PX, LOCAL_BAND_PX, NARROW_BAND_SIGMAS, NARROW_BAND_SLACK_PX,
    NEIGHBOUR_CLEARANCE_PX, WIDE_BAND_MAX_PX, Mark)
from calib_core.marks.dot_run import REASONS, dot_windows, fit_dot_windows
from calib_core.marks.intensity import PIXEL_APERTURE_VARIANCE


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
                full: float | None, box_below: float,
                noise: float) -> list[Mark | DetectionError]:
    """The dots' fits, in the order of ``candidates``: a Mark, or why there is none.

    ``labels`` and ``blob_boxes``: the frame's segmentation and its blobs' bounding boxes
    (b, 4: x0, y0, width, height; px; the candidates' are ``blob_boxes[candidates.index]``),
    to keep other blobs out of each dot's band;
    ``full``: the frame's full scale where some pixels reach it, else None;
    ``box_below``: the starting blur (px) below which a dot's model sees the pixel's
    box as it is (DetectorConfig.box_aperture_below_blur_px);
    ``noise``: the frame's noise sigma (intensity; see dot_run.fit_dot_windows)."""
    results: list = [None] * len(candidates.index)
    for ellipses in (False, True):
        group = np.flatnonzero(candidates.ellipse == ellipses)
        if group.size:
            # Most frames hold one kind only: then the candidates are the group.
            members = candidates if group.size == len(results) else candidates.subset(group)
            fits = _fit_group(pixels, members, ellipses, labels, blob_boxes, polarity, full,
                              box_below, noise)
            for index, fit in zip(group.tolist(), fits):
                results[index] = fit
    return results


def _fit_group(pixels, candidates, ellipses, labels, blob_boxes, polarity, full,
               box_below, noise) -> list[Mark | DetectionError]:
    """The fits of dots of one model: all disks, or all ellipses (``ellipses``)."""
    shapes = candidates.shape.astype(float)
    settings = (ellipses, labels, blob_boxes, polarity == 'dark',
                np.inf if full is None else float(full), box_below, float(noise))
    fits = _fit_dots(pixels, candidates, candidates.centroid.astype(float), shapes,
                     np.full(len(shapes), EDGE_BAND_PX), *settings)
    status, x, band_alone = fits[0], fits[1], fits[5]
    # A dot fitted on its band alone whose edge the band does not hold (defocused) again
    # on a band that does, from its fit, with the flat pixels beyond; where that fit
    # fails, the first stands. (A dot whose start read its edge as narrower had them:
    # at 1.5 px blur, its band holding 3.9 sigma, all of its pixels gain it nothing.)
    edge_sigma = np.sqrt(x[:, 3] ** 2 + PIXEL_APERTURE_VARIANCE)
    wide = np.flatnonzero((status == 0) & band_alone
                          & (NARROW_BAND_SIGMAS * edge_sigma > EDGE_BAND_PX))
    if wide.size:
        reaches = np.minimum(NARROW_BAND_SIGMAS * edge_sigma[wide] + NARROW_BAND_SLACK_PX,
                             WIDE_BAND_MAX_PX)
        again = _fit_dots(pixels, candidates.subset(wide), x[wide, :2].copy(),
                          x[wide, 8:10].copy() if ellipses else shapes[wide], reaches, *settings,
                          start=x[wide])
        taken = again[0] == 0
        for first_fit, wide_fit in zip(fits, again):
            first_fit[wide[taken]] = wide_fit[taken]
    # A dot that took the local fit on the plain band, fitted locally again on a wider
    # band and window (LOCAL_BAND_PX), from that fit; where that fails, the first stands.
    local = np.flatnonzero((status == 0) & fits[6])
    local = local[~np.isin(local, wide)] if wide.size else local
    if local.size:
        again = _fit_dots(pixels, candidates.subset(local), x[local, :2].copy(),
                          x[local, 8:10].copy() if ellipses else shapes[local],
                          np.full(local.size, LOCAL_BAND_PX), *settings, start=x[local],
                          local_only=True)
        taken = (again[0] == 0) & again[6]
        for first_fit, local_pass in zip(fits, again):
            first_fit[local[taken]] = local_pass[taken]
    status, x, covariance, radius, quality = fits[:5]
    # Python floats, not numpy scalars: numpy's call on a scalar costs 5 us a Mark.
    return [Mark('circle', cu, cv, cov, size, contrast, fit_quality) if not code
            else DetectionError(REASONS[code - 1])
            for code, cu, cv, cov, size, contrast, fit_quality in zip(
                status.tolist(), x[:, 0].tolist(), x[:, 1].tolist(), covariance,
                radius.tolist(), x[:, 4].tolist(), quality.tolist())]


def _fit_dots(pixels, candidates, centres, shapes, reaches, ellipses, labels, blob_boxes, dark,
              full, box_below, noise, start=None, local_only=False):
    """dot_run.fit_dot_windows' fits of ``candidates`` about their ``centres`` (m, 2; px) and
    ``shapes`` (m, 2), on edge bands of ``reaches`` (m,; px), clear of other blobs; from
    ``start`` (m, p), an earlier fit, where given; local fits only with ``local_only``."""
    geometry = dot_windows(candidates.box, candidates.area.astype(float), shapes,
                           *pixels.shape, reaches)
    clear, clear_first = _clear_masks(labels, blob_boxes, geometry[3], candidates.label,
                                      candidates.index, reaches)
    # The model is evaluated on the edge band; the flat pixels beyond it enter the fit by
    # their moments: they pin the illumination gradient, which the band alone confuses
    # with a shift of the centre (10 % of the centre's error on 20-40 px dots).
    return fit_dot_windows(pixels, geometry, centres, shapes, ellipses, clear, clear_first,
                           dark, full, box_below, noise, reaches, start, local_only)


def _clear_masks(labels, blob_boxes, windows, own, own_box, reaches):
    """bands.edge_bands_range's ``clear`` and ``clear_first``: masks for the dots whose
    windows (k, 4) hold other blobs than their own (``own``: labels, k; ``own_box``: their
    indices into the frame's ``blob_boxes``), or have them within their band's reach
    (``reaches``, k; px) outside.

    A blob's mask ends where its edge is halfway: its blurred edge reaches up to the
    band's width beyond (the model is flat beyond the band only for edges it holds to 4
    sigma). A neighbour 1 px outside a dot's window had put its edge among the dot's flat
    pixels and moved the dot by twice its sigma."""
    r0, r1, c0, c1 = windows.T
    pad, (height, width) = np.ceil(reaches).astype(np.int64)[:, None], labels.shape
    around = np.clip(windows + pad * (-1, 1, -1, 1), 0, (height, height, width, width))
    masks, first, start = [], np.full(len(windows), -1), 0
    for k in np.flatnonzero(crowded_windows(labels, around, own, blob_boxes, own_box)):
        top, bottom, left, right = around[k]
        mask = _clear_of_neighbours(labels[top:bottom, left:right], own[k])
        mask = mask[r0[k] - top:r1[k] - top, c0[k] - left:c1[k] - left]
        masks.append(mask.ravel())
        first[k], start = start, start + mask.size
    return (np.concatenate(masks) if masks else np.zeros(0, dtype=bool)), first


def _clear_of_neighbours(window, label):
    """Where a window of the frame's blob labels is nearer to blob ``label`` than to any
    other, and at least NEIGHBOUR_CLEARANCE_PX from all others (boolean, window-shaped).

    A neighbour's blurred edge inside the band pulls the centre away from it: by 0.05 px
    in a dense grid seen at 50 degrees (14 px between dot centres). Halfway between two
    blobs 2-4 px apart, the other's edge still holds a few % of its contrast: kept, it
    moved rendered dots by 1.25 times their reported sigma (RMS), 1.02 with the
    clearance."""
    own = window == label
    others = (window != 0) & ~own
    # distanceTransform measures to the nearest zero pixel. Its precise distances are the
    # roots of whole squared distances, but their float32 roots differ in the last bit
    # from one process to the next (0.0003 px in centres of the hexagonal-grid photos):
    # compared as whole squares, a pixel halfway between two blobs is always its own.
    to_own = cv2.distanceTransform((~own).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    to_others = np.rint(np.square(cv2.distanceTransform(
        (~others).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE), dtype=np.float64))
    return ((np.rint(np.square(to_own, dtype=np.float64)) <= to_others)
            & (to_others >= NEIGHBOUR_CLEARANCE_PX ** 2))
