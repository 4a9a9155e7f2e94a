"""Sub-pixel detection of circular and cross Marks.

Segmentation finds candidates: the frame is smoothed, a robust quadratic illumination
surface is taken off, and the connected components below (above) a threshold are the
dark (bright) candidates; the threshold is Otsu's unless that splits the background's
noise. Each candidate is refined by fitting an intensity model to the raw pixels by
Levenberg-Marquardt (circles: a small solver on the normal equations that fits all of a
frame's circles at once, for speed; crosses: scipy.optimize.least_squares). A circular
dot seen at an angle is an ellipse; a blob shaped like one (by its second moments) is
fitted with the ellipse's two shape parameters added, and reported as a circle of its
mean radius. Under
Gaussian noise that fit is the maximum-likelihood estimate, which is what lets the centre
error approach the Cramer-Rao bound. The covariance of the centre comes from the fit's
Jacobian and residual variance.

Pixels follow OpenCV's convention: the centre of the top-left pixel is (0, 0).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from calib_core.errors import DetectionError, InvalidInputError
from printer_alignment.core.mark_models import (PIXEL_APERTURE_VARIANCE, cross_coverage,
                                                dot_edge_model, edge_sigma,
                                                ellipse_edge_distance)

SHAPES = ('circle', 'cross')
# Half-width of the ring of pixels around a circle's edge used by the fit, px: covers the
# edge blur (sigma up to 1.5 px) to 4 sigma.
EDGE_BAND_PX = 6.0
# Edge bands with more pixels than this are fitted in two steps (see _fit_circle).
ONE_STEP_ABOVE_PX = 1500
ROUGH_FIT_PX = 750
# Segmentation: the illumination surface is fitted to means of blocks this wide (px),
# with this many rounds of outlier rejection.
TREND_BLOCK_PX = 16
TREND_ITERATIONS = 4
SURFACE_STEP_PX = 4
# The 5x5, sigma 1 px Gaussian smoothing before the threshold scales white noise by this.
SMOOTHING_NOISE_GAIN = 0.287
# The threshold stays at least this many smoothed-noise sigma from the background.
MIN_THRESHOLD_SIGMA = 5.0
# A candidate blob's box: its half-size within these factors of the accepted Mark sizes
# (the threshold makes blobs a little smaller or larger than the Mark), its sides within
# this aspect ratio, and at least this share of it filled (a thin cross's least).
SIZE_SLACK = (0.8, 1.2)
MAX_ASPECT = 1.35
MIN_FILL = 0.12
# A filled blob whose second moments are more elongated than this is a dot seen at an
# angle and is fitted as an ellipse; up to this elongation (the moments' axis ratio),
# which a dot shows at about 66 degrees from face-on.
ELLIPSE_ABOVE_ASPECT = 1.1
MAX_ELLIPSE_ASPECT = 2.5
# Such an ellipse fills its bounding box least when turned by 45 degrees, to
# pi k / (2 (1 + k^2)) at aspect k; 0.9 of that allows for the pixels.
ELLIPSE_MIN_FILL = 0.9 * np.pi * MAX_ELLIPSE_ASPECT / (2 * (1 + MAX_ELLIPSE_ASPECT ** 2))
# Such a blob overlaps the ellipse of its second moments by at least this share
# (intersection over union): 0.98 and more for 95 % of the dots in the tilted grid
# photos, 0.84 at most for two touching dots of 5-30 px, whatever their sizes.
MIN_ELLIPSE_OVERLAP = 0.9
# A dot's fit needs at least this many band pixels nearer to it than to other blobs.
MIN_BAND_PX = 40
# The cross fit gives up after this many model evaluations (see _fit_cross).
CROSS_MAX_EVALUATIONS = 40
# A cross's blob overlaps itself turned by 90 degrees by at least this share (intersection
# over union): 0.84-0.99 on rendered crosses of 5-40 px at 5 % noise, at most 0.5 on the
# touching dots of a random-dot photo, apart from a few tiny blobs.
MIN_QUARTER_TURN_OVERLAP = 0.7
DEGENERATE_FIT = 'degenerate fit: the pixels do not determine the centre'
# A fit whose centre's 1-sigma uncertainty exceeds this share of the Mark's size has not
# found the centre (a blob the model does not describe): the weakest Mark accepted, at
# min_snr and the smallest size, is determined to a few hundredths of its size.
MAX_SIGMA_OF_SIZE = 0.25
# The darkest (brightest) level of a frame is the one with this many pixels beyond it:
# fewer than the smallest Mark has, more than a hot pixel.
EXTREME_PIXELS = 4


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings (pixel units).

    Attributes
    ----------
    min_size_px, max_size_px : float
        Accepted circle radius / cross half-length, px.
    polarity : str
        ``"dark"`` (Marks darker than background), ``"bright"`` or ``"auto"`` (the class
        with more Mark-shaped blobs; setting it saves that look, about 0.3 ms a frame).
    min_snr : float
        Minimum fitted contrast over the image noise sigma.
    border_margin_px : float
        A candidate closer than this to the image border is reported as clipped.
    """

    min_size_px: float = 2.5
    max_size_px: float = 120.0
    polarity: str = 'auto'
    min_snr: float = 6.0
    border_margin_px: float = 1.0

    def __post_init__(self):
        if not 0 < self.min_size_px < self.max_size_px:
            raise InvalidInputError('need 0 < min_size_px < max_size_px')
        if self.polarity not in ('auto', 'dark', 'bright'):
            raise InvalidInputError(f'polarity must be auto, dark or bright, not {self.polarity!r}')
        if self.min_snr <= 0:
            raise InvalidInputError('min_snr must be positive')


