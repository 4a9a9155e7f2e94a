"""Detector settings and results: the tuned constants (each with why it has its value),
:class:`DetectorConfig`, and the :class:`Mark` and :class:`Detection` the detector returns."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_core.errors import InvalidInputError


SHAPES = ('circle', 'cross')
# Half-width of the ring of pixels around a circle's edge used by the fit, px: covers the
# edge blur (sigma up to 1.5 px) to 4 sigma.
EDGE_BAND_PX = 6.0
# A sharper dot's band is narrowed to its edge's reach as its start reads it: 4 of the
# edge's sigma, and a pixel for the start's edge being off, at least 3 px (px).
NARROW_BAND_SIGMAS, NARROW_BAND_SLACK_PX, NARROW_BAND_MIN_PX = 4.0, 1.0, 3.0
# A dot whose fitted edge EDGE_BAND_PX does not hold to NARROW_BAND_SIGMAS sigma (a
# defocused dot) is fitted again, from that fit, on a band that does (and
# NARROW_BAND_SLACK_PX more), up to this reach (px). On its 6 px band alone a dot blurred
# by 2.5 px had 1.22 times the Cramer-Rao bound of all its pixels (the band's own bound
# is 1.25x); now 1.03x. A band of 5 sigma gave the same, but its neighbours' edges
# reached its window in a grid of 45 px pitch, and their masks cost 5 ms a frame.
WIDE_BAND_MAX_PX = 18.0
# A dot's pixels within this distance of another blob are left out of its fit, px: the
# other's edge, blurred by sigma 1.4 px, has fallen there to 0.6 % of its contrast
# (2.5 sigma; a blob's mask ends where its edge is halfway).
NEIGHBOUR_CLEARANCE_PX = 3.5
# Segmentation: the illumination surface is fitted to means of blocks this wide (px),
# with this many rounds of outlier rejection.
TREND_BLOCK_PX = 16
TREND_ITERATIONS = 4
SURFACE_STEP_PX = 4
# Block means split in two classes that explain this share of their variance (Otsu's
# between-class share), the smaller class at least this share of the blocks, are a step
# (a plate on a light or dark table, a round field of view), not illumination: no
# surface is fitted across it (a quadratic warps at the step and leaves dark corners
# as blobs); the plate's dots get a level of their own inside its region. Uneven light
# gives 0.74, a cable across the plate 0.88 with 7 % of the blocks, the step scenes of
# calib_core/sim/scenes.py 0.93-0.97 with 23-77 %.
STEP_SEPARATION = 0.9
STEP_MIN_SHARE = 0.15
# Such classes that both reach the frame's border are a shadow's edge across it where at
# most this share of neighbouring blocks differ in class (segmentation._step).
STEP_MAX_BOUNDARY = 0.1
# The frame is scaled to 8 bits for segmentation between its extremes, unless a grey
# level would then span over this many noise sigma (a frame deeper than 8 bits stretched by
# a few hot or dead pixels, or an overlay): then between the levels with this share of
# the pixels beyond them at each end, where that range is under half of the frame's.
MAX_GREY_LEVEL_SIGMAS = 2.0
SCALING_OUTLIER_SHARE = 1e-4
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
# The pixels beyond a dot's edge band join its fit where their mean squared residual is
# within this factor of the band's: both are the noise's where the model holds (to
# about 15 % with a few hundred pixels).
FLAT_MISFIT = 4.0
# A dot whose edge band leaves a mean squared residual over this factor of the frame's
# noise variance is fitted again with light of its own along and across its edge
# (local_fit): the plain fit's ratio is 0.86-1.0 on rendered plates (the noise estimate
# takes the grey levels' rounding), 4.5-11 beside a highlight that moved the dot by
# 0.08-0.4 px.
LOCAL_MISFIT = 1.3
# ... over the noise's variance and that of this share of the dot's contrast: the plain
# model's own misfit on a sharp edge at high signal to noise (the profile's, which does
# not move the centre), which had called the local fit on every dot of clean frames at
# 1 % noise, 3.5 times their time (10 times on 40 px dots), for the same centres.
LOCAL_MISFIT_FLOOR = 0.01
# ... also on edges as wide as the band where the band's RMS residual is over this share
# of the contrast (a dot fading to 20 % across itself leaves 13 %, the plain fit taking
# the fade for a 1.7 px blur, 2-3.6 px off; a neighbour's blurred edge in a noise-free
# frame 0.1 % at most).
GROSS_MISFIT = 0.05
# ... and takes that fit where it moves the centre further than chance would with this
# probability, were the plain model right (dot_run._centre_moved).
LOCAL_SIGNIFICANCE = 1e-3
# A dot whose local fit was taken is fitted locally again on a band (and a window) that
# reaches this far from its edge (px): the background's series across the band, 15 of
# its 24 parameters at 9 px radius, are pinned by more pixels. Beside the hot spot of
# calib_core.sim.scenes over 20 seeds, the two dots fitted locally went from 1.51 and
# 1.68 times the Cramer-Rao bound to 1.26 and 1.38 (10 and 12 px: no better). The plain
# fits stay at EDGE_BAND_PX: with every band at 8 px, a dot 40 px from the highlight took
# more of its tail into its flat pixels (1.43 -> 1.70x).
LOCAL_BAND_PX = 8.0
# The cross fit gives up after this many model evaluations (see fit_cross).
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
        with more Mark-shaped blobs; setting it saves that look: 0.06 ms a 640 x 480
        frame of 9 dots, 0.13 ms of 81, where one mask decides, as it does for dots on an
        even background).
    min_snr : float
        Minimum fitted contrast over the image noise sigma.
    border_margin_px : float
        A candidate closer than this to the image border is reported as clipped.
    box_aperture_below_blur_px : float
        Dots whose optical blur sigma (px) is under this, as their start reads it or
        their fit through the fold finds it (then fitted again), are fitted with the
        pixel's 1 px box as it is, at about 1.3 times the fit's cost a pixel (11 against
        9 ns); blurrier dots with the box folded into the blur as a Gaussian. The fold
        moves a centre by up to 0.016 px at blur 0, 0.003 px at 0.3 px, 8e-4 px at
        0.5 px and 3.5e-4 px at 0.7 px, where the box model errs as much (the straight
        edge's curvature on small ellipses; bench_results/results.md, third table).
        ``inf``: always the box; 0: never.
    """

    min_size_px: float = 2.5
    max_size_px: float = 120.0
    polarity: str = 'auto'
    min_snr: float = 6.0
    border_margin_px: float = 1.0
    box_aperture_below_blur_px: float = 0.65

    def __post_init__(self):
        if not 0 < self.min_size_px < self.max_size_px:
            raise InvalidInputError('need 0 < min_size_px < max_size_px')
        if self.polarity not in ('auto', 'dark', 'bright'):
            raise InvalidInputError(f'polarity must be auto, dark or bright, not {self.polarity!r}')
        if self.min_snr <= 0:
            raise InvalidInputError('min_snr must be positive')
        if not self.box_aperture_below_blur_px >= 0:
            raise InvalidInputError('box_aperture_below_blur_px must be >= 0 (px; inf for '
                                    'always)')


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
        return float(largest_sigma(self.covariance))


def largest_sigma(covariance):
    """Largest 1-sigma axes (...,) of centre covariances (..., 2, 2), px^2 -> px: the
    square root of the larger eigenvalue, in closed form (eigvalsh costs 10 us a call)."""
    uu, uv, vv = covariance[..., 0, 0], covariance[..., 0, 1], covariance[..., 1, 1]
    return np.sqrt(0.5 * (uu + vv) + np.hypot(0.5 * (uu - vv), uv))


@dataclass
class Detection:
    """All Marks found in an image and the candidates rejected, with reasons."""

    marks: list[Mark]
    rejected: list[str] = field(default_factory=list)
    noise_sigma: float = 0.0
