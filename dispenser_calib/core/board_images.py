"""From a camera frame of the dot board to an observation: the dots found by the Mark
detector (:mod:`calib_core.marks`, an ellipse fit for dots seen at an angle), each named
by its board index.

Naming: the model in force (the nominal one before the first calibration) predicts every
dot at the commanded pose; each detection takes the nearest prediction, a homography from
the board to the image fitted to those pairs (RANSAC) maps the detections back onto the
board's lattice, and the lattice is shifted by whole pitches to where most detections fall
on the board. With the whole board in view its edges fix the names when the prediction
is off by up to two pitches (as a whole); with part of it in view a board without an
orientation mark can be named only if the model predicts the dots to better than half a
pitch, and a pose misplaced by more would name every dot a pitch off, consistently, which
no check on that image alone could see."""
from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from calib_core.errors import CalibrationError, DetectionError
from calib_core.marks import DetectorConfig, detect_marks
from dispenser_calib.core.data import SHIPPED_BOARD, Board, Image, board_points
from dispenser_calib.core.model import DispenserModel, project

MATCH_SHARE = 0.25   # of the pitch: a detection this close to a lattice place is that dot


def name_dots(detected: np.ndarray, predicted: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """For each detection (k, 2) px, the row of its dot in ``indices`` (n, 2), or -1.

    The nearest of the ``predicted`` pixels (n, 2) names each detection first; a
    homography fitted to those pairs (RANSAC) maps the detections back onto the board,
    where each takes the nearest lattice place within a quarter pitch. The lattice is then
    shifted by whole pitches (up to two) to where most detections fall on the board: when
    the whole board is in view that shift is unique, and it corrects a prediction off by
    more than half a pitch. When it is not unique, the prediction decides."""
    lookup = np.flatnonzero(np.all(np.isfinite(predicted), axis=1))
    tree = cKDTree(predicted[lookup])
    first = lookup[tree.query(detected)[1]]
    names = np.full(len(detected), -1)
    if len(np.unique(first)) < 4:
        return names
    # A pair named a pitch off misses by a pitch; the lens bends the lattice by a few px.
    pitch_px = float(np.median(tree.query(predicted[lookup], k=2)[0][:, 1]))
    homography, _ = cv2.findHomography(indices[first].astype(float), detected, cv2.RANSAC,
                                       MATCH_SHARE * pitch_px)
    if homography is None:
        return names
    on_board = cv2.perspectiveTransform(detected[:, None], np.linalg.inv(homography))[:, 0]
    place = np.round(on_board).astype(int)
    near = np.linalg.norm(on_board - place, axis=1) < MATCH_SHARE
    low, high = indices.min(axis=0), indices.max(axis=0)

    def inside(shift):
        moved = place[near] + shift
        return int(np.sum(np.all((moved >= low) & (moved <= high), axis=1)))
    shifts = [np.array([di, dj]) for di in range(-2, 3) for dj in range(-2, 3)]
    counts = np.array([inside(shift) for shift in shifts])
    best = np.flatnonzero(counts == counts.max())
    shift = shifts[best[0]] if len(best) == 1 else np.zeros(2, int)
    where = {tuple(i): k for k, i in enumerate(indices)}
    for k in np.flatnonzero(near):
        names[k] = where.get(tuple(place[k] + shift), -1)
    claimed, repeats = np.unique(names[names >= 0], return_counts=True)
    names[np.isin(names, claimed[repeats > 1])] = -1
    return names


def observe_frame(frame: np.ndarray, pose: np.ndarray, model: DispenserModel, name: str,
                  config: DetectorConfig = DetectorConfig(min_size_px=4, max_size_px=80,
                                                          polarity='dark'),
                  board: Board = SHIPPED_BOARD) -> Image:
    """The dots of ``board`` in one frame (H, W) taken at the commanded ``pose`` (5,),
    named with ``model``'s prediction.

    Raises
    ------
    CalibrationError
        No dot found (the board out of view or out of focus), naming the image."""
    try:
        marks = detect_marks(frame, config, 'circle').marks
    except DetectionError as exc:
        raise CalibrationError(f'{name}: no board dots found ({exc}): the board out of view '
                               f'or out of focus?') from None
    dots, indices = board_points(board)
    detected = np.array([[m.u, m.v] for m in marks])
    names = name_dots(detected, project(model, dots, pose[None])[0], indices)
    kept = names >= 0
    return Image(name, np.asarray(pose, float).copy(), indices[names[kept]], detected[kept],
                 board)
