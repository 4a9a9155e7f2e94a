"""The marks CSV of ``machine-align calibrate grid``: one row per mark and placement,
columns ``region`` (integer), ``placement`` (initial, rotated, shifted), ``i``, ``j`` (the
mark's centred indices, -K..K) and ``x``, ``y`` (the stage's measuring-system reading, m,
with the camera centred on the mark)."""
from __future__ import annotations

import csv
import io

import numpy as np

from calib_core.checks import MAX_POSITION_M, check_metres
from calib_core.files import read_text
from calib_core.storage import write_atomic
from grid_calib.core.model import PLACEMENTS, Grid, site_of
from grid_calib.core.selfcal import Placement
from grid_calib.errors import PlacementError

COLUMNS = ('region', 'placement', 'i', 'j', 'x', 'y')


def read_marks(path, pitch: float) -> tuple[Grid, dict[int, list[Placement]]]:
    """The grid (its size from the indices) and, per region, its placements with the
    deviation of each reading from the mark's nominal site position (m).

    Raises
    ------
    InvalidInputError
        Unreadable file, missing columns, values that are not numbers, lengths in mm.
    PlacementError
        Indices that are not a centred odd grid, unknown placements."""
    try:
        rows = list(csv.DictReader(io.StringIO(read_text(path, 'a grid marks CSV'))))
    except csv.Error as exc:
        raise PlacementError(f'{path} is not a CSV file: {exc}') from None
    if not rows or any(c not in rows[0] for c in COLUMNS):
        raise PlacementError(f'{path} needs the columns {", ".join(COLUMNS)}')
    try:
        region = np.array([int(r['region']) for r in rows])
        marks = np.array([[int(r['i']), int(r['j'])] for r in rows])
        reading = np.array([[float(r['x']), float(r['y'])] for r in rows])
    except (TypeError, ValueError) as exc:
        raise PlacementError(f'{path}: region, i, j must be integers and x, y numbers ({exc})') from None
    if not np.all(np.isfinite(reading)):
        raise PlacementError(f'{path}: x or y is NaN or infinite')
    check_metres(reading, 'the readings x, y', path, MAX_POSITION_M)
    names = [r['placement'].strip() for r in rows]
    unknown = sorted(set(names) - set(PLACEMENTS))
    if unknown:
        raise PlacementError(f'{path}: unknown placement(s) {unknown}; use {PLACEMENTS}')
    half = int(np.abs(marks).max())
    if marks.min() != -half:
        raise PlacementError(f'{path}: mark indices must be centred, -K..K (found '
                             f'{marks.min()}..{marks.max()})')
    grid = Grid(half, pitch)
    regions = {}
    for r in np.unique(region):
        placements = []
        for name in PLACEMENTS:
            rows_of = np.flatnonzero((region == r) & (np.array(names) == name))
            nominal = site_of(marks[rows_of], name) * pitch
            placements.append(Placement(name, marks[rows_of], reading[rows_of] - nominal))
        regions[int(r)] = placements
    return grid, regions


def write_marks(path, grid: Grid, placements: list[Placement], region: int = 0) -> None:
    """The marks CSV of one region's placements (readings = nominal site + deviation)."""
    lines = [','.join(COLUMNS)]
    for p in placements:
        reading = site_of(p.marks, p.name) * grid.pitch + p.deviation
        lines += [f'{region},{p.name},{i},{j},{x:.12g},{y:.12g}'
                  for (i, j), (x, y) in zip(p.marks, reading)]
    write_atomic(path, '\n'.join(lines) + '\n')
