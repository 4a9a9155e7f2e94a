"""Camera intrinsics and lens distortion with OpenCV (Zhang's method), from correspondences
or from images of chessboards and circle grids."""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calib_core.checks import MAX_POSITION_M
from calib_core.datasets import read_columns, write_columns
from calib_core.description import LENGTH_UNITS, si_per_unit
from calib_core.errors import CalibrationError, DetectionError, InvalidInputError
from calib_core.files import read_yaml
from calib_core.marks import detect_marks
from calib_core.marks.pixels import read_grey_image
from calib_core.schema import Column, Schema

INTRINSIC_NAMES = ('fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2', 'k3')


@dataclass(frozen=True)
class View:
    """Planar target points (m, (n, 2), z = 0) and their pixels (px, (n, 2)); ``label``:
    the view's id in the data it was read from ('' where it has none)."""

    model: np.ndarray
    pixels: np.ndarray
    label: str = ''


# The correspondences CSV, declared: target points on a plate of any size here.
CORRESPONDENCE_SCHEMA = Schema(tuple(
    Column(n, 'm', -MAX_POSITION_M, MAX_POSITION_M, f'target point {n[-1]}')
    for n in ('model_x', 'model_y')))


def read_correspondences(path, length_unit: str = 'm') -> list[View]:
    """Views from a CSV with columns view, model_x, model_y (m, or ``length_unit`` of
    calib_core.description.LENGTH_UNITS), u, v (px). A view is named by a number (views
    in its order) or by any text, such as its image's file name (views in the order they
    first appear)."""
    c = read_columns(path, ['view', 'model_x', 'model_y', 'u', 'v'], labels=('view',))
    per_unit = si_per_unit(length_unit, LENGTH_UNITS, f'{path}: the length unit')
    c['model_x'], c['model_y'] = c['model_x'] * per_unit, c['model_y'] * per_unit
    CORRESPONDENCE_SCHEMA.check(c, path)
    names = c['view']
    if not all(names):
        line = int(np.argmin(names.astype(bool))) + 2
        raise InvalidInputError(f'{path} line {line}: the view is not named')
    try:
        keys = names.astype(float)
        numbered = bool(np.all(np.isfinite(keys)))
    except ValueError:
        numbered = False
    if numbered:
        order = np.unique(keys)
        labels = [f'{n:g}' for n in order]
    else:
        keys = names
        order = labels = [names[k] for k in np.sort(np.unique(names, return_index=True)[1])]
    views = []
    for key, label in zip(order, labels):
        k = keys == key
        views.append(View(np.stack([c['model_x'][k], c['model_y'][k]], 1),
                          np.stack([c['u'][k], c['v'][k]], 1), label))
    return views


def write_correspondences(path, views: list[View]) -> None:
    """The CSV :func:`read_correspondences` reads (view, model_x, model_y in m, u, v in px)."""
    write_columns(path, ['view', 'model_x', 'model_y', 'u', 'v'],
                  [np.concatenate([np.full(len(v.model), k) for k, v in enumerate(views)]),
                   np.concatenate([v.model for v in views]),
                   np.concatenate([v.pixels for v in views])])


def infer_image_size(views: list[View]) -> tuple[int, int]:
    """A guess of (width, height) in px: the smallest image that holds every point."""
    allp = np.concatenate([v.pixels for v in views])
    return int(np.ceil(allp[:, 0].max() + 1)), int(np.ceil(allp[:, 1].max() + 1))


@dataclass(frozen=True)
class IntrinsicsResult:
    camera_matrix: np.ndarray
    distortion: np.ndarray
    rms_px: float
    per_view_rms_px: np.ndarray
    std_devs: dict
    image_size: tuple[int, int]
    fixed: dict = field(default_factory=dict)    # name -> why it was not estimated

    def report(self) -> dict:
        k, d = self.camera_matrix, self.distortion.ravel()
        values = dict(zip(INTRINSIC_NAMES, [k[0, 0], k[1, 1], k[0, 2], k[1, 2], *d[:5]]))
        return {'parameters': {n: float(v) for n, v in values.items()},
                'std_devs': self.std_devs,
                'units': {n: 'px' if n in ('fx', 'fy', 'cx', 'cy') else '1' for n in INTRINSIC_NAMES},
                'rms_reprojection_px': self.rms_px,
                'per_view_rms_px': self.per_view_rms_px.tolist(),
                'image_size': list(self.image_size), 'num_views': len(self.per_view_rms_px),
                'fixed': dict(self.fixed)}


