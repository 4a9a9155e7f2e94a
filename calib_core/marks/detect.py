"""The detector's entry point: validate the frame, segment it, classify each candidate
(circle, ellipse seen as a circle, cross, or rejected with a reason), fit, and accept
the Marks whose contrast, size and centre uncertainty make sense."""
from __future__ import annotations

import numpy as np

from calib_core.errors import DetectionError, InvalidInputError
from calib_core.marks.config import (
    MAX_SIGMA_OF_SIZE, MIN_ELLIPSE_OVERLAP, SHAPES, SIZE_SLACK, Detection, DetectorConfig, Mark,
    largest_sigma)
from calib_core.marks.cross import fit_cross
from calib_core.marks.pixels import check_image, full_scale
from calib_core.marks.segmentation import (
    estimate_noise, flattened, moment_overlap, moment_shapes, scaling_range, segment)


def _levels(image: np.ndarray, config: DetectorConfig) -> tuple:
    """The frame's lowest and highest value, its full scale (None where nothing is
    clipped: no Mark needs the saturation check) and its noise sigma; a saturated or
    uniform frame is refused. The frame stays in its own type; each Mark's pixels become
    float in its fit."""
    low, high = float(image.min()), float(image.max())
    full = full_scale(image)
    if full is not None and high >= full and np.count_nonzero(image >= full) > image.size / 2:
        raise DetectionError('image is saturated: more than half of the pixels are at full scale')
    if full is not None and high < full:
        full = None
    noise = max(estimate_noise(image), 1e-12 * max(abs(high), 1.0))
    if high - low < 2 * config.min_snr * noise or high == low:
        raise DetectionError('image has no contrast (empty or uniform): no Mark can be seen')
    return low, high, full, noise


def detect_marks(image, config: DetectorConfig = DetectorConfig(), shape: str = '',
                 expected_count: int = 0) -> Detection:
    """Find Marks in ``image`` and measure their centres to sub-pixel accuracy.

    Parameters
    ----------
    image : ndarray, shape (H, W), uint8, uint16 or float
    shape : str
        ``"circle"``, ``"cross"`` or ``""`` for both.
    expected_count : int
        If > 0, exactly this many Marks must be found.

    Raises
    ------
    DetectionError
        No Mark found, wrong number of Marks, saturated or uniform image; the message says
        what was seen (clipped or ambiguous candidates and where).
    InvalidInputError
        Not a single-channel finite image.
    """
    if shape not in ('',) + SHAPES:
        raise InvalidInputError(f'shape must be "circle", "cross" or "", not {shape!r}')
    image = check_image(image)
    low, high, full, noise = _levels(image, config)
    # Segmentation sees the frame within its scaling range; the fits see every pixel.
    scale_low, scale_high = scaling_range(image, low, high, noise)
    segmented = image if (scale_low, scale_high) == (low, high) else np.clip(
        image, image.dtype.type(scale_low), image.dtype.type(scale_high))
    noise_scaled = noise * 255.0 / (scale_high - scale_low)
    frame = flattened(segmented, noise_scaled)
    marks, reasons = _marks(image, frame, noise, noise_scaled, full, config, shape, False)
    if not marks or (expected_count and len(marks) < expected_count):
        # Otsu's level may have split a highlight off the plate where it outnumbers the
        # Marks (one Mark beside a glare): the levels from the frame's median instead.
        again = _marks(image, frame, noise, noise_scaled, full, config, shape, True)
        if len(again[0]) > len(marks) and not (expected_count
                                               and len(again[0]) > expected_count):
            marks, reasons = again
    if not marks:
        detail = f' ({"; ".join(reasons)})' if reasons else ''
        raise DetectionError(f'no {shape or "Mark"} found in the image{detail}')
    if expected_count and len(marks) != expected_count:
        detail = f'; rejected: {"; ".join(reasons)}' if reasons else ''
        raise DetectionError(f'expected {expected_count} Mark(s), found {len(marks)}: ambiguous'
                             f'{detail}')
    return Detection(marks=marks, rejected=reasons, noise_sigma=noise)


def _marks(image, frame, noise, noise_scaled, full, config, shape, from_median):
    """The Marks found (in reading order) and why each other candidate is not one, in
    ``frame`` (segmentation.flattened's) at segment's levels (``from_median``: see
    levels.mask_levels)."""
    # The compiled code and numba (105 MiB, 0.4 s) load with the first frame, not with
    # every process that imports this package.
    from calib_core.marks.bands import blob_statistics, box_classes
    from calib_core.marks.circle import fit_circles

    flat = frame[0]
    polarity, labels, boxes, seeds = segment(*frame, config, from_median)
    box_class = box_classes(boxes, *image.shape, config.min_size_px * SIZE_SLACK[0],
                            config.max_size_px * SIZE_SLACK[1], config.border_margin_px)
    blobs = blob_statistics(labels, boxes, seeds, flat, polarity == 'dark', box_class)
    circles, crosses, rejected = _classify(boxes, blobs, box_class, labels, config, shape,
                                           noise_scaled)
    found: list[tuple[int, Mark]] = []
    for index in crosses:
        (x0, y0, w, h), label, area = boxes[index], int(blobs[index, 0]), blobs[index, 1]
        try:
            found.append((index, fit_cross(image, x0, y0, _component(labels, x0, y0, w, h, label),
                                           area, polarity, noise, full)))
        except DetectionError as exc:
            rejected.append((index, str(exc)))
    # The dots are fitted together: one compiled run for all costs little more than for
    # one, where per-dot calls cost mostly the interpreter's overhead.
    fits = fit_circles(image, circles, labels, boxes, polarity, full,
                       config.box_aperture_below_blur_px, noise)
    for index, fitted in zip(circles.index, fits):
        if isinstance(fitted, Mark):
            found.append((index, fitted))
        else:
            rejected.append((index, str(fitted)))
    marks = []
    for (index, mark), why in zip(found, _refusals([m for _, m in found], noise, config)):
        if why:
            rejected.append((index, why))
        else:
            marks.append(mark)
    marks.sort(key=lambda m: (round(m.v), m.u))
    # Reasons in the blobs' order, each with where its blob is.
    return marks, [f'{why} {_where(blobs[index], boxes[index])}'
                   for index, why in sorted(rejected)]