@dataclass(frozen=True)
class Mark:
    """A detected Mark. ``covariance`` is the 2x2 covariance of (u, v) in px^2."""

    shape: str
    u: float
    v: float
    covariance: np.ndarray
    size: float
    contrast: float
    quality: float

    @property
    def sigma_px(self) -> float:
        """Largest 1-sigma axis of the centre uncertainty, px."""
        return float(np.sqrt(np.max(np.linalg.eigvalsh(self.covariance))))


@dataclass
class Detection:
    """All Marks found in an image and the candidates rejected, with reasons."""

    marks: list[Mark]
    rejected: list[str] = field(default_factory=list)
    noise_sigma: float = 0.0


def _full_scale(image: np.ndarray) -> float | None:
    if image.dtype == np.uint8:
        return 255.0
    if image.dtype == np.uint16:
        return 65535.0
    return None


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2:
        raise InvalidInputError(f'expected a single-channel image (2-D array), got shape {image.shape}')
    if image.size == 0:
        raise InvalidInputError('empty image')
    if image.dtype.kind == 'f' and not np.all(np.isfinite(image)):
        raise InvalidInputError('image contains NaN or infinite values')
    if image.dtype.kind not in 'uif':
        raise InvalidInputError(f'unsupported pixel type {image.dtype}')
    return image


def estimate_noise(image: np.ndarray) -> float:
    """Robust sigma of the pixel noise (image units) from horizontal pixel differences.

    About 10000 differences (every k-th row) give sigma to about 1.3 % (the MAD's
    efficiency is 37 %), and keep the two medians cheap on full frames."""
    step = max(1, int(np.ceil(image.size / 10000)))
    diff = np.diff(image[::step].astype(np.float64), axis=1).ravel()
    return float(np.median(np.abs(diff - np.median(diff))) / 0.6745 / np.sqrt(2.0))


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
    image = _check_image(image)
    # The frame stays in its own type; each Mark's pixels become float in its fit.
    low, high = float(image.min()), float(image.max())
    full = _full_scale(image)
    if full is not None and high >= full and np.count_nonzero(image >= full) > image.size / 2:
        raise DetectionError('image is saturated: more than half of the pixels are at full scale')
    if full is not None and high < full:
        full = None  # nothing is clipped: no Mark needs the saturation check
    noise = max(estimate_noise(image), 1e-12 * max(abs(high), 1.0))
    if high - low < 2 * config.min_snr * noise or high == low:
        raise DetectionError('image has no contrast (empty or uniform): no Mark can be seen')

    noise_scaled = noise * 255.0 / (high - low)
    polarity, labels, boxes, seeds, flat = _segment(image, noise_scaled, config)

    height, width = image.shape
    marks: list[Mark] = []
    rejected: list[str] = []
    circles: list[tuple[_CircleStart, str]] = []

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

    for (x0, y0, w, h), (seed_u, seed_v) in zip(boxes, seeds):
        half = max(w, h) / 2.0
        if half < config.min_size_px * SIZE_SLACK[0]:
            continue  # noise speck
        label = labels[seed_v, seed_u]
        component = labels[y0:y0 + h, x0:x0 + w] == label
        moments = _moment_shape(component)
        area = moments.area
        if area < 4:
            continue
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
              and moments.overlap(component) >= MIN_ELLIPSE_OVERLAP):
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
        if _depth(flat, x0, y0, w, h, polarity) < 0.5 * config.min_snr * noise_scaled:
            continue
        try:
            if kind == 'circle':
                circles.append((_circle_start(image, x0, y0, w, h, area, centroid,
                                              polarity, full, ellipse, (labels, label)),
                                where))
            else:
                accept(_fit_cross(image, x0, y0, component, area, polarity, noise, full),
                       kind, where)
        except DetectionError as exc:
            rejected.append(f'{exc} {where}')
    # The circles are fitted together: one solver run for all costs little more than
    # for one, where per-Mark runs cost mostly the interpreter's overhead.
    for fitted, (_, where) in zip(_fit_circles([start for start, _ in circles]), circles):
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


