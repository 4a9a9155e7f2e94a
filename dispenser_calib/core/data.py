"""The dispenser's observations: per image the commanded pose and the board dots seen.
The CSV contract of ``machine-align calibrate five-axis``: one row per dot and image,
``image`` (a name), ``x``, ``y``, ``z`` (commanded linear axes, m), ``a``, ``c`` (commanded
rotary axes, rad, the table's right-hand rotations about +X and +Z), ``i``, ``j`` (the
dot's indices on the board, centred), ``u``, ``v`` (its centre in px, OpenCV: the
top-left pixel's centre is (0, 0)). The board's dots lie at (i, j, 0) x pitch in its own
frame, each a circle of the board's dot radius (:class:`Board`; the shipped one's by
default, a machine description's for a user's)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.errors import CalibrationError, InvalidInputError
from calib_core.files import read_csv_rows
from calib_core.schema import Column, Schema
from calib_core.storage import write_atomic

COLUMNS = ('image', 'x', 'y', 'z', 'a', 'c', 'i', 'j', 'u', 'v')


@dataclass(frozen=True)
class Board:
    """The dot board the camera calibrates on: ``dots`` along x and y, their ``pitch`` (m)
    and each dot's ``radius`` (m); the shipped simulated board by default (11 x 9 dots of
    0.8 mm at 2 mm)."""

    dots: tuple = (11, 9)
    pitch: float = 2e-3
    radius: float = 0.4e-3

    def __post_init__(self):
        """Refuse a board the calibration cannot name or whose dots touch.

        Raises
        ------
        InvalidInputError"""
        if len(self.dots) != 2 or any(int(n) != n or n < 3 for n in self.dots):
            raise InvalidInputError(f'dots must be two whole numbers of at least 3 (along x '
                                    f'and y: a board has at least 3 whole dots a side), not '
                                    f'{self.dots!r}')
        if not (np.isfinite(self.pitch) and 0 < self.radius < self.pitch / 2):
            raise InvalidInputError(f'dot_radius_m {self.radius:g} must be under half the '
                                    f'pitch_m {self.pitch:g} (the dots apart)')


SHIPPED_BOARD = Board()


def board_as_dict(board: Board) -> dict:
    """``board`` as a report or a description holds it (m)."""
    return {'dots': list(board.dots), 'pitch_m': board.pitch, 'dot_radius_m': board.radius}


def board_from_dict(content: dict) -> Board:
    """The inverse of :func:`board_as_dict`.

    Raises
    ------
    InvalidInputError
        A missing key or a value that is not a number."""
    try:
        return Board(tuple(int(v) for v in content['dots']), float(content['pitch_m']),
                     float(content['dot_radius_m']))
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInputError(f'a board needs dots, pitch_m and dot_radius_m: {exc!r}') from None

# What a dispenser's commanded axes can read, whatever its strokes: linear axes well under
# 2 m, the tilt A within a half turn, the table C within two turns either way.
POSE_SCHEMA = Schema((
    Column('x', 'm', -2.0, 2.0, 'commanded X axis'),
    Column('y', 'm', -2.0, 2.0, 'commanded Y axis'),
    Column('z', 'm', -2.0, 2.0, 'commanded Z axis'),
    Column('a', 'rad', -np.pi, np.pi, 'commanded tilt A'),
    Column('c', 'rad', -4 * np.pi, 4 * np.pi, 'commanded table C')))
POSE_NAMES = ('x', 'y', 'z', 'a', 'c')


def check_poses(poses: np.ndarray, source: str) -> None:
    """Refuse commanded poses (n, 5) (x, y, z m; a, c rad) no dispenser produces, naming
    the column and the likely unit mistake.

    Raises
    ------
    InvalidInputError"""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    POSE_SCHEMA.check(dict(zip(POSE_NAMES, poses.T)), source)


@dataclass(frozen=True)
class Image:
    """One image: its name, the commanded pose (5,) (x, y, z m; a, c rad), the board
    indices (k, 2) of the dots seen, their centres (k, 2) px, and the ``board`` they are
    on."""

    name: str
    pose: np.ndarray
    indices: np.ndarray
    pixels: np.ndarray
    board: Board = SHIPPED_BOARD


def one_board(images: list[Image]) -> Board:
    """The board every one of ``images`` was taken of.

    Raises
    ------
    CalibrationError
        Images of different boards: one calibration is of one board."""
    boards = {im.board for im in images}
    if len(boards) != 1:
        raise CalibrationError(f'the images are of {len(boards)} different boards; calibrate '
                               'with the images of one')
    return boards.pop()


def board_points(board: Board = SHIPPED_BOARD) -> tuple[np.ndarray, np.ndarray]:
    """The ``board``'s dots (k, 3) m in its frame (centred, z = 0) and their indices (k, 2)."""
    ki = np.arange(board.dots[0]) - (board.dots[0] - 1) // 2
    kj = np.arange(board.dots[1]) - (board.dots[1] - 1) // 2
    jj, ii = np.meshgrid(kj, ki, indexing='ij')
    indices = np.column_stack([ii.ravel(), jj.ravel()])
    return np.column_stack([indices * board.pitch, np.zeros(len(indices))]), indices


