"""The grid self-calibration run on a machine: where to move for every mark of every
placement of every region, and how the readings become regions. Hardware is passed in as
callables, so the live node, the offline replay, the bench and the tests run the same
code."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from calib_core.checks import (
    MAX_COUNT, MAX_POSITION_M, check_metres, positive_length, whole_number)
from calib_core.errors import InvalidInputError, OutOfTravelError
from grid_calib.core.data import region_from_readings
from grid_calib.core.model import PLACEMENTS, Grid, region_origins, site_of

MAX_PITCH_M = 0.05      # a grid plate's pitch; 7.5 written in mm would read as 7.5 m


@dataclass(frozen=True)
class GridPlan:
    """A travel covered by ``columns`` x ``rows`` regions of a (2 ``half`` + 1)-square plate
    of ``pitch`` (m), neighbours sharing one row and column of sites. Site (m, n) lies at
    (m, n) ``pitch`` in the machine's reading frame; region 0's centre is site
    ``first_centre``. Every mark is approached from ``approach`` (m) below on both axes, so
    backlash acts the same way at every stop."""

    half: int = 4
    pitch: float = 7.5e-3
    columns: int = 3
    rows: int = 2
    first_centre: tuple = (5, 5)
    approach: float = 1e-3

    def __post_init__(self):
        # Checked whole here, before anything moves.
        object.__setattr__(self, 'half', whole_number(self.half, 'half', 1))
        object.__setattr__(self, 'columns', whole_number(self.columns, 'columns', 1))
        object.__setattr__(self, 'rows', whole_number(self.rows, 'rows', 1))
        object.__setattr__(self, 'pitch', positive_length(self.pitch, 'pitch', MAX_PITCH_M))
        readings = 4 * (2 * self.half + 1) ** 2 * self.columns * self.rows
        if readings > MAX_COUNT:
            raise InvalidInputError(
                f'half {self.half}, {self.columns} x {self.rows} regions: {readings} readings '
                f'(4 placements of (2 half + 1)^2 marks per region), more than the {MAX_COUNT} '
                'a plan may ask for')
        centre = tuple(whole_number(v, 'first_centre', -10 ** 6, 10 ** 6)
                       for v in self.first_centre)
        if len(centre) != 2:
            raise InvalidInputError(f'first_centre must be two site indices, not {centre!r}')
        object.__setattr__(self, 'first_centre', centre)
        if not (np.isfinite(self.approach) and 0 <= self.approach < self.pitch):
            raise InvalidInputError(f'approach must be a length in [0, pitch) m, not '
                                    f'{self.approach!r}')

    @property
    def grid(self) -> Grid:
        return Grid(self.half, self.pitch)

    def origins(self) -> dict:
        """Region -> centre site (m0, n0) in the reading frame."""
        centred = region_origins(self.grid, self.columns, self.rows)
        m0, n0 = centred[0]
        return {r: (m - m0 + self.first_centre[0], n - n0 + self.first_centre[1])
                for r, (m, n) in centred.items()}

    def stops(self, region: int, placement: str) -> tuple[np.ndarray, np.ndarray]:
        """The marks (k, 2) of a placement and where the machine goes to see each (k, 2) m:
        the nominal site the mark lies over."""
        marks = self.grid.marks
        return marks, (site_of(marks, placement) + self.origins()[region]) * self.pitch

    def check(self, x_range: tuple, y_range: tuple) -> None:
        """Refuse a plan with any stop or approach outside the travel (m), before anything
        moves."""
        every = np.vstack([self.stops(r, p)[1] for r in self.origins() for p in PLACEMENTS])
        check_metres(every, 'the plan\'s stops', 'the grid plan', MAX_POSITION_M)
        low = every - self.approach
        outside = ((low[:, 0] < x_range[0]) | (every[:, 0] > x_range[1])
                   | (low[:, 1] < y_range[0]) | (every[:, 1] > y_range[1]))
        if outside.any():
            raise OutOfTravelError(
                f'{int(outside.sum())} stop(s) of the grid plan lie outside the travel x '
                f'{x_range[0]:g}..{x_range[1]:g} m, y {y_range[0]:g}..{y_range[1]:g} m (stops '
                f'span x {low[:, 0].min():.4g}..{every[:, 0].max():.4g}, y '
                f'{low[:, 1].min():.4g}..{every[:, 1].max():.4g} m with the approach)')


def measure_grid(plan: GridPlan, place: Callable[[int, str, np.ndarray], None],
                 move: Callable[[float, float], np.ndarray],
                 locate: Callable[[], np.ndarray],
                 progress: Callable[[int, int, str], None] = lambda *a: None,
                 record: Callable[[int, str, tuple, np.ndarray], None] = lambda *a: None) -> dict:
    """Measure every mark of every placement of every region.

    ``place(region, placement, centre)`` has the plate put in that placement over the
    region whose centre is at ``centre`` (m; an operator on a real machine, the simulation
    here) and returns when it is done; ``move(x, y)`` moves to a target (m) and returns the
    measuring system's reading there (m, (2,)); ``locate()`` returns the mark's offset from
    the image centre (m, (2,)) in the same frame; ``record(region, placement, mark,
    reading)`` gets every reading as it is taken. Returns region -> ``Region``.

    Raises
    ------
    PlacementError
        The readings of a region show a placement other than the method's."""
    grid, origins = plan.grid, plan.origins()
    total = len(origins) * len(PLACEMENTS) * len(grid.marks)
    done, regions = 0, {}
    for region, origin in origins.items():
        readings = {}
        for placement in PLACEMENTS:
            place(region, placement, np.asarray(origin, dtype=float) * plan.pitch)
            marks, targets = plan.stops(region, placement)
            seen = []
            for x, y in targets:
                move(x - plan.approach, y - plan.approach)
                reading = np.asarray(move(x, y), dtype=float)
                seen.append(reading + np.asarray(locate(), dtype=float))
                record(region, placement, tuple(marks[len(seen) - 1]), seen[-1])
                done += 1
                if done % len(grid.marks) == 0 or done == total:
                    progress(done, total, f'region {region}, {placement}: '
                                          f'{len(seen)} marks')
            readings[placement] = (marks, np.array(seen))
        regions[region] = region_from_readings(grid, readings, f'region {region}')
    return regions


def camera_in_stage_frame(parameters: dict) -> tuple[float, float] | None:
    """The camera's pixel size (m/px) and the angle (rad) of its pixel axes to the stage's
    X axis, from a vision calibration's named parameters, or None if it lacks them.

    The vision calibration gives the camera's angle to its dot plate (``camera_angle``)
    and the gantry X axis's angle in that plate's frame (``axis_angle``); the grid readings
    must be in the stage's own axes, whose errors G describes, so the angle used is their
    difference. (With the plate's angle left in, every grid placement looks turned by it,
    and a plate placed exactly square is refused as turned beyond the small-angle model.)"""
    if 'pixel_size' not in parameters or 'camera_angle' not in parameters:
        return None
    return (float(parameters['pixel_size']),
            float(parameters['camera_angle']) - float(parameters.get('axis_angle', 0.0)))