SUSPECT_VIEW_RATIO = 3.0
"""A view whose reprojection RMS is over this many times the median over the views is
suspect: on the real sets in test/data/measured the views of a set lie within 1.4x and
1.7x of their median, and a view whose grid the detector ordered wrongly at 12.8x."""


def suspect_views(per_view_rms_px) -> np.ndarray:
    """Indices of the views whose reprojection RMS (px, one per view) exceeds
    SUSPECT_VIEW_RATIO times the median over the views; none below 4 views, where a
    median says little."""
    rms = np.asarray(per_view_rms_px, float)
    if rms.size < 4:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(rms > SUSPECT_VIEW_RATIO * np.median(rms))


def calibrate_intrinsics(views: list[View], image_size: tuple[int, int],
                         distortion: bool = True,
                         focal_px: float | None = None,
                         radial_only: bool = False) -> IntrinsicsResult:
    """Pinhole intrinsics (and k1, k2, p1, p2, k3 if ``distortion``) by cv2.calibrateCameraExtended.

    ``radial_only`` keeps the distortion to k1, k2 (p1 = p2 = k3 = 0): the model BoofCV and
    many lens data sheets use, and the one to fit when the views are too few to separate
    tangential terms from a shifted principal point.

    ``focal_px`` fixes fx = fy at that value (px), the principal point at the image centre
    and k3 at 0: for views taken square to the plate (a machine camera over a plate), where
    the focal length trades exactly against the plate distance and the principal point
    against a tilt of the plate, so only the distortion is determined (relative to the
    image centre; k1, k2 scale with focal_px squared, the distortion in px does not).

    Raises CalibrationError with fewer than 3 views or 6 points in a view."""
    if len(views) < 3:
        raise CalibrationError(f'intrinsics need at least 3 views of the plane at different '
                               f'tilts; got {len(views)}')
    for k, v in enumerate(views):
        if len(v.model) < 6:
            raise CalibrationError(f'view {k} has {len(v.model)} points; at least 6 are needed')
        if not (np.all(np.isfinite(v.model)) and np.all(np.isfinite(v.pixels))):
            raise InvalidInputError(f'view {k} has NaN or infinite coordinates')
    objects = [np.hstack([v.model, np.zeros((len(v.model), 1))]).astype(np.float32) for v in views]
    images = [v.pixels.reshape(-1, 1, 2).astype(np.float32) for v in views]
    flags = 0 if distortion else (cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
                                  | cv2.CALIB_ZERO_TANGENT_DIST)
    if radial_only:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    guess = None
    if focal_px is not None:
        if not (np.isfinite(focal_px) and focal_px > 0):
            raise InvalidInputError(f'focal_px must be a positive number of px, not {focal_px}')
        guess = np.array([[focal_px, 0, (image_size[0] - 1) / 2],
                          [0, focal_px, (image_size[1] - 1) / 2], [0, 0, 1.0]])
        flags |= (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_FOCAL_LENGTH
                  | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_K3)
    # With several threads OpenCV's reductions make the last digits depend on scheduling
    # (k1 of the chessboard photos varied by 6e-10 between runs). On one thread a replay
    # from a bag reproduces the live run exactly.
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rms, k, d, _, _, std_intr, _, per_view = cv2.calibrateCameraExtended(
            objects, images, tuple(image_size), guess, None, flags=flags)
    finally:
        cv2.setNumThreads(threads)
    fixed = {}
    if radial_only:
        fixed.update(dict.fromkeys(('p1', 'p2', 'k3'), 'radial k1, k2 only asked for'))
    if not distortion:
        fixed.update(dict.fromkeys(('k1', 'k2', 'p1', 'p2', 'k3'), 'no distortion asked for'))
    if focal_px is not None:
        fixed.update(dict.fromkeys(('fx', 'fy'), 'views square to the plate: the focal '
                                   'length trades against the plate distance (given)'))
        fixed.update(dict.fromkeys(('cx', 'cy'), 'views square to the plate: the principal '
                                   'point trades against a tilt (image centre)'))
        fixed.setdefault('k3', 'views square to the plate: kept to k1, k2')
    std = dict(zip(INTRINSIC_NAMES, std_intr.ravel()[:9].astype(float).tolist()))
    std.update(dict.fromkeys(fixed, 0.0))
    return IntrinsicsResult(k, d.ravel(), float(rms), per_view.ravel(), std, tuple(image_size),
                            fixed)