def write_observations(path, images: list[Image], pose_scale=None) -> None:
    """``images`` as the observations CSV; with ``pose_scale`` (5,) (SI per reading unit of
    x, y, z, a, c: a machine description's) the poses in the reading units."""
    scale = np.ones(5) if pose_scale is None else np.asarray(pose_scale, dtype=float)
    lines = [','.join(COLUMNS)]
    for image in images:
        pose = ','.join(f'{v:.12g}' for v in image.pose / scale)
        lines += [f'{image.name},{pose},{i},{j},{u:.6f},{v:.6f}'
                  for (i, j), (u, v) in zip(image.indices, image.pixels)]
    write_atomic(path, '\n'.join(lines) + '\n')


def read_observations(path, pose_scale=None, board: Board = SHIPPED_BOARD) -> list[Image]:
    """Images in the file's order, poses in m and rad: the file's times ``pose_scale`` (5,)
    (SI per reading unit of x, y, z, a, c, a machine description's; default: the file is
    in m and rad), their dots on ``board``.

    Raises
    ------
    InvalidInputError
        Unreadable file, missing columns, values that are not numbers or NaN, an image
        whose rows disagree on the pose, a dot seen twice in one image (each named)."""
    rows = read_csv_rows(path, 'a five-axis observations CSV', COLUMNS)
    by_image = {}
    for number, row in enumerate(rows, start=2):
        try:
            pose = tuple(float(row[k]) for k in ('x', 'y', 'z', 'a', 'c'))
            index = (int(row['i']), int(row['j']))
            pixel = (float(row['u']), float(row['v']))
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f'{path}, line {number}: {exc}') from None
        if not np.all(np.isfinite(pose + pixel)):
            raise InvalidInputError(f'{path}, line {number}: NaN or infinite value')
        entry = by_image.setdefault(row['image'], {'pose': pose, 'dots': {}})
        if entry['pose'] != pose:
            raise InvalidInputError(f'{path}, line {number}: image {row["image"]!r} has rows with '
                                    'different poses (inconsistent correspondences)')
        if index in entry['dots']:
            raise InvalidInputError(f'{path}, line {number}: image {row["image"]!r} has dot '
                                    f'{index} twice (inconsistent correspondences)')
        entry['dots'][index] = pixel
    scale = np.ones(5) if pose_scale is None else np.asarray(pose_scale, dtype=float)
    check_poses([np.array(e['pose']) * scale for e in by_image.values()], str(path))
    return [Image(name, np.array(e['pose']) * scale, np.array(list(e['dots'])),
                  np.array(list(e['dots'].values())), board) for name, e in by_image.items()]
