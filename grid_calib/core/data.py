"""The marks CSV of ``machine-align calibrate grid``: one row per mark and placement,
columns ``region`` (integer), ``placement`` (initial, rotated, shifted), ``i``, ``j`` (the
mark's centred indices, -K..K) and ``x``, ``y`` (the stage's measuring-system reading, m,
with the camera centred on the mark); optional ``time`` (s) and ``temperature`` (K) per
reading, for the closed loop."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_core.checks import MAX_POSITION_M
from calib_core.files import read_csv_rows
from calib_core.schema import Column, Schema
from calib_core.storage import write_atomic
from calib_core.temperature import TEMPERATURE
from grid_calib.core.model import PLACEMENTS, Grid, site_of
from grid_calib.core.selfcal import Placement
from grid_calib.errors import PlacementError

COLUMNS = ('region', 'placement', 'i', 'j', 'x', 'y')
# Logged with the readings where the machine has them; the closed loop uses them.
OPTIONAL_COLUMNS = ('time', 'temperature')


@dataclass(frozen=True)
class Region:
    """One region's placements, deviations from its own nominal sites (m), and where its
    centre lies in the travel frame (site indices)."""

    origin: tuple
    placements: list


# A placement is modelled to first order in its angle; the second-order term, angle^2 / 2
# times the plate's half size, must stay below this (m).
SMALL_ANGLE_LIMIT_M = 5e-9
LATTICE_TOLERANCE = 0.05     # of a pitch: a region's centre off its site by more is refused
EXPECTED_TURN = {'initial': 0.0, 'rotated': np.pi / 2, 'shifted': 0.0}


def _similarity(source: np.ndarray, target: np.ndarray):
    """Least-squares similarity target ~ s R(angle) source + t: (s, angle, residuals (k, 2))."""
    a, b = source - source.mean(axis=0), target - target.mean(axis=0)
    dot = np.sum(a * b)
    cross = np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    angle = np.arctan2(cross, dot)
    scale = np.hypot(dot, cross) / np.sum(a * a)
    c, s = np.cos(angle), np.sin(angle)
    turned = scale * a @ np.array([[c, s], [-s, c]])
    return scale, angle, b - turned


def region_from_readings(grid: Grid, readings: dict, label: str = 'region',
                         covariates: dict | None = None) -> Region:
    """A region from its raw readings: placement -> (marks (k, 2) int, readings (k, 2) m),
    with the covariates logged per reading (placement -> {name: (k,)}) if any.

    The readings themselves show how each placement lies: the plate turned by the angle
    between the marks' indices and the readings, at the readings' pitch, shifted by the
    readings' offset from the initial placement. Each is checked against the method's.

    Raises
    ------
    PlacementError
        A placement missing, turned other than as named, a pitch other than the given one,
        marks off a regular grid, a shift other than one pitch along +x."""
    missing = [n for n in PLACEMENTS if n not in readings or not len(readings[n][0])]
    if missing:
        raise PlacementError(f'{label}: placement(s) {missing} missing; the method needs '
                             f'{PLACEMENTS}')
    half_size = grid.half * grid.pitch
    angle_limit = np.sqrt(2 * SMALL_ANGLE_LIMIT_M / half_size)
    centres = {}
    for name in PLACEMENTS:
        marks, reading = readings[name]
        scale, angle, rest = _similarity(marks * grid.pitch, reading)
        off = np.angle(np.exp(1j * (angle - EXPECTED_TURN[name])))
        if abs(off) > angle_limit:
            raise PlacementError(
                f'{label}, {name}: the readings show the plate turned by '
                f'{np.degrees(angle):.3f} deg, not {np.degrees(EXPECTED_TURN[name]):.0f} deg '
                f'({abs(off) * 1e3:.3g} mrad off; the method\'s small-angle model holds to '
                f'{SMALL_ANGLE_LIMIT_M * 1e9:.0f} nm up to {angle_limit * 1e3:.2f} mrad at this '
                'plate size): re-place the plate')
        if abs(scale - 1) > 1e-3:
            raise PlacementError(f'{label}, {name}: the readings have a pitch of '
                                 f'{scale * grid.pitch * 1e3:.5g} mm, not the given '
                                 f'{grid.pitch * 1e3:.5g} mm')
        worst = np.linalg.norm(rest, axis=1).max()
        if worst > 0.01 * grid.pitch:
            raise PlacementError(f'{label}, {name}: marks lie off a regular grid by up to '
                                 f'{worst * 1e6:.4g} um (an uneven pitch, or indices that do '
                                 'not match the marks)')
        centres[name] = np.mean(reading - site_of(marks, name) * grid.pitch, axis=0)
    origin = np.round(centres['initial'] / grid.pitch).astype(int)
    # The sites are the reading frame's lattice: a plate centred between them would have
    # G sampled off the sites it is filed under, differently in each region.
    off = centres['initial'] - origin * grid.pitch
    if np.abs(off).max() > LATTICE_TOLERANCE * grid.pitch:
        raise PlacementError(
            f'{label}: the plate\'s centre lies ({off[0] * 1e3:.3f}, {off[1] * 1e3:.3f}) mm '
            'from the nearest site: site (m, n) must be at (m, n) x pitch in the reading '
            'frame (subtract that offset from x, y, or place the centre mark on a site)')
    for name in ('rotated', 'shifted'):
        moved = (centres[name] - centres['initial']) / grid.pitch
        if np.abs(moved).max() > 0.25:
            raise PlacementError(
                f'{label}, {name}: the plate lies ({moved[0] + (name == "shifted"):.2f}, '
                f'{moved[1]:.2f}) pitches from the initial placement; the method needs '
                + ('one pitch along +x' if name == 'shifted' else 'a turn about the plate '
                   'centre'))
    placements = [Placement(n, readings[n][0],
                            readings[n][1] - (site_of(readings[n][0], n) + origin) * grid.pitch,
                            (covariates or {}).get(n))
                  for n in PLACEMENTS]
    return Region((int(origin[0]), int(origin[1])), placements)


# The grid marks CSV, declared: readings anywhere on a machine, temperatures in kelvin.
MARKS_SCHEMA = Schema((
    Column('x', 'm', -MAX_POSITION_M, MAX_POSITION_M, 'mark reading x'),
    Column('y', 'm', -MAX_POSITION_M, MAX_POSITION_M, 'mark reading y'),
    TEMPERATURE))


def read_marks(path, pitch: float, m_per_unit: float = 1.0) -> tuple[Grid, dict]:
    """The grid (its size from the indices) and, per region, a ``Region``; x, y are in m,
    or times ``m_per_unit`` (a machine description's unit of the stage's readings).

    Raises
    ------
    InvalidInputError
        Unreadable file, missing columns, values that are not numbers, lengths in mm.
    PlacementError
        Indices that are not a centred odd grid, unknown placements, placements that do
        not lie as the method needs."""
    rows = read_csv_rows(path, 'a grid marks CSV', COLUMNS, PlacementError)
    try:
        region = np.array([int(r['region']) for r in rows])
        marks = np.array([[int(r['i']), int(r['j'])] for r in rows])
        reading = np.array([[float(r['x']), float(r['y'])] for r in rows]) * m_per_unit
    except (TypeError, ValueError) as exc:
        raise PlacementError(f'{path}: region, i, j must be integers and x, y numbers ({exc})') from None
    if not np.all(np.isfinite(reading)):
        raise PlacementError(f'{path}: x or y is NaN or infinite')
    logged = {}
    for name in OPTIONAL_COLUMNS:
        if name in rows[0]:
            try:
                logged[name] = np.array([float(r[name]) for r in rows])
            except (TypeError, ValueError) as exc:
                raise PlacementError(f'{path}: {name} must be a number in every row ({exc})') from None
            if not np.all(np.isfinite(logged[name])):
                raise PlacementError(f'{path}: {name} is NaN or infinite')
    MARKS_SCHEMA.check({'x': reading[:, 0], 'y': reading[:, 1], **logged}, path)
    names = np.array([r['placement'].strip() for r in rows])
    unknown = sorted(set(names.tolist()) - set(PLACEMENTS))
    if unknown:
        raise PlacementError(f'{path}: unknown placement(s) {", ".join(unknown)}; use '
                             f'{", ".join(PLACEMENTS)}')
    half = int(np.abs(marks).max())
    if marks.min() != -half:
        raise PlacementError(f'{path}: mark indices must be centred, -K..K, for an odd N '
                             f'(found {marks.min()}..{marks.max()})')
    grid = Grid(half, pitch)
    regions = {}
    for r in np.unique(region):
        rows_of = {n: np.flatnonzero((region == r) & (names == n)) for n in PLACEMENTS}
        regions[int(r)] = region_from_readings(
            grid, {n: (marks[k], reading[k]) for n, k in rows_of.items()}, f'region {r}',
            {n: {c: v[k] for c, v in logged.items()} for n, k in rows_of.items()} if logged
            else None)
    return grid, regions


def write_marks(path, grid: Grid, regions: dict, m_per_unit: float = 1.0) -> None:
    """The marks CSV of regions (region -> Region); readings = nominal site + deviation, in
    m or divided by ``m_per_unit`` (a machine description's unit)."""
    logged = [c for c in OPTIONAL_COLUMNS
              if all((p.covariates or {}).get(c) is not None
                     for region in regions.values() for p in region.placements)]
    lines = [','.join(COLUMNS + tuple(logged))]
    for r, region in regions.items():
        for p in region.placements:
            reading = ((site_of(p.marks, p.name) + region.origin) * grid.pitch
                       + p.deviation) / m_per_unit
            extra = [p.covariates[c] for c in logged]
            lines += [f'{r},{p.name},{i},{j},{x:.12g},{y:.12g}'
                      + ''.join(f',{v[k]:.12g}' for v in extra)
                      for k, ((i, j), (x, y)) in enumerate(zip(p.marks, reading))]
    write_atomic(path, '\n'.join(lines) + '\n')
