"""Random-dot (Uchiya) markers: find the dots in a photo and tell which marker each belongs to.

A random-dot marker carries no code; a dot is recognised by the arrangement of its
neighbours. This is LLAH, locally likely arrangement hashing (Uchiya and Saito, "Random dot
markers", IEEE VR 2011): around each dot, its ``neighbours`` nearest dots are taken in
angular order; every subset of ``combination`` of them gives affine-invariant ratios of
triangle areas, quantised into ``levels`` equally populated bins and hashed. A dot in a
photo votes for the marker dots that share its hashes, and each marker's votes are checked
by a RANSAC homography (OpenCV) and completed by projecting the marker's other dots.

The photo is read as a view of a plane, so what comes out is a set of correspondences per
marker (model points in m, pixels in px) for :func:`calibrate_intrinsics` or solvePnP.

Pixels follow OpenCV's convention: the centre of the top-left pixel is (0, 0).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from calib_core.errors import DetectionError, InvalidInputError
from calib_core.files import read_yaml
from printer_alignment.core.camera_calibration import View, read_images

UNITS_M = {'m': 1.0, 'cm': 1e-2, 'mm': 1e-3}


def load_uchiya_markers(path) -> dict[int, np.ndarray]:
    """Marker dot positions from a BoofCV ``descriptions.yaml``.

    Returns
    -------
    dict
        marker id (its index in the file, the number printed beside it) -> (n, 2) dot
        centres in m, in the marker's frame.

    Raises
    ------
    InvalidInputError
        Unreadable file, unknown units, or a marker that is not a list of finite (x, y).
    """
    content = read_yaml(path, 'random-dot marker descriptions (BoofCV YAML)')
    if not isinstance(content, dict) or not isinstance(content.get('markers'), list):
        raise InvalidInputError(f'{path}: no "markers" list (expected BoofCV Uchiya descriptions)')
    units = content.get('units', 'm')
    if units not in UNITS_M:
        raise InvalidInputError(f'{path}: units {units!r} not one of {sorted(UNITS_M)}')
    markers = {}
    for marker_id, dots in enumerate(content['markers']):
        try:
            xy = np.asarray(dots, dtype=float) * UNITS_M[units]
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f'{path}: marker {marker_id} is not a list of (x, y)') from exc
        if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
            raise InvalidInputError(f'{path}: marker {marker_id} is not a list of finite (x, y)')
        markers[marker_id] = xy
    if not markers:
        raise InvalidInputError(f'{path}: the markers list is empty')
    return markers


@dataclass(frozen=True)
class DotConfig:
    """How dots are found in a photo (px unless stated).

    Attributes
    ----------
    block_px : int
        Side of the local-mean window of the adaptive threshold (odd); a few dot spacings,
        so uneven light and shadows do not matter.
    offset : float
        How much darker than the local mean a pixel must be to count as dot, grey levels.
    max_diameter_px : float
        Larger blobs are not dots.
    min_contrast : float
        Dot depth below the paper around it, as a fraction of the paper's grey level.
    max_background_spread : float
        Standard deviation of the ring around a dot over its mean: printed dots sit on
        uniform paper, texture (asphalt, carpet, a wall) does not.
    """

    block_px: int = 31
    offset: float = 10.0
    max_diameter_px: float = 25.0
    min_contrast: float = 0.25
    max_background_spread: float = 0.15

    def __post_init__(self):
        if self.block_px < 3 or self.block_px % 2 == 0:
            raise InvalidInputError(f'block_px must be an odd number >= 3, not {self.block_px}')
        if not (self.max_diameter_px > 2 and 0 < self.min_contrast < 1
                and self.max_background_spread > 0):
            raise InvalidInputError('need max_diameter_px > 2, 0 < min_contrast < 1 and '
                                    'max_background_spread > 0')


def find_dots(image, config: DotConfig = DotConfig()) -> np.ndarray:
    """Centres (px, (n, 2)) of dark round dots on light paper in a grey photo.

    Adaptive threshold and connected components (OpenCV); each blob must be round and
    filled, clearly darker than the paper around it, and sit on uniform paper. The centre
    is the intensity-weighted centroid of the blob's darkness over its bounding box plus
    one pixel, which keeps the partial pixels of the edge.

    Raises
    ------
    InvalidInputError
        Not a 2-D uint8 image.
    DetectionError
        No dot found.
    """
    gray = np.asarray(image)
    if gray.ndim != 2 or gray.dtype != np.uint8 or gray.size == 0:
        raise InvalidInputError(f'find_dots needs a non-empty 2-D uint8 image, got '
                                f'{gray.dtype} {gray.shape}')
    smoothed = cv2.GaussianBlur(gray, (3, 3), 0.8)
    mask = cv2.adaptiveThreshold(smoothed, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                 cv2.THRESH_BINARY_INV, config.block_px, config.offset)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    pixels = gray.astype(np.float64)
    height, width = gray.shape
    centres = []
    for label in range(1, count):
        x0, y0, w, h, area = stats[label]
        if area < 4 or max(w, h) > config.max_diameter_px:
            continue
        if max(w, h) / min(w, h) > 1.6 or area / (w * h) < 0.55:
            continue
        pad = max(w, h) // 2 + 2
        r0, r1 = max(y0 - pad, 0), min(y0 + h + pad, height)
        c0, c1 = max(x0 - pad, 0), min(x0 + w + pad, width)
        window = labels[r0:r1, c0:c1]
        patch = pixels[r0:r1, c0:c1]
        ring = patch[window == 0]
        if ring.size < 8:
            continue
        paper = float(np.median(ring))
        if paper - patch[window == label].min() < config.min_contrast * paper:
            continue
        if ring.std() > config.max_background_spread * paper:
            continue
        b0, b1 = max(y0 - 1, 0), min(y0 + h + 1, height)
        a0, a1 = max(x0 - 1, 0), min(x0 + w + 1, width)
        weight = np.clip(paper - pixels[b0:b1, a0:a1], 0.0, None)
        vv, uu = np.mgrid[b0:b1, a0:a1]
        centres.append((float((weight * uu).sum() / weight.sum()),
                        float((weight * vv).sum() / weight.sum())))
    if not centres:
        raise DetectionError('no dot found in the image')
    return np.array(centres)


@dataclass(frozen=True)
class LlahConfig:
    """LLAH matching settings.

    Attributes
    ----------
    neighbours : int
        Nearest dots around each dot that describe it.
    combination : int
        Size of the subsets of those neighbours hashed; ``neighbours - combination`` of the
        neighbours may be missing (occluded) or foreign (clutter, another marker).
    levels : int
        Quantisation levels per invariant.
    min_votes : int
        Votes a photo dot needs for its best marker dot to count.
    inlier_px : float
        Distance (px) within which a projected marker dot claims a photo dot.
    min_dots : int
        Dots a marker must match to be reported (against chance matches in clutter).
    """

    neighbours: int = 9
    combination: int = 6
    levels: int = 10
    min_votes: int = 2
    inlier_px: float = 3.0
    min_dots: int = 12

    def __post_init__(self):
        if not 4 <= self.combination <= self.neighbours:
            raise InvalidInputError('need 4 <= combination <= neighbours')
        if self.levels < 2:
            raise InvalidInputError('levels must be at least 2')
        invariants = len(list(itertools.combinations(range(self.combination), 4)))
        if invariants * np.log2(self.levels) > 62:
            raise InvalidInputError(f'{invariants} invariants at {self.levels} levels do '
                                    f'not fit a 64-bit hash; use fewer levels or a smaller '
                                    f'combination')
        if self.min_votes < 1 or self.inlier_px <= 0 or self.min_dots < 5:
            raise InvalidInputError('need min_votes >= 1, inlier_px > 0 and min_dots >= 5')


@dataclass(frozen=True)
class MarkerMatch:
    """One marker seen in a photo.

    Attributes
    ----------
    marker_id : int
    marker_dots : ndarray, shape (k,)
        Indices of the matched dots in the marker's description.
    photo_dots : ndarray, shape (k,)
        Indices of the same dots in the photo's dot list.
    model : ndarray, shape (k, 2)
        Matched dot centres in the marker frame, m.
    pixels : ndarray, shape (k, 2)
        Their centres in the photo, px.
    homography : ndarray, shape (3, 3)
        Marker plane (m) to photo (px), fitted to all matched dots.
    rms_px : float
        RMS distance of the matched dots from the homography's projection, px.
    """

    marker_id: int
    marker_dots: np.ndarray
    photo_dots: np.ndarray
    model: np.ndarray
    pixels: np.ndarray
    homography: np.ndarray
    rms_px: float


def _angular_neighbours(points: np.ndarray, count: int) -> np.ndarray:
    """(n, count) indices of each point's nearest ``count`` points, sorted by angle."""
    _, index = cKDTree(points).query(points, count + 1)
    index = index[:, 1:]
    offset = points[index] - points[:, None]
    order = np.argsort(np.arctan2(offset[..., 1], offset[..., 0]), axis=1)
    return np.take_along_axis(index, order, axis=1)