def _classify(boxes, blobs, box_class, labels, config, shape, noise_scaled):
    """The blobs taken for dots (DotCandidates) and for crosses (their indices), and the
    others' reasons (index, why); noise specks and faint blobs are dropped without one.

    ``blobs``: bands.blob_statistics' table (label, area, centroid in the box, moments,
    depth) of the blobs whose boxes (k, 4: x0, y0, width, height; px) are ``boxes``;
    ``box_class``: their bands.box_classes."""
    from calib_core.marks import bands
    from calib_core.marks.circle import DotCandidates
    classes, cross_shaped, numbers = bands.blob_classes(boxes, blobs, box_class)
    half, aspect, fill = numbers.T
    # A dot seen at an angle fills its moments' ellipse; touching dots do not.
    for k in np.flatnonzero(classes == bands.ELLIPSE_SHAPED):
        x0, y0, w, h = boxes[k]
        component = _component(labels, x0, y0, w, h, int(blobs[k, 0]))
        if moment_overlap(component, *blobs[k, 1:7]) < MIN_ELLIPSE_OVERLAP:
            classes[k] = bands.CROSS if cross_shaped[k] else bands.AMBIGUOUS
    rejected = [(k, f'too large ({half[k]:.0f} px)' if kind == bands.TOO_LARGE
                 else 'clipped at the image border' if kind == bands.CLIPPED
                 else f'ambiguous shape (aspect {aspect[k]:.2f}, fill {fill[k]:.2f}; '
                      'touching Marks, debris, or a Mark washed out on one side?)')
                for k, kind in enumerate(classes.tolist())
                if kind in (bands.TOO_LARGE, bands.CLIPPED, bands.AMBIGUOUS)]
    # A Mark at the lowest accepted contrast stands out of the smoothed frame by at
    # least half of it; a noise speck does not, and is dropped before a costly fit.
    deep = blobs[:, 7] >= 0.5 * config.min_snr * noise_scaled
    ellipse = classes == bands.ELLIPSE_SHAPED
    dots = np.flatnonzero(((classes == bands.CIRCLE) | ellipse) & deep
                          & (shape in ('', 'circle')))
    shapes = np.zeros((len(dots), 2))
    if ellipse[dots].any():  # 15 us a frame of dots seen face on, where all are zero
        uu, uv, vv = blobs[dots, 4:7].T
        shapes = np.where(ellipse[dots, None], moment_shapes(uu, uv, vv), 0.0)
    candidates = DotCandidates(dots, boxes[dots], blobs[dots, 1],
                               boxes[dots, :2] + blobs[dots, 2:4], shapes, ellipse[dots],
                               blobs[dots, 0].astype(int))
    crosses = np.flatnonzero((classes == bands.CROSS) & deep & (shape in ('', 'cross')))
    return candidates, crosses, rejected


def _refusals(marks, noise, config) -> list[str | None]:
    """Why each fitted Mark is not accepted (its contrast, size or centre's uncertainty
    makes no sense), or None."""
    if not marks:
        return []
    contrast = np.abs([m.contrast for m in marks])
    size = np.array([m.size for m in marks])
    sigma = largest_sigma(np.array([m.covariance for m in marks]))
    reasons = []
    for mark, level, size_px, sigma_px in zip(marks, contrast.tolist(), size.tolist(),
                                              sigma.tolist()):
        if level < config.min_snr * noise:
            reasons.append(f'contrast {level:.3g} below {config.min_snr} x noise')
        elif not config.min_size_px <= size_px <= config.max_size_px:
            reasons.append(f'{mark.shape} of size {size_px:.1f} px outside '
                           f'[{config.min_size_px}, {config.max_size_px}]')
        elif sigma_px > MAX_SIGMA_OF_SIZE * size_px:
            reasons.append(f'{mark.shape} centre not determined (1-sigma {sigma_px:.2g} px '
                           f'for a {size_px:.1f} px Mark)')
        else:
            reasons.append(None)
    return reasons


def _where(blob, box) -> str:
    """Where a blob (its row of blob_statistics and its box) is, for a reason."""
    return f'near ({box[0] + blob[2]:.0f}, {box[1] + blob[3]:.0f}) px'


def _component(labels, x0, y0, w, h, label):
    """A blob's pixels in its box x0, y0, w, h (boolean, C-contiguous): for the shapes
    that need more than its moments."""
    return labels[y0:y0 + h, x0:x0 + w] == label
