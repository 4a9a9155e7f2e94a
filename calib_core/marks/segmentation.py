"""Candidate Marks in a frame: the frame is smoothed, a robust quadratic illumination
surface is taken off, and the connected components below (above) a threshold are the
dark (bright) candidates; the threshold is Otsu's unless that splits the background's
noise. Each candidate's shape is summarised by its second moments."""
from __future__ import annotations

import cv2
import numpy as np

from calib_core.marks.config import (
    MAX_GREY_LEVEL_SIGMAS, MIN_THRESHOLD_SIGMA, SCALING_OUTLIER_SHARE, SIZE_SLACK,
    SMOOTHING_NOISE_GAIN, STEP_MAX_BOUNDARY, STEP_MIN_SHARE, STEP_SEPARATION, SURFACE_STEP_PX,
    TREND_BLOCK_PX, TREND_ITERATIONS)


def estimate_noise(image: np.ndarray) -> float:
    """Robust sigma of the pixel noise (image units) from horizontal pixel differences; 0
    for a frame one pixel wide.

    About 10000 differences (every k-th row) give sigma to about 1.3 % (the MAD's
    efficiency is 37 %), and keep the two medians cheap on full frames."""
    step = max(1, int(np.ceil(image.size / 10000)))
    rows = image[::step]
    if rows.shape[1] < 2:
        return 0.0
    if rows.dtype.kind in 'ui' and int(rows.max()) - int(rows.min()) < 1 << 16:
        # Integer pixels: both medians from histograms, compiled (numba loads with the
        # first frame).
        from calib_core.marks.noise import integer_difference_mad
        mad = integer_difference_mad(np.ascontiguousarray(rows))  # one compiled layout
    else:
        diff = np.diff(rows.astype(np.float64), axis=1).ravel()
        mad = np.median(np.abs(diff - np.median(diff)))
    return float(mad / 0.6745 / np.sqrt(2.0))