def _invariant_triples(config: LlahConfig):
    """Which neighbour triangles make each invariant.

    Invariant (combination c, starting neighbour s, quadruple a < b < c' < d of the
    combination) is area(a, c', d) / area(a, b, c'), Uchiya's affine invariant. Each area is
    a signed triangle of three of the ``neighbours`` points; returned as indices into
    ``combinations(range(neighbours), 3)`` with the sign of the permutation, shape
    (combos, combination, quads) each, for numerator and denominator."""
    table = np.zeros((config.neighbours,) * 3, int)
    for k, triple in enumerate(itertools.combinations(range(config.neighbours), 3)):
        table[triple] = k
    combos = np.array(list(itertools.combinations(range(config.neighbours), config.combination)))
    quads = np.array(list(itertools.combinations(range(config.combination), 4)))
    m = config.combination
    starts = (np.arange(m)[None] + np.arange(m)[:, None]) % m          # (rotations, m)
    roles = combos[:, starts][:, :, quads]                              # (C, R, Q, 4)

    def lookup(corners):
        ordered = np.sort(corners, axis=-1)
        index = table[ordered[..., 0], ordered[..., 1], ordered[..., 2]]
        # A signed area flips with each swap of two corners: the parity of the inversions.
        inversions = sum((corners[..., i] > corners[..., j]).astype(int)
                         for i, j in ((0, 1), (0, 2), (1, 2)))
        return index, 1.0 - 2.0 * (inversions % 2)
    return lookup(roles[..., [0, 2, 3]]), lookup(roles[..., [0, 1, 2]])


