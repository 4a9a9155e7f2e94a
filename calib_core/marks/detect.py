"""The detector's entry point: validate the frame, segment it, classify each candidate
(circle, ellipse seen as a circle, cross, or rejected with a reason), fit, and accept
the Marks whose contrast, size and centre uncertainty make sense."""
from __future__ import annotations

import numpy as np

from calib_core.errors import DetectionError, InvalidInputError
from calib_core.marks.config import (
    ELLIPSE_ABOVE_ASPECT, ELLIPSE_MIN_FILL, MAX_ASPECT, MAX_ELLIPSE_ASPECT, MAX_SIGMA_OF_SIZE,
    MIN_ELLIPSE_OVERLAP, MIN_FILL, SHAPES, SIZE_SLACK, Detection, DetectorConfig, Mark)
from calib_core.marks.cross import fit_cross
from calib_core.marks.pixels import check_image, full_scale
from calib_core.marks.segmentation import MomentShape, estimate_noise, segment


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
    # The compiled code and numba (105 MiB, 0.4 s) load with the first frame, not with
    # every process that imports this package.
    from calib_core.marks.bands import blob_statistics
    from calib_core.marks.circle import DotCandidate, fit_circles

    if shape not in ('',) + SHAPES:
        raise InvalidInputError(f'shape must be "circle", "cross" or "", not {shape!r}')
    image = check_image(image)
    # The frame stays in its own type; each Mark's pixels become float in its fit.
    low, high = float(image.min()), float(image.max())
    full = full_scale(image)
    if full is not None and high >= full and np.count_nonzero(image >= full) > image.size / 2:
        raise DetectionError('image is saturated: more than half of the pixels are at full scale')
    if full is not None and high < full:
        full = None  # nothing is clipped: no Mark needs the saturation check
    noise = max(estimate_noise(image), 1e-12 * max(abs(high), 1.0))
    if high - low < 2 * config.min_snr * noise or high == low:
        raise DetectionError('image has no contrast (empty or uniform): no Mark can be seen')

    noise_scaled = noise * 255.0 / (high - low)
    polarity, labels, boxes, seeds, flat = segment(image, noise_scaled, config)

    height, width = image.shape
    marks: list[Mark] = []
    rejected: list[str] = []
    circles: list[tuple[DotCandidate, str]] = []

    def accept(mark, kind, where):
        if abs(mark.contrast) < config.min_snr * noise:
            rejected.append(f'contrast {abs(mark.contrast):.3g} below {config.min_snr} x noise {where}')
        elif not config.min_size_px <= mark.size <= config.max_size_px:
            rejected.append(f'{kind} of size {mark.size:.1f} px outside '
                            f'[{config.min_size_px}, {config.max_size_px}] {where}')
        elif mark.sigma_px > MAX_SIGMA_OF_SIZE * mark.size:
            rejected.append(f'{kind} centre not determined (1-sigma {mark.sigma_px:.2g} px for a '
                            f'{mark.size:.1f} px Mark) {where}')
        else:
            marks.append(mark)

    statistics = blob_statistics(labels, boxes, seeds, flat, polarity == 'dark')
    for (x0, y0, w, h), (label, area, *moments, depth) in zip(boxes, statistics):
        label = int(label)
        half = max(w, h) / 2.0
        if half < config.min_size_px * SIZE_SLACK[0] or area < 4:
            continue  # noise speck
        moments = MomentShape(area, *moments)
        centroid = (x0 + moments.cu, y0 + moments.cv)
        where = f'near ({centroid[0]:.0f}, {centroid[1]:.0f}) px'
        if half > config.max_size_px * SIZE_SLACK[1]:
            rejected.append(f'too large ({half:.0f} px) {where}')
            continue
        if (x0 < config.border_margin_px or y0 < config.border_margin_px
                or x0 + w > width - config.border_margin_px
                or y0 + h > height - config.border_margin_px):
            rejected.append(f'clipped at the image border {where}')
            continue
        aspect = max(w, h) / max(min(w, h), 1)
        fill = area / float(w * h)
        ellipse = None
        if fill > 0.62 and aspect < MAX_ASPECT and moments.aspect < ELLIPSE_ABOVE_ASPECT:
            kind = 'circle'
        elif (fill > ELLIPSE_MIN_FILL and moments.aspect <= MAX_ELLIPSE_ASPECT
              and moments.overlap(_component(labels, x0, y0, w, h, label))
              >= MIN_ELLIPSE_OVERLAP):
            kind, ellipse = 'circle', moments
        elif aspect < MAX_ASPECT and MIN_FILL < fill < 0.6:
            kind = 'cross'
        else:
            rejected.append(f'ambiguous shape (aspect {aspect:.2f}, fill {fill:.2f}; '
                            f'touching Marks or debris?) {where}')
            continue
        if shape and kind != shape:
            continue
        # A Mark at the lowest accepted contrast stands out of the smoothed frame by at
        # least half of it; a noise speck does not, and is dropped before a costly fit.
        if depth < 0.5 * config.min_snr * noise_scaled:
            continue
        if kind == 'circle':
            circles.append((DotCandidate((x0, y0, w, h), area, centroid, ellipse, label), where))
            continue
        try:
            accept(fit_cross(image, x0, y0, _component(labels, x0, y0, w, h, label), area,
                             polarity, noise, full), kind, where)
        except DetectionError as exc:
            rejected.append(f'{exc} {where}')
    # The dots are fitted together: one compiled run for all costs little more than for
    # one, where per-dot calls cost mostly the interpreter's overhead.
    dots = fit_circles(image, [dot for dot, _ in circles], labels, polarity, full,
                       config.box_aperture_below_blur_px)
    for fitted, (_, where) in zip(dots, circles):
        if isinstance(fitted, Mark):
            accept(fitted, 'circle', where)
        else:
            rejected.append(f'{fitted} {where}')

    marks.sort(key=lambda m: (round(m.v), m.u))
    if not marks:
        detail = f' ({"; ".join(rejected)})' if rejected else ''
        raise DetectionError(f'no {shape or "Mark"} found in the image{detail}')
    if expected_count and len(marks) != expected_count:
        detail = f'; rejected: {"; ".join(rejected)}' if rejected else ''
        raise DetectionError(f'expected {expected_count} Mark(s), found {len(marks)}: ambiguous'
                             f'{detail}')
    return Detection(marks=marks, rejected=rejected, noise_sigma=noise)


def _component(labels, x0, y0, w, h, label):
    """A blob's pixels in its box x0, y0, w, h (boolean, C-contiguous): for the shapes
    that need more than its moments."""
    return labels[y0:y0 + h, x0:x0 + w] == label
