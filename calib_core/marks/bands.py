"""The compiled (numba) work on a frame's blobs and dot candidates: each blob's moments,
depth and class, each dot's edge band and starting levels, one call for all of a frame's.
Per-blob numpy calls had cost 30-100 us a blob, mostly the interpreter's."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from calib_core.marks.config import (
    ELLIPSE_ABOVE_ASPECT, ELLIPSE_MIN_FILL, MAX_ASPECT, MAX_ELLIPSE_ASPECT, MIN_FILL)

# Reassociation lets the compiler vectorise a loop's sums (their order changes their last
# bits only); numpy's error model, a division without a check that would keep it scalar.
_SUMS = {'fastmath': {'reassoc', 'contract', 'nsz'}, 'error_model': 'numpy'}


@njit(cache=True)
def blob_statistics(labels, boxes, seeds, flat, dark, box_class):
    """Per blob (its bounding box and one pixel of it, see segment): its label, its
    moments and how far it stands out of the flattened frame; for a blob whose box
    decides its class (``box_class``, see box_classes), its label, its box's area and
    centre and zeros: a plate's blob in its surround had cost 0.3 ms a frame, summed
    over the frame.

    Returns
    -------
    statistics : ndarray, shape (k, 8)
        The label; the area (px^2); the centroid (px, in the box); the second central
        moments uu, uv, vv (px^2, with the pixel's own 1/12 px^2 added), which
        blob_classes and segmentation's moment_shapes and moment_overlap take; and the
        depth: how far the blob's extreme in ``flat`` (uint8) lies from the median of a
        2 px ring around its box (smoothed, scaled units).
    """
    height, width = labels.shape
    statistics = np.zeros((len(boxes), 8))
    counts = np.zeros(256, dtype=np.int64)
    for k in range(len(boxes)):
        x0, y0, w, h = boxes[k]
        label = labels[seeds[k, 1], seeds[k, 0]]
        if box_class[k] != BY_SHAPE:
            statistics[k, 0], statistics[k, 1] = label, w * h
            statistics[k, 2], statistics[k, 3] = (w - 1) / 2.0, (h - 1) / 2.0
            continue
        area, su, sv, suu, suv, svv = _label_moments(labels, x0, y0, w, h, label)
        cu, cv = su / area, sv / area
        statistics[k, 0], statistics[k, 1], statistics[k, 2], statistics[k, 3] = (
            label, area, cu, cv)
        statistics[k, 4] = suu / area - cu * cu + 1.0 / 12.0
        statistics[k, 5] = suv / area - cu * cv
        statistics[k, 6] = svv / area - cv * cv + 1.0 / 12.0
        r0, r1 = max(y0 - 2, 0), min(y0 + h + 2, height)
        c0, c1 = max(x0 - 2, 0), min(x0 + w + 2, width)
        counts[:] = 0
        region = flat[r0:r1, c0:c1]
        extreme = region.min() if dark else region.max()
        # The ring: the outermost rows and columns (corners in both).
        for col in range(c0, c1):
            counts[flat[r0, col]] += 1
            counts[flat[r1 - 1, col]] += 1
        for row in range(r0, r1):
            counts[flat[row, c0]] += 1
            counts[flat[row, c1 - 1]] += 1
        # The ring's upper median, from its histogram.
        middle, seen, level = (np.sum(counts) // 2), 0, 0
        for level in range(256):
            seen += counts[level]
            if seen > middle:
                break
        statistics[k, 7] = level - extreme if dark else extreme - level
    return statistics


# Blob classes (blob_classes): a noise speck, too large, clipped at the frame's border,
# ambiguous, a circle, shaped like an ellipse (a dot seen at an angle where its pixels fill
# its moments' ellipse), a cross; and (box_classes) one its pixels decide.
SPECK, TOO_LARGE, CLIPPED, AMBIGUOUS, CIRCLE, ELLIPSE_SHAPED, CROSS = range(7)
BY_SHAPE = -1


@njit(cache=True)
def box_classes(boxes, height, width, min_half, max_half, margin):
    """Each blob's class as its bounding box (k, 4: x0, y0, width, height; px) in a frame
    ``height`` x ``width`` (px) decides it: a speck under ``min_half`` (px, half the box's
    longer side), too large over ``max_half``, clipped within ``margin`` (px) of the
    border; else BY_SHAPE (its pixels decide, see blob_classes)."""
    classes = np.empty(len(boxes), dtype=np.int64)
    for k in range(len(boxes)):
        x0, y0, w, h = boxes[k]
        half = max(w, h) / 2.0
        if half < min_half:
            classes[k] = SPECK
        elif half > max_half:
            classes[k] = TOO_LARGE
        elif x0 < margin or y0 < margin or x0 + w > width - margin or y0 + h > height - margin:
            classes[k] = CLIPPED
        else:
            classes[k] = BY_SHAPE
    return classes


@njit(cache=True)
def blob_classes(boxes, statistics, box_class):
    """Each blob's class by its bounding box (k, 4: x0, y0, width, height; px), its row
    of blob_statistics and its box_classes class: where the box does not decide it, a
    speck under 4 px^2, then by its shape. A circle fills over 0.62 of its box, is nearly
    square and its moments nearly isotropic; an ellipse-shaped blob fills enough for an
    ellipse up to MAX_ELLIPSE_ASPECT; a cross is nearly square and fills MIN_FILL to
    0.6.

    Returns
    -------
    classes : ndarray of int, shape (k,)
    cross_shaped : ndarray of bool, shape (k,)
        Whether the blob has a cross's aspect and fill (the class of an ellipse-shaped
        blob whose pixels do not fill its moments' ellipse: CROSS, else AMBIGUOUS).
    shape : ndarray, shape (k, 3)
        Half the box's longer side (px), the box's aspect and the blob's fill of it.
    """
    classes = np.empty(len(boxes), dtype=np.int64)
    cross_shaped = np.empty(len(boxes), dtype=np.bool_)
    shape = np.empty((len(boxes), 3))
    for k in range(len(boxes)):
        x0, y0, w, h = boxes[k]
        area, uu, uv, vv = statistics[k, 1], statistics[k, 4], statistics[k, 5], statistics[k, 6]
        half, aspect, fill = max(w, h) / 2.0, max(w, h) / max(min(w, h), 1), area / (w * h)
        shape[k, 0], shape[k, 1], shape[k, 2] = half, aspect, fill
        cross_shaped[k] = aspect < MAX_ASPECT and MIN_FILL < fill < 0.6
        if box_class[k] != BY_SHAPE:
            classes[k] = box_class[k]
            continue
        # The axis ratio of the moments' ellipse, from its eigenvalues' contrast e.
        e = math.hypot(uu - vv, 2 * uv) / (uu + vv)
        moment_aspect = math.sqrt((1 + e) / max(1 - e, 1e-12))
        if area < 4:
            classes[k] = SPECK
        elif fill > 0.62 and aspect < MAX_ASPECT and moment_aspect < ELLIPSE_ABOVE_ASPECT:
            classes[k] = CIRCLE
        elif fill > ELLIPSE_MIN_FILL and moment_aspect <= MAX_ELLIPSE_ASPECT:
            classes[k] = ELLIPSE_SHAPED
        elif cross_shaped[k]:
            classes[k] = CROSS
        else:
            classes[k] = AMBIGUOUS
    return classes, cross_shaped, shape


@njit(cache=True)
def mark_shaped_count(boxes, areas, height, width, min_half, max_half, margin):
    """How many blobs, by their bounding boxes (k, 4: x0, y0, width, height; px) and
    areas (k,; px^2), in a frame ``height`` x ``width`` (px), have half the box's longer
    side within [min_half, max_half] (px), a box's aspect under MAX_ELLIPSE_ASPECT (a dot
    seen at an angle's too) and a fill of it over MIN_FILL, clear of ``margin`` (px) from
    the border. In numpy its dozen calls on a few blobs cost 10 us."""
    count = 0
    for k in range(len(boxes)):
        x0, y0, w, h = boxes[k]
        longer, shorter = max(w, h), min(w, h)
        count += (x0 >= margin and y0 >= margin and x0 + w <= width - margin
                  and y0 + h <= height - margin and min_half <= longer / 2.0 <= max_half
                  and longer < MAX_ELLIPSE_ASPECT * shorter and areas[k] / (w * h) > MIN_FILL)
    return count


@njit(cache=True, **_SUMS)
def _label_moments(labels, x0, y0, w, h, label):
    """The count and the sums of col, row, col^2, col row and row^2 (px, in the box) of
    the pixels of ``label`` in the box x0, y0, w, h of ``labels``: without branches, so
    that the compiler vectorises the rows."""
    area = su = sv = suu = suv = svv = 0.0
    for row in range(h):
        row_area = row_u = row_uu = 0.0
        for col in range(w):
            hit = 1.0 if labels[y0 + row, x0 + col] == label else 0.0
            row_area += hit
            row_u += hit * col
            row_uu += hit * col * col
        area += row_area
        su += row_u
        sv += row_area * row
        suu += row_uu
        suv += row_u * row
        svv += row_area * row * row
    return area, su, sv, suu, suv, svv


@njit(cache=True, nogil=True)
def edge_bands_range(pixels, windows, centres, radii, shapes, reaches, clear, clear_first,
                     dots, starts, u, v, z, distance, spans, flat):
    """The edge bands of the dots of indices ``dots``: for dot k, the pixels of its
    window (rows r0:r1, columns c0:c1) within ``reaches[k]`` (px) of the edge of
    dot_edge_model's ellipse of its radius (px) and shape (a, b) at its centre (u, v;
    px), by Sampson's distance, and where its ``clear`` mask holds; and the moments of
    the window's other clear pixels, outside the band and inside it, where the dot's
    model is flat: they tell the illumination gradient apart from a shift of the centre
    at the cost of a few sums. Without the GIL: each dot writes only its own rows and
    its band from ``starts[k]`` on, so two threads can take the dots in two halves.

    The norm's gradient is between sqrt(1 - e) and sqrt(1 + e) long (e = |(a, b)|),
    which bounds the band in squared norms, so the distance is taken only near the edge.

    Parameters
    ----------
    pixels : ndarray, shape (H, W)
    windows : ndarray of int, shape (k, 4)
        r0, r1, c0, c1 per dot.
    centres : ndarray, shape (k, 2)
        Also each dot's reference point of the flat moments.
    radii : ndarray, shape (k,)
    shapes : ndarray, shape (k, 2)
    reaches : ndarray, shape (k,)
    clear : ndarray of bool, shape (c,)
        The masks of the dots that have one, each window-shaped and flattened, one after
        another.
    clear_first : ndarray of int, shape (k,)
        Where dot k's mask begins in ``clear``; -1 for none (every pixel is clear).
    dots : ndarray of int
    starts : ndarray of int, shape (k,)
        Where dot k's band may begin in u, v, z and distance: room for its window's
        pixels from there on.

    Outputs
    -------
    u, v, z, distance : ndarray, shape (n,)
        The bands' pixels (px, in the frame), intensities and signed distances from the
        edge (px, negative inside), row by row.
    spans : ndarray of int, shape (k, 2)
        Dot k's band is ``spans[k, 0]:spans[k, 1]`` of them.
    flat : ndarray, shape (k, 2, 10), zeros on entry
        Per dot, of its clear pixels beyond the band outside the edge ([k, 0]) and inside
        it ([k, 1]), with (eu, ev) their offsets from the centre (px) and z their
        intensities: the count and the sums of eu, ev, eu^2, eu ev, ev^2, z, z eu, z ev
        and z^2.
    """
    for k in dots:
        r0, r1, c0, c1 = windows[k]
        count = starts[k]
        a, b = shapes[k]
        radius, first, reach = radii[k], clear_first[k], reaches[k]
        slack = reach * math.sqrt(1.0 + math.hypot(a, b))
        inner = (radius - slack) ** 2 if radius > slack else -1.0
        outer = (radius + slack) ** 2
        spans[k, 0] = count
        cu = centres[k, 0]
        for row in range(r0, r1):
            dv = row - centres[k, 1]
            # Without a mask, the columns certainly beyond the outer bound or within the
            # inner one (the row's roots, a pixel to spare) are flat, and summed as runs;
            # the others are taken one by one. Only for dots wider than twice the band's
            # reach: on smaller ones the window is mostly band, and the roots cost more
            # than they save (trial: 5-10 px dots 5-25 % slower; 20 px dots 1.25x and
            # 40 px 1.8x faster).
            low, high, inside_low, inside_high = c0, c1, c0, c0
            if first < 0 and radius > 2.0 * slack:
                low, high = _row_span(a, b, dv, outer, cu, c0, c1, 1.0)
                inside_low, inside_high = _row_span(a, b, dv, inner, cu, low, high, -1.0)
                _add_flat_run(pixels, row, c0, low, cu, dv, flat[k, 0])
                _add_flat_run(pixels, row, high, c1, cu, dv, flat[k, 0])
                _add_flat_run(pixels, row, inside_low, inside_high, cu, dv, flat[k, 1])
            for col in range(low, high):
                if inside_low <= col < inside_high:
                    continue
                if first >= 0 and not clear[first + (row - r0) * (c1 - c0) + col - c0]:
                    continue
                du = col - cu
                w_u, w_v = (1.0 + a) * du + b * dv, b * du + (1.0 - a) * dv
                norm2 = du * w_u + dv * w_v
                value = float(pixels[row, col])
                gap = reach if norm2 >= outer else -reach
                if inner < norm2 < outer:
                    norm = math.sqrt(max(norm2, 1e-18))
                    gap = (norm - radius) * norm / math.sqrt(max(w_u * w_u + w_v * w_v, 1e-18))
                    if abs(gap) < reach:
                        u[count], v[count], z[count], distance[count] = col, row, value, gap
                        count += 1
                        continue
                _add_flat(flat[k, 0] if gap > 0 else flat[k, 1], du, dv, value)
        spans[k, 1] = count


@njit(cache=True, inline='always')
def _add_flat(moments, du, dv, value):
    """Adds one pixel, ``du``, ``dv`` px from the dot's centre, of intensity ``value``, to
    its flat ``moments`` (see edge_bands_range)."""
    moments[0] += 1.0
    moments[1] += du
    moments[2] += dv
    moments[3] += du * du
    moments[4] += du * dv
    moments[5] += dv * dv
    moments[6] += value
    moments[7] += value * du
    moments[8] += value * dv
    moments[9] += value * value


@njit(cache=True)
def narrow_band(k, reach, centres, u, v, z, distance, spans, flat):
    """Narrows dot k's edge band (see edge_bands_range) to the pixels within ``reach``
    (px) of its edge: the others join its flat pixels' moments, outside the edge or
    inside it, and the band is compacted in place."""
    count = spans[k, 0]
    cu, cv = centres[k, 0], centres[k, 1]
    for i in range(spans[k, 0], spans[k, 1]):
        if abs(distance[i]) < reach:
            u[count], v[count], z[count], distance[count] = u[i], v[i], z[i], distance[i]
            count += 1
        else:
            _add_flat(flat[k, 0] if distance[i] > 0 else flat[k, 1], u[i] - cu, v[i] - cv,
                      z[i])
    spans[k, 1] = count


@njit(cache=True)
def _row_span(a, b, dv, bound, cu, c0, c1, spare):
    """The columns [low, high) within [c0, c1) of a row ``dv`` (px from the centre) where
    ``d^T P d < bound`` (see edge_bands_range) could hold, widened by a pixel (``spare`` 1), or
    where it certainly holds, narrowed by one (``spare`` -1); ``cu``: the centre's
    column (px). An empty span is (c0, c0)."""
    # d^T P d = (1 + a) du^2 + 2 b dv du + (1 - a) dv^2, with 1 + a > 0.
    half_b = b * dv
    discriminant = half_b * half_b - (1.0 + a) * ((1.0 - a) * dv * dv - bound)
    if discriminant <= 0.0:
        return c0, c0
    root = math.sqrt(discriminant)
    low = math.floor(cu + (-half_b - root) / (1.0 + a) - spare) + 1
    high = math.ceil(cu + (-half_b + root) / (1.0 + a) + spare)
    low, high = min(max(low, c0), c1), min(max(high, c0), c1)
    return (low, high) if low < high else (c0, c0)


@njit(cache=True, **_SUMS)
def _add_flat_run(pixels, row, start, end, cu, dv, moments):
    """Adds the pixels of ``row``, columns [start, end), to a dot's flat ``moments`` (see
    edge_bands_range), with ``cu`` its centre's column and ``dv`` the row's offset (px). The
    row's offset is one number, so six sums serve the ten."""
    count = s_u = s_uu = s_z = s_zu = s_zz = 0.0
    for col in range(start, end):
        du = col - cu
        value = float(pixels[row, col])
        count += 1.0
        s_u += du
        s_uu += du * du
        s_z += value
        s_zu += value * du
        s_zz += value * value
    moments[0] += count
    moments[1] += s_u
    moments[2] += count * dv
    moments[3] += s_uu
    moments[4] += s_u * dv
    moments[5] += count * dv * dv
    moments[6] += s_z
    moments[7] += s_zu
    moments[8] += s_z * dv
    moments[9] += s_zz