def scaling_range(image, low, high, noise):
    """The levels (image units) that segment maps to 0 and 255: the frame's ``low`` and
    ``high``, or, where one of 256 grey levels between them would span over
    MAX_GREY_LEVEL_SIGMAS of the ``noise`` (sigma, image units) and the range without
    SCALING_OUTLIER_SHARE of the pixels at each end is under half as wide, that range.

    Two hot pixels at 65535 in a 16-bit frame of 12-bit data put its dots' 100 DN of
    contrast within half a grey level, and no Mark was found; an 8-bit frame's grey
    level is never wider than its own."""
    if image.dtype == np.uint8 or (high - low) / 255.0 <= MAX_GREY_LEVEL_SIGMAS * noise:
        return low, high
    values = image.ravel()
    # Where a sample of about 10000 pixels already spans half of the range, few pixels do
    # not stretch it (a noise-free frame's Marks and background): the full sort is spared.
    sample = values[::max(values.size // 10000, 1)]
    if float(sample.max()) - float(sample.min()) >= 0.5 * (high - low):
        return low, high
    beyond = max(int(values.size * SCALING_OUTLIER_SHARE), 1)
    ends = [beyond, values.size - 1 - beyond]
    inner_low, inner_high = (float(level) for level in np.partition(values, ends)[ends])
    if inner_high <= inner_low or inner_high - inner_low >= 0.5 * (high - low):
        return low, high
    return inner_low, inner_high


def _flatten(smoothed, tolerance):
    """``smoothed`` (uint8) less a robust quadratic illumination surface, at 128 (uint8).

    The surface is fitted by least squares to block means of the frame, dropping blocks
    more than 3 robust sigma off it (the Marks, and in photos the scene around the plate),
    so a fall-off of light across the frame does not split the background in two at the
    threshold. Frames whose block means vary less than ``tolerance`` from their median
    to their 10th percentile, or to their 90th, are returned unchanged: the Marks darken
    (brighten) one tail of the blocks, uneven light spreads both, and an even background
    gains nothing from the fit (dense dots had it fitted in every frame: 0.3 ms); but for
    a shadow's edge across the frame, which may spread one tail only. Nor are frames
    whose block means fall in two classes like a plate and its surround (:func:`_step`,
    'inside'): a quadratic fitted across that step warps the plate. A frame with a
    shadow's edge across it (:func:`_step`, 'across') is taken over its local background
    (:func:`_over_local_background`): no quadratic takes up that step.

    The blocks are whole TREND_BLOCK_PX squares from the frame's top left corner; the
    last rows and columns of a frame whose sides are no multiples of it (under a block)
    are left out of the means, not the surface. cv2.resize's INTER_AREA, which shares
    them out in fractions, took 4.2 ms on a 1920 x 1080 frame (half of its detection),
    0.07 ms where the blocks tile the frame. A frame under three blocks a side is cut
    into three fractional ones by INTER_AREA."""
    # numba loads with the first frame
    from calib_core.marks.trend import robust_quadratic, tile_means
    height, width = smoothed.shape
    if min(height, width) >= 3 * TREND_BLOCK_PX:
        rows, cols = height // TREND_BLOCK_PX, width // TREND_BLOCK_PX
        means = tile_means(smoothed, TREND_BLOCK_PX).ravel()
        block_u = block_v = float(TREND_BLOCK_PX)
    else:
        rows, cols = max(height // TREND_BLOCK_PX, 3), max(width // TREND_BLOCK_PX, 3)
        means = cv2.resize(smoothed, (cols, rows), interpolation=cv2.INTER_AREA)
        means = means.ravel().astype(np.float64)
        block_u, block_v = width / cols, height / rows
    # The 10th, 50th and 90th percentiles, as order statistics (np.percentile costs 5x
    # more).
    tenths = [means.size // 10, means.size // 2, means.size - 1 - means.size // 10]
    low, middle, high = np.partition(means, tenths)[tenths]
    if max(middle - low, high - middle) < tolerance:
        return smoothed
    step = _step(means.reshape(rows, cols))
    if min(middle - low, high - middle) < tolerance and step != 'across':
        return smoothed     # one tail: Marks, or a shadow over less than half the frame
    if step == 'inside':
        return smoothed
    if step == 'across':
        return _over_local_background(smoothed)
    coef = robust_quadratic(means.reshape(rows, cols), width, height, block_u, block_v,
                            TREND_ITERATIONS)
    # The surface is evaluated every SURFACE_STEP_PX px and interpolated up: cv2.resize
    # puts the coarse sample j at full-frame px SURFACE_STEP_PX * j + (SURFACE_STEP_PX - 1) / 2.
    step = SURFACE_STEP_PX
    u = ((np.arange(-(-width // step)) * step + (step - 1) / 2) / width * 2 - 1).astype(np.float32)
    v = ((np.arange(-(-height // step)) * step + (step - 1) / 2) / height * 2 - 1).astype(np.float32)
    c0, cu, cv_, cuu, cuv, cvv = coef.astype(np.float32)
    coarse = np.add.outer(cv_ * v + cvv * v * v, c0 + cu * u + cuu * u * u) + cuv * np.outer(v, u)
    surface = cv2.resize(np.clip(coarse, 0, 255).astype(np.uint8),
                         (len(u) * step, len(v) * step), interpolation=cv2.INTER_LINEAR)
    return cv2.addWeighted(smoothed, 1.0, surface[:height, :width], -1.0, 128.0)


def _over_local_background(smoothed):
    """``smoothed`` (uint8) over its local background, at 128 (uint8): a shadow's edge
    across the frame is a step no quadratic takes up, and the half in shadow was one
    region whose own level its dots did not stand out of (its soft edge split off by
    Otsu's level). The background is the median of a window an eighth of the frame's
    shorter side wide, on a frame a quarter the size (1.3 ms at 640 x 480): it keeps a
    step and leaves out Marks of up to about half the window in radius (at 640 x 480 all
    8 dots of 28 px under a shadow's edge were found, 3 of 8 of 32 px). Over it, as light
    scales the plate and its Marks alike, a dot has the same level in the shadow as out
    of it."""
    height, width = smoothed.shape
    small = cv2.resize(smoothed, (max(width // 4, 1), max(height // 4, 1)),
                       interpolation=cv2.INTER_AREA)
    window = max(min(small.shape) // 8, 1) | 1
    # Grown by a pixel of the small frame: where the linear interpolation up crossed the
    # step, the lit side's level had dropped and the plate there had come out bright.
    background = cv2.dilate(cv2.medianBlur(small, window), np.ones((3, 3), np.uint8))
    background = cv2.resize(background, (width, height), interpolation=cv2.INTER_LINEAR)
    return cv2.divide(smoothed, np.maximum(background, 1), scale=128.0)


def _step(means) -> str | None:
    """Whether block ``means`` ((rows, cols), uint8 levels) fall in two classes apart like
    a plate and its surround (STEP_SEPARATION, STEP_MIN_SHARE, by Otsu's split of their
    histogram): 'inside' where one of them is clear of the frame's outer blocks (a plate
    inside the frame), 'across' where both reach them (a shadow's edge across the
    frame), else None."""
    flat = np.clip(np.asarray(means), 0, 255).astype(np.int64)
    counts = np.bincount(flat.ravel(), minlength=256)
    levels = np.arange(256, dtype=np.float64)
    total = float(counts.sum())
    share = np.cumsum(counts)[:-1] / total
    mass = np.cumsum(counts * levels)[:-1] / total
    mean = float(counts @ levels) / total
    variance = float(counts @ (levels - mean) ** 2) / total
    if variance <= 0:
        return None
    inside = (share > 0) & (share < 1)
    # Between-class variance of each split, over the total: Otsu's criterion.
    between = np.zeros_like(share)
    between[inside] = (mean * share[inside] - mass[inside]) ** 2 / (
        share[inside] * (1 - share[inside]))
    best = int(np.argmax(between))
    if not (between[best] / variance > STEP_SEPARATION
            and min(share[best], 1 - share[best]) >= STEP_MIN_SHARE):
        return None
    low = flat <= best
    ring = np.ones(low.shape, bool)
    ring[1:-1, 1:-1] = False
    if not low[ring].any() or low[ring].all():
        return 'inside'
    # A shadow is one piece or two: few neighbouring blocks differ in class (a straight
    # edge's share is a block in a row or column); blocks with and without the dots of
    # a grid scattered alike differ in half of the pairs.
    differ = (np.count_nonzero(low[1:] != low[:-1]) + np.count_nonzero(low[:, 1:] != low[:, :-1]))
    pairs = low[1:].size + low[:, 1:].size
    return 'across' if differ <= STEP_MAX_BOUNDARY * pairs else None


def flattened(image, noise_scaled):
    """The frame ``image`` scaled to 8 bits between its extremes (clipped to
    scaling_range's by the caller), smoothed and flattened (_flatten), with its histogram
    (256 bins) and the guard (grey levels) its levels keep from the background's noise
    (``noise_scaled``: the noise sigma in the scaled frame's grey levels); segment's
    input, which its tries at other levels share."""
    scaled = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    smoothed_noise = SMOOTHING_NOISE_GAIN * noise_scaled
    flat = _flatten(cv2.GaussianBlur(scaled, (5, 5), 1.0), smoothed_noise)
    histogram = cv2.calcHist([flat], [0], None, [256], [0, 256]).ravel()
    return flat, histogram, MIN_THRESHOLD_SIGMA * smoothed_noise


def segment(flat, histogram, guard, config, from_median=False):
    """Candidate Marks: the connected components of the thresholded, flattened frame
    (``flat``, ``histogram`` and ``guard`` as flattened gives them).

    Returns the polarity; the labels of the Marks' mask (int32, 8-connected); each
    blob's bounding box (k, 4: x, y, width, height, px) and one pixel of it (k, 2: u, v),
    from its outer contour; and the flattened frame (uint8). Labels and contours cost a
    fifth of connected components with statistics, which sum over every pixel of the
    frame; where no two blobs' boxes overlap, the labels are painted in the boxes
    (labels.py), a fifth of connected components' time. The threshold is Otsu's unless
    that splits the background's noise (see levels.mask_levels). ``auto`` polarity takes
    the class with more Mark-shaped blobs (_vote): the minority class is not the Marks
    when a dense dot grid and a dark table fill most of a photo. With ``from_median`` the
    levels lie between the frame's median and its extremes, not at Otsu's (see
    levels.mask_levels)."""
    from calib_core.marks.levels import mask_levels  # numba loads with the first frame
    levels = dict(zip(('dark', 'bright'), mask_levels(histogram, guard, from_median)))
    if config.polarity == 'auto':
        polarity, mask, (contours, boxes, _) = _vote(flat, histogram, levels, config, guard,
                                                     from_median)
    else:
        polarity = config.polarity
        mask = _mask(flat, levels[polarity], polarity)
        contours, boxes, _ = _regions_split(flat, histogram, mask, _blobs(mask), polarity,
                                            guard, config, from_median)
    from calib_core.marks.labels import boxes_overlap, paint_labels
    if boxes_overlap(boxes):
        labels = cv2.connectedComponents(mask, connectivity=8)[1]
    else:
        labels = np.zeros(mask.shape, dtype=np.int32)
        paint_labels(mask, boxes, labels)
    seeds = np.array([c[0, 0] for c in contours], dtype=int).reshape(-1, 2)
    return polarity, labels, boxes, seeds


def _regions_split(flat, histogram, mask, blobs, polarity, guard, config, from_median):
    """The blobs of ``mask`` (as :func:`_blobs` gives them; ``histogram``: ``flat``'s), with
    each region that is no Mark cut again at a level of its own: a plate on a light table
    or in a round field of view is one blob of the frame's threshold, darker than its
    surround, and its dots lie inside it darker still. A region is a blob too large for a
    Mark in either direction or one at the frame's border (where a Mark is refused as
    clipped anyway); its level is taken from its own pixels' histogram as the frame's is
    (:func:`levels.mask_levels`), kept where it leaves the region's background out (the
    region's class above the level is most of it). The cut stands where it gives at least
    twice the Mark-shaped blobs the frame's threshold gave (see below); ``mask`` is then
    cut in place and its blobs traced again."""
    contours, boxes, holes = blobs
    height, width = flat.shape
    cut = None          # the mask with the regions cut, copied at the first cut
    largest = 2 * SIZE_SLACK[1] * config.max_size_px
    smallest = 4 * SIZE_SLACK[0] * config.min_size_px
    margin = config.border_margin_px
    from calib_core.marks.levels import mask_levels
    # The regions, chosen over all boxes at once: a frame's noise specks made a loop over
    # every blob cost 0.08 ms. A region holds a Mark with its surround: smaller ones
    # (specks at the border) none.
    x0s, y0s, ws, hs = np.asarray(boxes).reshape(-1, 4).T
    at_border = ((x0s <= margin) | (y0s <= margin) | (x0s + ws >= width - margin)
                 | (y0s + hs >= height - margin))
    regions = np.flatnonzero(((ws > largest) | (hs > largest) | at_border)
                             & (np.minimum(ws, hs) >= smallest))
    for index in regions.tolist():
        contour, (x0, y0, w, h) = contours[index], boxes[index]
        region = np.zeros((h, w), np.uint8)
        cv2.drawContours(region, [contour], -1, 1, cv2.FILLED, offset=(-x0, -y0))
        pixels = flat[y0:y0 + h, x0:x0 + w]
        # A region that fills its box (a surround's is the whole frame, a plate's its
        # rectangle) is counted without the mask, which costs calcHist 2.5 times as much;
        # the whole frame's histogram is at hand.
        if cv2.countNonZero(region) < region.size:
            counts = cv2.calcHist([pixels], [0], region, [256], [0, 256]).ravel()
        elif pixels.size < flat.size:
            counts = cv2.calcHist([pixels], [0], None, [256], [0, 256]).ravel()
        else:
            counts = histogram
        dark, bright = mask_levels(counts, guard, from_median)
        level = dark if polarity == 'dark' else bright
        marks = (counts[:int(level) + 1] if polarity == 'dark'
                 else counts[int(level) + 1:]).sum()
        if not 0 < marks < 0.5 * counts.sum():
            continue            # one class only: nothing inside stands out of the region
        cut = mask.copy() if cut is None else cut
        window = cut[y0:y0 + h, x0:x0 + w]
        inside = region.view(bool)
        window[inside] = _mask(pixels, level, polarity)[inside]
    if cut is None:
        return contours, boxes, holes
    split = _blobs(cut)
    # Kept where the regions held the Marks: the frame's threshold found at most half as
    # many (none, on a light table). A dense grid on a dark table has its Marks already;
    # a level of the table's own then finds only what lies on it.
    before = _mark_shaped(contours, boxes, flat.shape, config)
    if _mark_shaped(*split[:2], flat.shape, config) >= max(2 * before, 1):
        mask[:] = cut
        return split
    return contours, boxes, holes


def _vote(flat, histogram, levels, config, guard, from_median):
    """The polarity whose mask has more Mark-shaped blobs (ties go to dark Marks), its
    mask and its blobs (as _blobs gives them).

    Where both masks are cut at Otsu's level they complement each other, and a blob of
    one mask clear of the frame's border is made of holes of the other's blobs. So when
    the class with fewer pixels (the Marks, but for a dense grid on a dark table) has as
    many Mark-shaped blobs as its blobs have holes, the other cannot have more, and its
    contours (a tenth of a millisecond a frame) are not traced."""
    complementary = levels['dark'] == levels['bright'] and config.border_margin_px > 0
    dark_pixels = histogram[:int(levels['dark']) + 1].sum()
    order = ('bright', 'dark') if dark_pixels > histogram.sum() / 2 else ('dark', 'bright')
    votes = []
    for polarity in order:
        mask = _mask(flat, levels[polarity], polarity)
        blobs = _regions_split(flat, histogram, mask, _blobs(mask), polarity, guard, config,
                               from_median)
        vote = (_mark_shaped(*blobs[:2], flat.shape, config), polarity == 'dark')
        votes.append((vote, polarity, mask, blobs))
        # The other mask has at most this one's holes in Mark-shaped blobs.
        if complementary and vote > (blobs[2], polarity != 'dark'):
            break
    return max(votes, key=lambda entry: entry[0])[1:]


def _mask(flat, level, polarity):
    """1 on the flattened frame's pixels of ``polarity`` Marks, else 0 (uint8): at or
    below the dark Marks' ``level``, above the bright ones' (levels.mask_levels)."""
    kind = cv2.THRESH_BINARY_INV if polarity == 'dark' else cv2.THRESH_BINARY
    return cv2.threshold(flat, level, 1, kind)[1]


def _blobs(mask):
    """The outer contours of a mask's blobs, their bounding boxes (k, 4: x, y, width,
    height, px) and how many holes the blobs have. With RETR_CCOMP every blob's outer
    contour is at the top level, also a Mark's inside a hole of another blob, as dots on
    a plate framed by a table; the holes' contours are at the second."""
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    outer = [c for c, link in zip(contours, hierarchy[0] if contours else []) if link[3] < 0]
    boxes = np.array([cv2.boundingRect(c) for c in outer], dtype=int).reshape(-1, 4)
    return outer, boxes, len(contours) - len(outer)


def _mark_shaped(contours, boxes, shape, config) -> int:
    """How many of the blobs (outer contours and bounding boxes) in a frame of ``shape``
    have a Mark's size, aspect (a dot seen at an angle's too) and fill, clear of the
    frame's border. A blob at the border is refused as clipped, and the background of a
    frame with one small Mark is such a blob: counted, it outvoted a dot seen at an angle."""
    if not contours:
        return 0
    from calib_core.marks.bands import mark_shaped_count
    # A contour's polygon runs through the boundary pixels' centres, so it encloses about
    # half a pixel less than the blob all round.
    area = np.array([cv2.contourArea(c) for c in contours]) + boxes[:, 2] + boxes[:, 3]
    return mark_shaped_count(boxes, area, *shape, SIZE_SLACK[0] * config.min_size_px,
                             SIZE_SLACK[1] * config.max_size_px, float(config.border_margin_px))


def moment_shapes(uu, uv, vv):
    """The shapes (a, b) of dot_edge_model (m, 2) of the ellipses of blobs' second central
    moments (px^2, arrays): its P is C^-1 scaled to a trace of 2."""
    return np.column_stack([(vv - uu) / (uu + vv), -2 * uv / (uu + vv)])


def moment_overlap(component, area, cu, cv, uu, uv, vv) -> float:
    """Intersection over union of a blob (``component``, its boolean box) and the ellipse
    of its second moments, ``{d : d^T C^-1 d <= 4}`` (the blob itself for a filled
    ellipse); ``area`` (px^2), centroid ``cu``, ``cv`` (px, in the box) and moments as
    blob_statistics gives them."""
    h, w = component.shape
    dv = np.arange(-1, h + 1) - cv
    du = np.arange(-1, w + 1) - cu
    det = uu * vv - uv * uv
    form = (np.add.outer(uu * dv * dv, vv * du * du) - 2 * uv * np.outer(dv, du)) / det
    inside = form <= 4.0
    common = np.count_nonzero(inside[1:-1, 1:-1] & component)
    return common / (np.count_nonzero(inside) + area - common)