def _flatten(smoothed, tolerance):
    """``smoothed`` (uint8) less a robust quadratic illumination surface, at 128 (uint8).

    The surface is fitted by least squares to block means of the frame, dropping blocks
    more than 3 robust sigma off it (the Marks, and in photos the scene around the plate),
    so a fall-off of light across the frame does not split the background in two at the
    threshold. Frames whose block means (10th to 90th percentile) vary less than
    ``tolerance`` are returned unchanged."""
    height, width = smoothed.shape
    rows, cols = max(height // TREND_BLOCK_PX, 3), max(width // TREND_BLOCK_PX, 3)
    means = cv2.resize(smoothed, (cols, rows), interpolation=cv2.INTER_AREA).ravel().astype(np.float64)
    low, high = np.percentile(means, [10, 90])
    if high - low < tolerance:
        return smoothed
    y, x = np.divmod(np.arange(rows * cols), cols)
    # Block centres in full-frame px, scaled to [-1, 1] for conditioning.
    x = ((x + 0.5) * width / cols - 0.5) / width * 2 - 1
    y = ((y + 0.5) * height / rows - 0.5) / height * 2 - 1
    design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    keep = np.ones(means.size, dtype=bool)
    for _ in range(TREND_ITERATIONS):
        # lstsq, not the normal equations: the kept blocks may not pin every term.
        coef = np.linalg.lstsq(design[keep], means[keep], rcond=None)[0]
        residual = means - design @ coef
        centre = np.median(residual[keep])
        spread = 1.4826 * np.median(np.abs(residual[keep] - centre))
        keep_next = np.abs(residual - centre) < max(3 * spread, 1.0)
        if np.count_nonzero(keep_next) < 2 * design.shape[1]:
            break
        keep = keep_next
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


def _segment(image, noise_scaled, config):
    """Candidate Marks: the connected components of the thresholded, flattened frame.

    Returns the polarity; the labels of the Marks' mask (int32, 8-connected); each
    blob's bounding box (k, 4: x, y, width, height, px) and one pixel of it (k, 2: u, v),
    from its outer contour; and the flattened frame (uint8). Labels and contours cost a
    fifth of connected components with statistics, which sum over every pixel of the
    frame. The threshold is Otsu's unless that
    splits the background's noise (see _threshold). ``auto`` polarity takes the class
    with more Mark-shaped blobs: the minority class is not the Marks when a dense dot
    grid and a dark table fill most of a photo."""
    scaled = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    smoothed_noise = SMOOTHING_NOISE_GAIN * noise_scaled
    guard = MIN_THRESHOLD_SIGMA * smoothed_noise
    flat = _flatten(cv2.GaussianBlur(scaled, (5, 5), 1.0), smoothed_noise)
    histogram = cv2.calcHist([flat], [0], None, [256], [0, 256]).ravel()
    otsu = _otsu(histogram)
    polarities = ('dark', 'bright') if config.polarity == 'auto' else (config.polarity,)
    masks = {p: _mask(flat, histogram, otsu, guard, p) for p in polarities}
    blobs = {p: _blobs(masks[p]) for p in polarities}
    # Ties go to dark Marks, the first.
    polarity = (max(polarities, key=lambda p: _mark_shaped(*blobs[p], config))
                if len(polarities) > 1 else polarities[0])
    labels = cv2.connectedComponents(masks[polarity], connectivity=8)[1]
    contours, boxes = blobs[polarity]
    seeds = np.array([c[0, 0] for c in contours], dtype=int).reshape(-1, 2)
    return polarity, labels, boxes, seeds, flat


def _mask(flat, histogram, otsu, guard, polarity):
    """1 on the flattened frame's pixels of ``polarity`` Marks, else 0 (uint8).

    cv2.threshold floors the level on 8-bit frames and keeps src > level (src <= level
    inverted); the masks are flat < dark level and flat > bright level."""
    if polarity == 'dark':
        level = np.ceil(_threshold(histogram, otsu, guard)) - 1
        return cv2.threshold(flat, level, 1, cv2.THRESH_BINARY_INV)[1]
    level = 255 - _threshold(histogram[::-1], 255 - otsu, guard)
    return cv2.threshold(flat, level, 1, cv2.THRESH_BINARY)[1]


def _otsu(histogram) -> int:
    """Otsu's threshold of a 256-bin histogram: the level t that maximises the variance
    between the classes <= t and > t (as cv2.THRESH_OTSU, which would also binarise)."""
    levels = np.arange(histogram.size)
    weight = np.cumsum(histogram)
    moment = np.cumsum(histogram * levels)
    total, total_moment = weight[-1], moment[-1]
    with np.errstate(divide='ignore', invalid='ignore'):
        between = (total_moment * weight - total * moment) ** 2 / (weight * (total - weight))
    return int(np.argmax(np.nan_to_num(between[:-1], nan=-1.0, posinf=-1.0)))


def _threshold(histogram, otsu, guard) -> float:
    """Grey level below which a pixel belongs to a dark Mark, from the flattened frame's
    histogram (256 bins; mirror it for bright Marks) and Otsu's threshold.

    Otsu's threshold is kept when it lies at least ``guard`` below the median of the
    class above it. Otherwise it has split the background's noise (one small Mark in
    view), and the level is halfway between that median and the darkest pixels: the
    Mark's edge, as Otsu's threshold would have put it."""
    above = np.cumsum(histogram[int(otsu) + 1:])
    if not above.size or above[-1] == 0:
        return otsu
    background = int(otsu) + 1 + int(np.searchsorted(above, above[-1] / 2))
    if otsu <= background - guard:
        return otsu
    darkest = int(np.searchsorted(np.cumsum(histogram), EXTREME_PIXELS))
    return min(background - guard, (background + darkest) / 2)


def _blobs(mask):
    """The outer contours of a mask's blobs and their bounding boxes (k, 4: x, y, width,
    height, px). With RETR_CCOMP every blob's outer contour is at the top level, also a
    Mark's inside a hole of another blob, as dots on a plate framed by a table."""
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    contours = [c for c, link in zip(contours, hierarchy[0] if contours else []) if link[3] < 0]
    return contours, np.array([cv2.boundingRect(c) for c in contours], dtype=int).reshape(-1, 4)


def _mark_shaped(contours, boxes, config) -> int:
    """How many of the blobs (outer contours and bounding boxes) have a Mark's size,
    aspect and fill."""
    if not contours:
        return 0
    w, h = boxes[:, 2].astype(float), boxes[:, 3].astype(float)
    # A contour's polygon runs through the boundary pixels' centres, so it encloses about
    # half a pixel less than the blob all round.
    area = np.array([cv2.contourArea(c) for c in contours]) + (w + h)
    half = np.maximum(w, h) / 2.0
    fill = area / (w * h)
    return int(np.count_nonzero(
        (half >= SIZE_SLACK[0] * config.min_size_px) & (half <= SIZE_SLACK[1] * config.max_size_px)
        & (np.maximum(w, h) < MAX_ASPECT * np.minimum(w, h)) & (fill > MIN_FILL)))


@dataclass(frozen=True)
class _MomentShape:
    """A blob's area (px^2), centroid (px, in its box) and second central moments (px^2,
    with the pixel's own 1/12 px^2 added), seen as the ellipse of the same moments:
    ``{d : d^T C^-1 d <= 4}``, which is the blob itself for a filled ellipse."""

    area: float
    cu: float
    cv: float
    uu: float
    uv: float
    vv: float

    @property
    def eccentricity(self) -> float:
        """(l1 - l2) / (l1 + l2) of the moments' eigenvalues: 0 for a disk."""
        return float(np.hypot(self.uu - self.vv, 2 * self.uv) / (self.uu + self.vv))

    @property
    def aspect(self) -> float:
        """Axis ratio, >= 1."""
        e = self.eccentricity
        return float(np.sqrt((1 + e) / max(1 - e, 1e-12)))

    @property
    def shape(self) -> tuple[float, float]:
        """(a, b) of dot_edge_model: its P is C^-1 scaled to a trace of 2."""
        return ((self.vv - self.uu) / (self.uu + self.vv), -2 * self.uv / (self.uu + self.vv))

    def overlap(self, component) -> float:
        """Intersection over union of the blob (``component``, its boolean box) and its
        moment ellipse."""
        h, w = component.shape
        dv = np.arange(-1, h + 1) - self.cv
        du = np.arange(-1, w + 1) - self.cu
        det = self.uu * self.vv - self.uv * self.uv
        form = (np.add.outer(self.uu * dv * dv, self.vv * du * du)
                - 2 * self.uv * np.outer(dv, du)) / det
        inside = form <= 4.0
        common = np.count_nonzero(inside[1:-1, 1:-1] & component)
        return common / (np.count_nonzero(inside) + self.area - common)


def _moment_shape(component) -> _MomentShape:
    """The moments of a blob, ``component`` its boolean box (C-contiguous). It holds at
    least its seed, a pixel of the blob's contour."""
    m = cv2.moments(component.view(np.uint8), binaryImage=True)
    area = m['m00']
    pixel = 1.0 / 12.0
    return _MomentShape(area, m['m10'] / area, m['m01'] / area, m['mu20'] / area + pixel,
                        m['mu11'] / area, m['mu02'] / area + pixel)


def _depth(flat, x0, y0, w, h, polarity):
    """How far the component's extreme in the flattened frame lies from the median of a
    2 px ring around its box (smoothed, scaled units)."""
    r0, r1, c0, c1 = _window(flat.shape, x0, y0, w, h, 2)
    patch = flat[r0:r1, c0:c1]
    level = _middle(_border(patch))
    return level - float(patch.min()) if polarity == 'dark' else float(patch.max()) - level


def _middle(values) -> float:
    """The median of a 1-D array of odd size; of even size, the upper of the two middle
    values. For starting values and ring levels, at a tenth of np.median's call cost."""
    middle = values.size // 2
    return float(np.partition(values, middle)[middle])


def _border(patch):
    """The outermost rows and columns of a 2-D patch, as one 1-D array."""
    return np.concatenate([patch[0], patch[-1], patch[:, 0], patch[:, -1]])


def _window(shape, x0, y0, w, h, pad):
    """Rows r0:r1 and columns c0:c1 of the bounding box grown by ``pad``, inside the image."""
    height, width = shape
    return (max(y0 - pad, 0), min(y0 + h + pad, height),
            max(x0 - pad, 0), min(x0 + w + pad, width))


def _patch(pixels, x0, y0, w, h, pad):
    r0, r1, c0, c1 = _window(pixels.shape, x0, y0, w, h, pad)
    vv, uu = np.mgrid[r0:r1, c0:c1]
    return pixels[r0:r1, c0:c1].astype(np.float64), uu.astype(float), vv.astype(float)


def _check_saturation(values, full):
    if full is not None and np.mean(values >= full) > 0.01:
        raise DetectionError('saturated Mark (clipped intensities bias the centre)')


def _covariances(normals, residual_variances):
    """Centre covariances (k, 2, 2), px^2, from normal matrices J^T J (k, p, p) and the
    fits' residual variances (k,), and which of them are covariances: finite and positive
    definite. Where one is not, the pixels did not determine the centre, whatever the
    fit says."""
    try:
        inverse = np.linalg.inv(normals)
    except np.linalg.LinAlgError:
        inverse = np.linalg.pinv(normals)
    with np.errstate(over='ignore', invalid='ignore'):
        covariances = inverse[:, :2, :2] * residual_variances[:, None, None]
        uu, uv, vv = covariances[:, 0, 0], covariances[:, 0, 1], covariances[:, 1, 1]
        valid = np.isfinite(covariances).all(axis=(1, 2)) & (uu > 0) & (uu * vv - uv * uv > 0)
    return covariances, valid


def _residual_variance(residuals, parameters):
    """Residual variance of a fit of ``parameters`` unknowns (image units^2)."""
    return float(residuals @ residuals) / max(residuals.size - parameters, 1)


def _levenberg_marquardt(model, observed, valid, x, tolerance, max_iterations=100):
    """Least squares of ``model(x) - observed`` by Levenberg-Marquardt (Marquardt's
    diagonal scaling), for a stack of independent problems solved side by side.

    scipy.optimize.least_squares solves one problem per call, and its fixed cost per
    call (argument checks, MINPACK's QR of the full n x p Jacobian) was most of the
    detector's time; here every step solves the p x p normal equations of all problems
    at once. Each problem keeps its own damping and stops on its own: when the cost
    fell by less than ``tolerance`` relatively, the step, scaled by the Jacobian's
    column norms as MINPACK does, is below ``tolerance`` of x, or the residual is
    orthogonal to the Jacobian.

    Parameters
    ----------
    model : callable
        ``model(x, rows)`` returns the values (k, n) and the Jacobian (k, p, n) of the
        problems ``rows`` (k,) at their parameters ``x`` (k, p).
    observed : ndarray, shape (m, n)
    valid : ndarray of bool, shape (m, n)
        False on the padding that brings every problem to n values.
    x : ndarray, shape (m, p)
        Starting parameters.
    tolerance : ndarray, shape (m,)

    Returns
    -------
    x : ndarray, shape (m, p)
    residuals : ndarray, shape (m, n)
        Zero on the padding.
    normal : ndarray, shape (m, p, p)
        The normal matrix J^T J at x.
    converged : ndarray of bool, shape (m,)
    """
    weight = valid.astype(np.float64)

    def evaluate(x, rows):
        """Residuals, normal matrices, gradients J^T r and costs of the problems ``rows``
        at ``x``; the Jacobians themselves are not kept, to save copying them."""
        # A diverging trial overflows; its cost is then not finite and the step refused.
        with np.errstate(over='ignore', invalid='ignore'):
            values, jac = model(x, rows)
            residuals = values - observed[rows]
            residuals *= weight[rows]
            jac *= weight[rows, None, :]
            return (residuals, jac @ jac.transpose(0, 2, 1), (jac @ residuals[..., None])[..., 0],
                    np.einsum('mn,mn->m', residuals, residuals))

    x = x.copy()
    residuals, normal, gradient, cost = evaluate(x, np.arange(len(x)))
    damping = np.full(len(x), 1e-3)
    steps = np.zeros(len(x), dtype=int)
    converged = np.zeros(len(x), dtype=bool)
    active = np.ones(len(x), dtype=bool)
    diagonal = np.eye(x.shape[1], dtype=bool)
    while active.any():
        rows = np.flatnonzero(active)
        scale = np.maximum(normal[rows][:, diagonal], 1e-300)
        # At the optimum the residual is orthogonal to every Jacobian column (MINPACK's
        # gtol); checked first, because there rounding may keep any step from lowering
        # the cost.
        orthogonal = (np.max(np.abs(gradient[rows]) / np.sqrt(scale), axis=1)
                      <= 1e-10 * np.sqrt(np.maximum(cost[rows], 1e-300)))
        converged[rows[orthogonal]] = True
        active[rows[orthogonal]] = False
        rows, scale = rows[~orthogonal], scale[~orthogonal]
        if not rows.size:
            break
        damped = normal[rows]
        damped[:, diagonal] += damping[rows, None] * scale
        try:
            step = np.linalg.solve(damped, -gradient[rows][..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -(np.linalg.pinv(damped) @ gradient[rows][..., None])[..., 0]
        finite = np.all(np.isfinite(step), axis=1)
        trial = x[rows] + np.where(finite[:, None], step, 0.0)
        residuals_new, normal_new, gradient_new, cost_new = evaluate(trial, rows)
        better = finite & (cost_new <= cost[rows])
        # A step that raised the cost is tried again, shorter, from the same point.
        worse = rows[~better]
        damping[worse] *= 10.0
        active[worse[damping[worse] > 1e12]] = False
        taken = rows[better]
        decrease = cost[taken] - cost_new[better]
        column = np.sqrt(scale[better])
        x[taken], residuals[taken], normal[taken], gradient[taken], cost[taken] = (
            trial[better], residuals_new[better], normal_new[better], gradient_new[better],
            cost_new[better])
        damping[taken] = np.maximum(damping[taken] * 0.1, 1e-12)
        steps[taken] += 1
        small = ((decrease <= tolerance[taken] * cost[taken])
                 | (np.linalg.norm(column * step[better], axis=1)
                    <= tolerance[taken] * np.linalg.norm(column * x[taken], axis=1)))
        converged[taken[small]] = True
        active[taken[small | (steps[taken] >= max_iterations)]] = False
    return x, residuals, normal, converged


@dataclass(frozen=True)
class _CircleStart:
    """A dot candidate's edge-band pixels (px, image units) and starting parameters."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    part: np.ndarray | slice  # the pixels of the first, rough fit (see _circle_start)
    # dot_edge_model's: (cu, cv, radius, blur, contrast, background, grad_u, grad_v), and
    # for an ellipse its shape (a, b).
    x: np.ndarray
    radius0: float  # from the candidate's area, px

    @property
    def one_step(self) -> bool:
        return not isinstance(self.part, slice)


def _circle_start(pixels, x0, y0, w, h, area, centroid, polarity, full,
                  ellipse: _MomentShape | None, segmentation) -> _CircleStart:
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
    r0, r1, c0, c1 = _window(pixels.shape, x0, y0, w, h, pad)
    cu0, cv0 = centroid
    # The centre is in the edge; the flat interior adds nothing but time. The norm's
    # gradient is between sqrt(1 - e) and sqrt(1 + e) long, which bounds the band in
    # squared norms, so that the distance is taken only near the edge.
    du, dv = np.arange(c0, c1) - cu0, np.arange(r0, r1) - cv0
    a, b = shape
    norm2 = np.add.outer((1 - a) * dv * dv, (1 + a) * du * du)
    if b:
        norm2 += 2 * b * np.outer(dv, du)
    radius, reach = radius0 * scale, EDGE_BAND_PX * np.sqrt(1 + e)
    inner = (radius - reach) ** 2 if radius > reach else -1.0
    rows, cols = np.nonzero((norm2 > inner) & (norm2 < (radius + reach) ** 2))
    if ellipse is None:
        distance = np.sqrt(norm2[rows, cols]) - radius
    else:
        distance = ellipse_edge_distance(du[cols], dv[rows], radius, shape)
        band = np.abs(distance) < EDGE_BAND_PX
        rows, cols, distance = rows[band], cols[band], distance[band]
    clear = _clear_of_neighbours(segmentation, r0, r1, c0, c1)
    if clear is not None:
        keep = clear[rows, cols]
        if np.count_nonzero(keep) < MIN_BAND_PX:
            raise DetectionError('crowded: other blobs are nearer than it to most of its edge')
        rows, cols, distance = rows[keep], cols[keep], distance[keep]
    rows += r0
    cols += c0
    u, v = cols.astype(np.float64), rows.astype(np.float64)
    z = pixels[rows, cols].astype(np.float64)
    _check_saturation(z, full)
    # Large Marks: converge roughly on every k-th diagonal of the band (about ROUGH_FIT_PX
    # pixels), then one Gauss-Newton step on all of it. One Newton step from an estimate
    # within the noise of the optimum is as efficient as the full fit (Le Cam's one-step
    # estimator), at a fraction of the cost.
    part = ((rows + cols) % max(2, z.size // ROUGH_FIT_PX) == 0 if z.size > ONE_STEP_ABOVE_PX
            else slice(None))
    z_part, distance = z[part], distance[part]
    # Starting intensities from the part's pixels clearly inside and outside the edge.
    in_mark = z_part[distance < -1.5]
    outside = z_part[distance > 1.5]
    background = _middle(outside if outside.size else z_part)
    level = (_middle(in_mark) if in_mark.size
             else float(z_part.min() if polarity == 'dark' else z_part.max()))
    if level == background:
        raise DetectionError('no contrast between the Mark and its surroundings')
    # Starting radius and edge sigma from the band's intensities as fractions of the way
    # from background to Mark. Blur conserves area, so the fractions sum to the Mark's
    # area inside the band; and for an erf edge those between 16 and 84 % lie within one
    # sigma of the edge, a share sigma / EDGE_BAND_PX of the band's radial width.
    fraction = (z_part - background) / (level - background)
    inner_axes = np.maximum(semi_axes - EDGE_BAND_PX, 0.0)
    area = float(np.sum(fraction)) * z.size / z_part.size
    radius_init = np.sqrt(max(area / np.pi + inner_axes[0] * inner_axes[1], radius0 ** 2 / 4))
    transition = np.count_nonzero((fraction > 0.16) & (fraction < 0.84)) / z_part.size
    sigma0 = float(np.clip(EDGE_BAND_PX * transition, 0.3, 3.0))
    blur0 = np.sqrt(max(sigma0 ** 2 - PIXEL_APERTURE_VARIANCE, 0.1 ** 2))
    x = [cu0, cv0, radius_init * scale, blur0, level - background, background, 0.0, 0.0]
    return _CircleStart(u, v, z, part, np.array(x + list(shape) if ellipse is not None else x),
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


def _stack(arrays):
    """1-D arrays padded with zeros to one (k, n) array, and where it holds data."""
    stacked = np.zeros((len(arrays), max(a.size for a in arrays)))
    valid = np.zeros(stacked.shape, dtype=bool)
    for row, a in enumerate(arrays):
        stacked[row, :a.size] = a
        valid[row, :a.size] = True
    return stacked, valid


def _fit_circles(starts: list[_CircleStart]) -> list[Mark | DetectionError]:
    """The circles' fits, in the order of ``starts``: a Mark, or why there is none.

    Candidates are fitted in groups of one model (disk or ellipse) and similar pixel
    counts, so that little of the solver's work goes on the padding."""
    results: list = [None] * len(starts)
    if not starts:
        return results
    models = np.array([s.x.size for s in starts])
    sizes = np.array([s.z[s.part].size for s in starts])
    order = np.lexsort((sizes, models))
    models, sizes = models[order], sizes[order]
    group_start = 0
    for end in range(1, len(order) + 1):
        if (end == len(order) or models[end] != models[group_start]
                or sizes[end] > 2 * sizes[group_start]):
            group = order[group_start:end]
            for index, mark in zip(group, _fit_circle_group([starts[i] for i in group])):
                results[index] = mark
            group_start = end
    return results


def _fit_circle_group(starts: list[_CircleStart]) -> list[Mark | DetectionError]:
    u, valid = _stack([s.u[s.part] for s in starts])
    v, _ = _stack([s.v[s.part] for s in starts])
    z, _ = _stack([s.z[s.part] for s in starts])
    x_init = np.array([s.x for s in starts])
    reference = x_init[:, :2]
    tolerance = np.array([1e-4 if s.one_step else 1e-6 for s in starts])
    x, residuals, normals, converged = _levenberg_marquardt(
        lambda p, rows: dot_edge_model(p, u[rows], v[rows], reference[rows]),
        z, valid, x_init, tolerance)
    fits = []
    for k, start in enumerate(starts):
        ok, xk = bool(converged[k]), x[k]
        if start.one_step:
            values, jac_k = dot_edge_model(xk[None], start.u[None], start.v[None],
                                           reference[k:k + 1])
            jac_k = jac_k[0]
            residuals_k = values[0] - start.z
            normal = jac_k @ jac_k.T
            try:
                step = np.linalg.solve(normal, -jac_k @ residuals_k)
            except np.linalg.LinAlgError:
                ok = False
            else:
                xk, residuals_k = xk + step, residuals_k + step @ jac_k
        else:
            residuals_k, normal = residuals[k, :start.z.size], normals[k]
        fits.append((ok, xk, residuals_k, normal))
    covariances, determined = _covariances(
        np.array([normal for *_, normal in fits]),
        np.array([_residual_variance(r, x.shape[1]) for _, _, r, _ in fits]))
    results: list[Mark | DetectionError] = []
    for k, (ok, xk, residuals_k, _) in enumerate(fits):
        cu, cv, radius, sigma, contrast = xk[:5]
        # An ellipse's mean radius; from e = 1 on, P is no longer positive definite and
        # the edge no ellipse.
        e = float(np.hypot(*xk[8:])) if xk.size > 8 else 0.0
        if e < 1:
            radius /= (1 - e * e) ** 0.25
        if (not ok or e >= 1 or abs(sigma) > radius or radius <= 0
                or np.hypot(cu - reference[k, 0], cv - reference[k, 1]) > 0.5 * starts[k].radius0):
            results.append(DetectionError('circle fit did not converge'))
        elif not determined[k]:
            results.append(DetectionError(DEGENERATE_FIT))
        else:
            rms = float(np.sqrt(np.mean(residuals_k ** 2)))
            results.append(Mark('circle', float(cu), float(cv), covariances[k], float(radius),
                                float(contrast), float(np.clip(1 - rms / abs(contrast), 0, 1))))
    return results


def _fit_cross(pixels, x0, y0, component, area, polarity, noise, full) -> Mark:
    h, w = component.shape
    rows, cols = np.nonzero(component)
    # A cross is itself turned by a quarter turn about its centre; touching dots or
    # debris with a cross's fill are not, and the fit would wander on them (see
    # CROSS_MAX_EVALUATIONS).
    turned_rows = np.rint(rows.mean() + cols - cols.mean()).astype(int)
    turned_cols = np.rint(cols.mean() - rows + rows.mean()).astype(int)
    inside = (turned_rows >= 0) & (turned_rows < h) & (turned_cols >= 0) & (turned_cols < w)
    common = np.count_nonzero(component[turned_rows[inside], turned_cols[inside]])
    overlap = common / (2 * rows.size - common)
    if overlap < MIN_QUARTER_TURN_OVERLAP:
        raise DetectionError(f'not a cross: it differs from itself turned by 90 degrees '
                             f'(overlap {overlap:.2f}; touching Marks or debris?)')
    cu0, cv0 = x0 + cols.mean(), y0 + rows.mean()
    du, dv = x0 + cols - cu0, y0 + rows - cv0
    dist = np.hypot(du, dv)
    tips = dist > 0.8 * dist.max()
    # The arm tips give the orientation modulo 90 degrees (circular mean of 4 * angle).
    angle0 = np.angle(np.mean(np.exp(4j * np.arctan2(dv[tips], du[tips])))) / 4.0
    half0 = float(dist.max())
    width0 = float(np.clip(area / (4.0 * half0), 1.0, half0))
    pad = 4
    values, uu, vv = _patch(pixels, x0, y0, w, h, pad)
    u, v, z = uu.ravel(), vv.ravel(), values.ravel()
    _check_saturation(z, full)
    background = _middle(_border(values))
    level = _middle(pixels[y0 + rows, x0 + cols])
    x_init = np.array([cu0, cv0, angle0, half0, width0, 0.8, level - background, background])

    def residual(p):
        cu, cv, angle, half, width, sigma, contrast, bg = p
        cover = cross_coverage(u - cu, v - cv, angle, half, width, edge_sigma(sigma))
        return bg + contrast * cover - z

    # A cross converges in 5-8 evaluations; a blob that is no cross (touching dots) can
    # wander for hundreds, at a few ms each.
    result = least_squares(residual, x_init, method='lm', x_scale='jac',
                           max_nfev=CROSS_MAX_EVALUATIONS)
    cu, cv, angle, half, width, sigma, contrast, _ = result.x
    if not result.success or half <= 0 or width <= 0 or np.hypot(cu - cu0, cv - cv0) > 0.5 * half0:
        raise DetectionError('cross fit did not converge')
    covariance, determined = _covariances((result.jac.T @ result.jac)[None],
                                          np.array([_residual_variance(result.fun, x_init.size)]))
    if not determined[0]:
        raise DetectionError(DEGENERATE_FIT)
    rms = float(np.sqrt(np.mean(result.fun ** 2)))
    return Mark('cross', float(cu), float(cv), covariance[0],
                float(half), float(contrast), float(np.clip(1 - rms / abs(contrast), 0, 1)))