def camera_arrays(parameters: dict) -> tuple[np.ndarray, np.ndarray]:
    """(camera matrix (3, 3), distortion (5,) k1, k2, p1, p2, k3) from a dict with the
    names of ``IntrinsicsResult.report()['parameters']`` or read_boofcv_intrinsics."""
    p = parameters
    return (np.array([[p['fx'], 0.0, p['cx']], [0.0, p['fy'], p['cy']], [0.0, 0.0, 1.0]]),
            np.array([p[name] for name in ('k1', 'k2', 'p1', 'p2', 'k3')]))


def read_boofcv_intrinsics(path) -> dict:
    """fx, fy, cx, cy (px) and k1, k2, p1, p2, k3 from a BoofCV ``intrinsic.yaml``
    (pinhole_radial_tangential; missing radial terms are 0)."""
    try:
        content = read_yaml(path, 'BoofCV intrinsics (intrinsic.yaml)')
        pinhole = content['pinhole']
        distortion = content.get('radial_tangential') or {}
        radial = list(distortion.get('radial') or []) + [0.0, 0.0, 0.0]
        values = {'fx': pinhole['fx'], 'fy': pinhole['fy'], 'cx': pinhole['cx'],
                  'cy': pinhole['cy'], 'k1': radial[0], 'k2': radial[1],
                  'p1': distortion.get('t1', 0.0), 'p2': distortion.get('t2', 0.0),
                  'k3': radial[2]}
        values = {name: float(value) for name, value in values.items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InvalidInputError(f'{path}: not BoofCV pinhole intrinsics ({exc})') from exc
    if not all(np.isfinite(list(values.values()))):
        raise InvalidInputError(f'{path}: intrinsics with NaN or infinite values')
    return values


def reprojection_errors(camera_matrix, distortion, views: list[View]) -> list[np.ndarray]:
    """Per view, the (n, 2) px residuals of its points after solving its pose (solvePnP,
    IPPE then Levenberg-Marquardt) with the given intrinsics: how well intrinsics that were
    not fitted to these views explain them."""
    camera_matrix = np.asarray(camera_matrix, float)
    distortion = np.asarray(distortion, float).ravel()
    errors = []
    for k, view in enumerate(views):
        if len(view.model) < 4:
            raise CalibrationError(f'view {k} has {len(view.model)} points; a pose needs 4')
        points = np.hstack([view.model, np.zeros((len(view.model), 1))])
        found, rvec, tvec = cv2.solvePnP(points, view.pixels, camera_matrix, distortion,
                                         flags=cv2.SOLVEPNP_IPPE)
        if not found:
            raise CalibrationError(f'no pose found for view {k}')
        rvec, tvec = cv2.solvePnPRefineLM(points, view.pixels, camera_matrix, distortion,
                                          rvec, tvec)
        projected, _ = cv2.projectPoints(points, rvec, tvec, camera_matrix, distortion)
        errors.append(projected.reshape(-1, 2) - view.pixels)
    return errors


def rms_px(errors: list[np.ndarray]) -> float:
    """Root mean square length (px) of residual vectors pooled over views."""
    every = np.concatenate(errors)
    return float(np.sqrt(np.mean(np.sum(every ** 2, axis=1))))


def dot_grid_view(pixels, pitch: float, pitch_px: float, angle: float = 0.0,
                  centre=(319.5, 239.5)) -> View:
    """One view of a square dot grid: each dot's plate coordinates (m), counted in pitches
    from the dot nearest ``centre`` (px) along the image axes turned by ``angle`` (rad).

    ``pitch_px`` (px per pitch) and ``angle`` need only be good to a few percent and
    degrees: a dot is assigned to the nearest lattice node, and two dots on one node are an
    error (the grid is not what was assumed).

    Parameters
    ----------
    pixels : array_like (n, 2)
        Dot centres, px.
    pitch : float
        Dot pitch on the plate, m.
    """
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if not (pitch > 0 and pitch_px > 0):
        raise InvalidInputError('pitch and pitch_px must be positive')
    if len(pixels) < 6 or not np.all(np.isfinite(pixels)):
        raise CalibrationError(f'a dot-grid view needs at least 6 finite dots, got {len(pixels)}')
    origin = pixels[np.argmin(np.linalg.norm(pixels - np.asarray(centre, float), axis=1))]
    c, s = np.cos(angle), np.sin(angle)
    offsets = (pixels - origin) @ np.array([[c, -s], [s, c]]) / pitch_px
    index = np.round(offsets)
    if np.abs(offsets - index).max() > 0.3:
        raise CalibrationError(f'dots lie up to {np.abs(offsets - index).max():.2f} pitch from '
                               'the assumed grid: check the pitch and the pixel size')
    if len(np.unique(index, axis=0)) < len(index):
        raise CalibrationError('two dots fall on one grid node: check the pitch and pixel size')
    return View(index * pitch, pixels)


def distortion_from_dot_views(dots_per_view, setup: dict) -> IntrinsicsResult:
    """Lens distortion from views square onto a dot plate, as ``vision_calibrator`` does it
    live and ``machine-align calibrate camera --bag`` offline.

    Parameters
    ----------
    dots_per_view : list of array_like (n, 2)
        Dot centres per view, px.
    setup : dict
        ``pitch_m`` (dot pitch, m), ``pitch_px`` (nominal px per pitch), ``focal_px`` (the
        lens's focal length, px) and ``image_size`` ([width, height], px).
    """
    missing = [k for k in ('pitch_m', 'pitch_px', 'focal_px', 'image_size') if k not in setup]
    if missing:
        raise InvalidInputError(f'dot-plate setup lacks {", ".join(missing)}')
    size = tuple(int(v) for v in setup['image_size'])
    centre = ((size[0] - 1) / 2, (size[1] - 1) / 2)
    views = [dot_grid_view(dots, float(setup['pitch_m']), float(setup['pitch_px']),
                           centre=centre) for dots in dots_per_view]
    return calibrate_intrinsics(views, size, focal_px=float(setup['focal_px']))


def target_points(kind: str, cols: int, rows: int, spacing: float) -> np.ndarray:
    """Model points (m, (cols*rows, 2)) of a chessboard's inner corners or a circle grid,
    in the order OpenCV's finders return them."""
    if kind == 'acircles':
        return np.array([((2 * i + j % 2) * spacing, j * spacing)
                         for j in range(rows) for i in range(cols)], float)
    return np.array([(i * spacing, j * spacing) for j in range(rows) for i in range(cols)], float)


def find_target(image: np.ndarray, kind: str, cols: int, rows: int) -> np.ndarray:
    """Pixels (px, (n, 2)) of the target's points in a grey image (8 or 16 bits, or float).

    ``kind``: ``chessboard`` (inner corners, refined by cornerSubPix), ``circles``
    (symmetric grid) or ``acircles`` (asymmetric grid; both: the centres of our
    detector's Marks, see _circle_grid). Raises DetectionError if not found."""
    if kind == 'chessboard':
        # OpenCV finds a board in 8 bits only; the corners are refined on every bit.
        eight = image if image.dtype == np.uint8 else cv2.normalize(
            image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
        found, corners = cv2.findChessboardCorners(
            eight, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if found:
            corners = cv2.cornerSubPix(image if image.dtype == np.uint8
                                       else image.astype(np.float32), corners, (5, 5), (-1, -1),
                                       (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
    elif kind in ('circles', 'acircles'):
        return _circle_grid(image, kind, cols, rows)
    else:
        raise InvalidInputError(f'unknown target {kind!r}; use chessboard, circles or acircles')
    if not found:
        raise DetectionError(f'{kind} {cols}x{rows} not found in the image')
    return corners.reshape(-1, 2).astype(float)


def _circle_grid(image, kind, cols, rows):
    """A circle grid's dot centres from our Mark detector (sub-pixel, ellipses where the
    plate is tilted), put in OpenCV's grid order.

    findCirclesGrid orders what its blob detector finds, and on the photos it takes
    centroids of thresholded blobs, and misses grids seen steeply (2 of the 6 regular-grid
    photos). Here it orders a clean drawing of our Marks alone, first with its grid
    search, then with its clustering (which copes with strong perspective), and each
    grid point is the Mark drawn there."""
    marks = detect_marks(image, shape='circle').marks
    centres = np.array([(m.u, m.v) for m in marks])
    # 4 fractional bits: cv2.circle draws at 1/16 px.
    clean = np.full(image.shape[:2], 255, np.uint8)
    for mark in marks:
        cv2.circle(clean, (int(round(mark.u * 16)), int(round(mark.v * 16))),
                   int(round(np.clip(mark.size, 4.0, 40.0) * 16)), 0, -1, cv2.LINE_AA, 4)
    grid = cv2.CALIB_CB_SYMMETRIC_GRID if kind == 'circles' else cv2.CALIB_CB_ASYMMETRIC_GRID
    for flags in (grid, grid | cv2.CALIB_CB_CLUSTERING):
        found, corners = cv2.findCirclesGrid(clean, (cols, rows), flags=flags)
        if found:
            break
    else:
        raise DetectionError(f'{kind} {cols}x{rows} not found among the {len(marks)} dots')
    corners = corners.reshape(-1, 2)
    distances = np.linalg.norm(corners[:, None, :] - centres[None], axis=2)
    nearest = distances.argmin(axis=1)
    # Each grid point is a drawn disk's centre, found again within a pixel.
    if (np.unique(nearest).size != nearest.size
            or distances[np.arange(nearest.size), nearest].max() > 1.0):
        raise DetectionError(f'{kind} {cols}x{rows}: the grid found does not match the dots')
    return centres[nearest]


def read_images(paths: list, measure):
    """(results, image_size, failures): ``measure(image)`` for each grey image file of the
    same size. Unreadable images, images of another size than the first, and images
    where ``measure`` raises DetectionError are listed in ``failures`` as (path, reason),
    not fatal; results are (path, measurement) pairs."""
    results, failures, size = [], [], None
    for path in paths:
        image = read_grey_image(path)
        if image is None:
            failures.append((str(path), 'not a readable image'))
            continue
        if size is not None and (image.shape[1], image.shape[0]) != size:
            failures.append((str(path), f'size {image.shape[::-1]} differs from {size}'))
            continue
        size = (image.shape[1], image.shape[0])
        try:
            results.append((str(path), measure(image)))
        except DetectionError as exc:
            failures.append((str(path), str(exc)))
    return results, size, failures


def views_from_images(paths: list, kind: str, cols: int, rows: int, spacing: float):
    """(views, image_size, failures) from image files; unreadable or target-less images
    are listed in ``failures`` with the reason, not fatal."""
    model = target_points(kind, cols, rows, spacing)
    found, size, failures = read_images(
        paths, lambda image: View(model, find_target(image, kind, cols, rows)))
    return [view for _, view in found], size, failures
