"""The flattened frame's threshold levels from its histogram, compiled (numba): Otsu's
level and, per polarity, the level the Marks' mask is cut at. In numpy their dozen
cumulative sums and searches cost 0.05-0.06 ms a frame within a detection."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from calib_core.marks.config import EXTREME_PIXELS


@njit(cache=True)
def mask_levels(histogram, guard, from_median):
    """The levels of the dark and the bright Marks' masks from the flattened frame's
    256-bin histogram (float32, as cv2.calcHist gives it) and the ``guard`` (grey levels)
    between Otsu's level and the background's median: dark Marks are the pixels at or
    below the first, bright ones those above the second (as cv2.threshold takes an 8-bit
    level: floored, src > level). Where Otsu's level t is kept for both, both are t - 1:
    the dark Marks' mask is the pixels below t, the bright Marks' the others.

    With ``from_median``, Otsu's level is not tried: each level lies between the
    frame's median and its extreme (see _class_threshold). A highlight beside a lone
    Mark outnumbers it, and Otsu's level splits the highlight from the plate."""
    otsu = otsu_level(histogram)
    dark = math.ceil(_class_threshold(histogram, otsu, guard, from_median)) - 1.0
    bright = 255.0 - _class_threshold(histogram[::-1], 255 - otsu, guard, from_median)
    # The pixels at Otsu's level go to the bright Marks, so that the masks complement
    # each other (segmentation._vote counts on it).
    return dark, bright - 1.0 if bright == otsu else bright


@njit(cache=True)
def otsu_level(histogram):
    """Otsu's threshold of a 256-bin histogram (float32): the level t that maximises the
    variance between the classes <= t and > t (as cv2.THRESH_OTSU). The classes' weights
    are summed in float32 and their products taken in float32, as numpy takes them for
    calcHist's float32 bins."""
    total, total_moment = np.float32(0.0), 0.0
    for level in range(histogram.size):
        total = np.float32(total + histogram[level])
        total_moment += np.float64(histogram[level]) * level
    best, best_between = 0, -np.inf
    weight, moment = np.float32(0.0), 0.0
    for level in range(histogram.size - 1):
        weight = np.float32(weight + histogram[level])
        moment += np.float64(histogram[level]) * level
        spread = weight * np.float32(total - weight)
        # An empty class makes the variance undefined: below every defined one.
        between = (total_moment * weight - total * moment) ** 2 / spread if spread else -1.0
        if between > best_between:
            best, best_between = level, between
    return best


@njit(cache=True)
def _class_threshold(histogram, otsu, guard, from_median):
    """Grey level below which a pixel belongs to a dark Mark, from the flattened frame's
    histogram (mirrored for bright Marks) and Otsu's threshold.

    Otsu's threshold is kept when it lies at least ``guard`` below the median of the
    class above it. Otherwise it has split the background's noise (one small Mark in
    view), and the level is halfway between that median and the darkest pixels (the
    first level with EXTREME_PIXELS at or below it): the Mark's edge, as Otsu's
    threshold would have put it. With ``from_median``, that level, from the median of
    the whole frame."""
    size = histogram.size
    first = 0 if from_median else otsu + 1
    above = np.float32(0.0)
    for level in range(first, size):
        above = np.float32(above + histogram[level])
    if above == 0:  # also where no level is above Otsu's
        return float(otsu)
    half, seen, background = np.float32(above / 2), np.float32(0.0), size
    for level in range(first, size):
        seen = np.float32(seen + histogram[level])
        if seen >= half:
            background = level
            break
    if not from_median and otsu <= background - guard:
        return float(otsu)
    seen, darkest = np.float32(0.0), size
    for level in range(size):
        seen = np.float32(seen + histogram[level])
        if seen >= EXTREME_PIXELS:
            darkest = level
            break
    return min(background - guard, (background + darkest) / 2)
