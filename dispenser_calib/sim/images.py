"""The dispenser's camera frames of the dot board, rendered: each dot's circle projected in
full perspective (the image of a circle under the board-to-image homography is an exact
ellipse, whose centre is not the image of the dot's centre), then through the lens
distortion, blurred and sampled by the exact renderer of :mod:`calib_core.sim.render`,
with sensor noise and 8-bit quantisation. Truth for tests and benches."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from calib_core.sim.render import MarkShape, coverage
from dispenser_calib.core.data import SHIPPED_BOARD, board_points
from dispenser_calib.core.model import DispenserModel, _camera_rows, project
from dispenser_calib.core.procedure import SHIPPED_WORKSPACE, Workspace

BACKGROUND, CONTRAST = 200.0, -150.0   # grey levels: a white board with dark dots
BLUR_SIGMA = 0.8        # px: the lens's point spread
EDGE = 6.0              # blur sigmas: beyond this from the ellipse's edge, coverage is 0 or 1


def _board_homography(model: DispenserModel, pose: np.ndarray) -> np.ndarray:
    """(3, 3) from board (x, y, 1) m to ideal (undistorted) pixels at ``pose``."""
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    camera = _camera_rows(model, corners, np.repeat(pose[None], 3, 0))
    plane = np.column_stack([camera[1] - camera[0], camera[2] - camera[0], camera[0]])
    return model.camera_matrix @ plane


def dot_ellipse(model: DispenserModel, pose: np.ndarray, centre: np.ndarray,
                radius: float = SHIPPED_BOARD.radius) -> MarkShape:
    """The image, in ideal pixels, of the board's circle of ``radius`` m about ``centre``
    (3,) m: its conic mapped by the homography, C' = H^-T C H^-1, as an ellipse's centre,
    mean radius, axis ratio and direction."""
    h = _board_homography(model, pose)
    x0, y0 = centre[:2]
    conic = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [-x0, -y0, x0 ** 2 + y0 ** 2 - radius ** 2]])
    inverse = np.linalg.inv(h)
    image = inverse.T @ conic @ inverse
    quadratic, linear = image[:2, :2], image[:2, 2]
    middle = -np.linalg.solve(quadratic, linear)
    level = -(image[2, 2] + linear @ middle)
    values, vectors = np.linalg.eigh(quadratic / level)
    minor, major = 1 / np.sqrt(values[1]), 1 / np.sqrt(values[0])
    angle = float(np.arctan2(vectors[1, 0], vectors[0, 0]))
    return MarkShape('circle', float(middle[0]), float(middle[1]), float(np.sqrt(major * minor)),
                     angle=angle, aspect=float(major / minor))


def _coverage(mark: MarkShape, ideal: np.ndarray) -> np.ndarray:
    """The renderer's exact coverage where the blurred edge is, 1 and 0 well inside and
    outside (EDGE blur sigmas from the edge): the quadrature only on the edge band."""
    c, s = np.cos(mark.angle), np.sin(mark.angle)
    du, dv = ideal[:, 0] - mark.u, ideal[:, 1] - mark.v
    root = np.sqrt(mark.aspect)
    major, minor = mark.size * root, mark.size / root
    radial = np.hypot((c * du + s * dv) / major, (-s * du + c * dv) / minor)
    band = EDGE * BLUR_SIGMA / minor
    out = (radial < 1 - band).astype(float)
    edge = np.abs(radial - 1) <= band
    out[edge] = coverage(mark, ideal[edge, 0], ideal[edge, 1], BLUR_SIGMA)
    return out


def render_board(model: DispenserModel, pose: np.ndarray, size, noise: float = 2.0,
                 seed: int = 0, occluded: tuple = (), displaced: dict | None = None,
                 centre_noise_px: float = 0.0,
                 workspace: Workspace = SHIPPED_WORKSPACE) -> np.ndarray:
    """The camera's 8-bit frame (height, width) of the ``workspace``'s board at ``pose``
    (5,): every dot
    whose ellipse lies inside the frame, rendered through the distortion, except the board
    indices in ``occluded``; the dots in ``displaced`` (index (i, j) -> (du, dv) px) drawn
    that far off (dust on the dot: a mis-detection); Gaussian noise of ``noise`` grey
    levels. Each dot is drawn ``centre_noise_px`` (1 sigma per axis, drawn per frame from
    ``seed``) off its true image: what the source's dot-centre noise (0.1 px) stands for,
    from print, illumination and focus, which a clean rendering alone does not have. Poses
    outside the ``workspace``'s strokes are refused."""
    workspace.check(pose)
    board = workspace.board
    width, height = (int(s) for s in size)
    frame = np.full((height, width), BACKGROUND)
    dots, indices = board_points(board)
    distorted = project(model, dots, pose[None])[0]
    k, distortion = model.camera_matrix, model.distortion
    hidden = {tuple(i) for i in occluded}
    jitter = np.random.default_rng(seed + 81).normal(0.0, centre_noise_px, (len(dots), 2))
    for point, index, (u, v), (du, dv) in zip(dots, indices, distorted, jitter):
        if tuple(index) in hidden or not np.isfinite(u):
            continue
        mark = dot_ellipse(model, pose, point, board.radius)
        mark = replace(mark, u=mark.u + du, v=mark.v + dv)
        shift = (displaced or {}).get(tuple(index))
        if shift is not None:
            mark = replace(mark, u=mark.u + shift[0], v=mark.v + shift[1])
            u, v = u + shift[0], v + shift[1]
        # The box holds the ellipse, the blur and the distortion's shift across the box.
        reach = 1.2 * mark.size * np.sqrt(mark.aspect) + EDGE * BLUR_SIGMA + 3
        rows = np.arange(max(int(v - reach), 0), min(int(v + reach) + 2, height))
        cols = np.arange(max(int(u - reach), 0), min(int(u + reach) + 2, width))
        if len(rows) == 0 or len(cols) == 0:
            continue
        vv, uu = np.meshgrid(rows, cols, indexing='ij')
        pixels = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
        ideal = cv2.undistortPointsIter(pixels.reshape(-1, 1, 2), k, np.r_[distortion, 0.0],
                                        None, k, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                                  40, 1e-10)).reshape(-1, 2)
        frame[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1] += (
            CONTRAST * _coverage(mark, ideal).reshape(uu.shape))
    frame += np.random.default_rng(seed + 80).normal(0, noise, frame.shape)
    return np.clip(np.round(frame), 0, 255).astype(np.uint8)