class LlahIndex:
    """Hash table of every dot of a set of markers; :meth:`match` finds them in a photo."""

    def __init__(self, markers: dict[int, np.ndarray], config: LlahConfig = LlahConfig()):
        self.config = config
        self.markers = markers
        self._triples = np.array(list(itertools.combinations(range(config.neighbours), 3)))
        self._numerator, self._denominator = _invariant_triples(config)
        ids, dots, invariants = [], [], []
        for marker_id, xy in markers.items():
            if len(xy) <= config.neighbours:
                raise InvalidInputError(f'marker {marker_id} has {len(xy)} dots; LLAH with '
                                        f'{config.neighbours} neighbours needs more')
            # One rotation suffices here: the photo side tries every starting neighbour.
            invariants.append(self._invariants(xy, rotations=1)[:, :, 0])
            ids += [marker_id] * len(xy)
            dots += list(range(len(xy)))
        self._dot_marker = np.array(ids)
        self._dot_index = np.array(dots)
        every = np.concatenate(invariants)                      # (dots, combos, invariants)
        inner = np.linspace(0, 1, config.levels + 1)[1:-1]
        self._edges = np.quantile(every[np.isfinite(every)], inner)
        keys = self._keys(every).reshape(len(every), -1)       # (dots, combos)
        self._key_dot = np.repeat(np.arange(len(every)), keys.shape[1])
        keys = keys.ravel()
        order = np.argsort(keys, kind='stable')
        self._keys_sorted, self._key_dot = keys[order], self._key_dot[order]

    def _invariants(self, points: np.ndarray, rotations: int) -> np.ndarray:
        """(n, combos, rotations, quads) arctan of affine area ratios around each point."""
        near = points[_angular_neighbours(points, self.config.neighbours)]   # (n, N, 2)
        p, q, r = (near[:, self._triples[:, k]] for k in range(3))            # (n, T, 2)
        area = ((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))          # (n, T)
        (num, num_sign), (den, den_sign) = self._numerator, self._denominator
        with np.errstate(divide='ignore', invalid='ignore'):
            return np.arctan((num_sign[:, :rotations] * area[:, num[:, :rotations]])
                             / (den_sign[:, :rotations] * area[:, den[:, :rotations]]))

    def _keys(self, invariants: np.ndarray) -> np.ndarray:
        levels = np.searchsorted(self._edges, np.nan_to_num(invariants, nan=0.0))
        weights = self.config.levels ** np.arange(levels.shape[-1], dtype=np.int64)
        return (levels.astype(np.int64) * weights).sum(axis=-1)

    def _votes(self, dots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each photo dot, its best marker dot (index into the table, or -1)."""
        keys = self._keys(self._invariants(dots, rotations=self.config.combination))
        keys = keys.reshape(len(dots), -1)
        lo = np.searchsorted(self._keys_sorted, keys, side='left')
        hi = np.searchsorted(self._keys_sorted, keys, side='right')
        hits = hi - lo
        photo = np.repeat(np.repeat(np.arange(len(dots)), keys.shape[1]), hits.ravel())
        starts = np.repeat(lo.ravel(), hits.ravel())
        within = np.arange(hits.sum()) - np.repeat(np.cumsum(hits.ravel()) - hits.ravel(),
                                                   hits.ravel())
        table_dot = self._key_dot[starts + within]
        pairs, votes = np.unique(photo * len(self._dot_marker) + table_dot, return_counts=True)
        photo_of, table_of = np.divmod(pairs, len(self._dot_marker))
        best = np.full(len(dots), -1)
        best_votes = np.zeros(len(dots), int)
        order = np.lexsort((-votes, photo_of))
        first = np.r_[True, photo_of[order][1:] != photo_of[order][:-1]]
        chosen = order[first]
        best[photo_of[chosen]] = table_of[chosen]
        best_votes[photo_of[chosen]] = votes[chosen]
        best[best_votes < self.config.min_votes] = -1
        return best, best_votes

    def match(self, dots) -> list[MarkerMatch]:
        """Markers seen among the photo's dots (px, (n, 2)), most dots first.

        Each photo dot belongs to at most one marker. Raises DetectionError if there are
        too few dots to describe, InvalidInputError on NaN or a wrong shape."""
        dots = np.asarray(dots, dtype=float)
        if dots.ndim != 2 or dots.shape[1] != 2 or not np.all(np.isfinite(dots)):
            raise InvalidInputError('dots must be a finite (n, 2) array of px')
        if len(dots) <= self.config.neighbours:
            raise DetectionError(f'{len(dots)} dots in the photo; LLAH needs more than '
                                 f'{self.config.neighbours}')
        best, _ = self._votes(dots)
        candidates = {}
        for photo_dot in np.flatnonzero(best >= 0):
            marker_id = int(self._dot_marker[best[photo_dot]])
            candidates.setdefault(marker_id, []).append((photo_dot, self._dot_index[best[photo_dot]]))
        tree = cKDTree(dots)
        claimed = np.zeros(len(dots), bool)
        found = []
        for marker_id, pairs in sorted(candidates.items(), key=lambda kv: -len(kv[1])):
            match = self._verify(marker_id, np.array(pairs), dots, tree, claimed)
            if match is not None:
                claimed[match.photo_dots] = True
                found.append(match)
        return sorted(found, key=lambda m: -len(m.marker_dots))

    def _verify(self, marker_id, pairs, dots, tree, claimed) -> MarkerMatch | None:
        """RANSAC homography on the voted pairs, then every marker dot that projects onto
        a free photo dot; None unless ``min_dots`` agree."""
        if len(pairs) < 5:
            return None
        model = self.markers[marker_id]
        homography, _ = cv2.findHomography(model[pairs[:, 1]], dots[pairs[:, 0]], cv2.RANSAC,
                                           self.config.inlier_px)
        for _ in range(2):
            if homography is None:
                return None
            projected = cv2.perspectiveTransform(model[None], homography)[0]
            distance, photo = tree.query(projected)
            ok = (distance < self.config.inlier_px) & ~claimed[photo]
            # A photo dot claimed by two marker dots belongs to neither.
            values, counts = np.unique(photo[ok], return_counts=True)
            ok &= ~np.isin(photo, values[counts > 1])
            if ok.sum() < self.config.min_dots:
                return None
            homography, _ = cv2.findHomography(model[ok], dots[photo[ok]], 0)
        if homography is None:
            return None
        projected = cv2.perspectiveTransform(model[ok][None], homography)[0]
        residual = projected - dots[photo[ok]]
        return MarkerMatch(marker_id, np.flatnonzero(ok), photo[ok], model[ok],
                           dots[photo[ok]], homography,
                           float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))))


@dataclass(frozen=True)
class MarkerPhoto:
    """The dots found in one photo (px, (n, 2)) and the markers matched among them."""

    path: str
    dots: np.ndarray
    matches: list[MarkerMatch] = field(default_factory=list)

    def views(self) -> list[View]:
        """One planar view per matched marker, for calibrate_intrinsics or solvePnP."""
        return [View(m.model, m.pixels) for m in self.matches]

    def summary(self) -> dict:
        return {'image': self.path, 'dots_found': len(self.dots),
                'markers': [{'id': m.marker_id, 'dots_matched': len(m.marker_dots),
                             'homography_rms_px': m.rms_px} for m in self.matches]}


def read_marker_photos(paths, index: LlahIndex, config: DotConfig = DotConfig()):
    """(photos, image_size, failures) for image files of random-dot markers.

    Unreadable photos, photos of another size than the first, and photos without dots are
    listed in ``failures`` as (path, reason) and skipped; a photo with dots but no marker
    is kept with no matches, so the caller can tell it was looked at."""
    def measure(image):
        dots = find_dots(image, config)
        return dots, index.match(dots)
    found, size, failures = read_images(paths, measure)
    return [MarkerPhoto(path, *measured) for path, measured in found], size, failures