@njit(cache=True)
def crowded_windows(labels, windows, own, boxes, own_box):
    """Whether each window (k, 4: r0, r1, c0, c1) of the frame's blob ``labels`` holds a
    blob other than its own (``own``, k). Only a window that another blob's bounding box
    (``boxes``, b, 4: x0, y0, width, height, px; the window's own is ``boxes[own_box]``)
    overlaps is searched."""
    crowded = np.zeros(len(windows), dtype=np.bool_)
    for k in range(len(windows)):
        r0, r1, c0, c1 = windows[k]
        overlapped = False
        for j in range(len(boxes)):
            x0, y0, w, h = boxes[j]
            if j != own_box[k] and x0 < c1 and x0 + w > c0 and y0 < r1 and y0 + h > r0:
                overlapped = True
                break
        if not overlapped:
            continue
        for row in range(r0, r1):
            # A row's count without branches, which the compiler vectorises.
            others = 0
            for col in range(c0, c1):
                label = labels[row, col]
                others += (label != 0) & (label != own[k])
            if others:
                crowded[k] = True
                break
    return crowded


@njit(cache=True, **_SUMS)
def dot_levels(z, distance, dark, full):
    """Starting intensities of a dot from its edge band's intensities ``z`` and signed
    distances from the edge (see edge_bands_range). Means, not medians: a start only has to lie
    in the fit's basin, and a median (quickselect on noisy values) cost 8 us a dot, more
    than the rest of the start.

    Returns
    -------
    background, level, fraction_sum, transition, clipped : float
        The background (the mean outside 1.5 px of the edge), the Mark's level (the mean
        inside 1.5 px, or the band's extreme: its minimum if ``dark``), the sum of the
        band's fractions of the way from background to Mark, how many of those fractions
        lie between 16 and 84 % (both 0 where the two levels are equal, or the band
        empty), and how many pixels are at ``full`` scale or above (clipped).
    """
    if not z.size:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    # Sums and counts by selection, not branches, so that the compiler vectorises the
    # two passes.
    outside = in_mark = 0.0
    outside_sum = in_mark_sum = 0.0
    extreme = np.inf if dark else -np.inf
    for i in range(z.size):
        beyond, within = distance[i] > 1.5, distance[i] < -1.5
        outside += beyond
        outside_sum += z[i] if beyond else 0.0
        in_mark += within
        in_mark_sum += z[i] if within else 0.0
        extreme = min(extreme, z[i]) if dark else max(extreme, z[i])
    background = outside_sum / outside if outside else np.mean(z)
    level = in_mark_sum / in_mark if in_mark else extreme
    span = level - background
    total = transition = clipped = 0.0
    for i in range(z.size):
        fraction = (z[i] - background) / span  # not kept where the span is 0
        total += fraction
        transition += (fraction > 0.16) & (fraction < 0.84)
        clipped += z[i] >= full
    if span == 0.0:
        return background, level, 0.0, 0.0, clipped
    return background, level, total, transition, clipped
