"""Reading a recorded grid self-calibration run into core values. Live messages and
messages decoded from a bag have the same fields (only attribute access is used), so the
node and the offline tools read a run with the same code. The topic names are the contract
between the node that records a run and the tools that replay it."""
from __future__ import annotations

import numpy as np

from calib_core.temperature import run_covariates, stamp_seconds
from grid_calib.core.data import region_from_readings
from grid_calib.core.model import PLACEMENTS, Grid
from grid_calib.errors import PlacementError

READINGS_TOPIC = '/grid_calibrator/readings'
PLACEMENT_TOPIC = '/grid_calibrator/placement'
RESULT_TOPIC = '/grid_calibrator/result'


def grid_from_placements(placements) -> Grid:
    """The plate (N, pitch) the run's GridPlacement messages name.

    Raises
    ------
    PlacementError
        No placement recorded, or placements that disagree on the plate."""
    plates = {(int(p.marks_per_side), float(p.pitch)) for p in placements}
    if len(plates) != 1:
        raise PlacementError('the run records no plate placement' if not plates else
                             f'the run\'s placements name different plates: {sorted(plates)}')
    (count, pitch), = plates
    if count % 2 == 0 or count < 3:
        raise PlacementError(f'the run names a plate of {count} marks a side; the method '
                             'needs an odd N >= 3')
    return Grid((count - 1) // 2, pitch)


def regions_from_readings(grid: Grid, readings, temperatures=None
                          ) -> tuple[dict, list[str]]:
    """Regions (region -> ``data.Region``) from GridMarkReading messages, and sentences
    saying what was left out: each region whose run is incomplete (a run stopped or killed
    part way; what was measured is kept, nothing incomplete is solved), a temperature the
    log does not cover. With every reading stamped, each carries its ``time`` (s since the
    run's first reading) for the closed loop, and with a log of ``temperatures``
    (``calib_core.temperature.temperature_log``) its ``temperature`` (K).

    Raises
    ------
    PlacementError
        A reading with NaN or an unknown placement, or a complete region whose placements
        are not the method's."""
    run, why = run_covariates([stamp_seconds(msg) for msg in readings], temperatures)
    left_out = [why] if why and 'time' in run else []
    by_region = {}
    for k, msg in enumerate(readings):
        if msg.placement not in PLACEMENTS:
            raise PlacementError(f'a reading names placement {msg.placement!r}; the method '
                                 f'uses {PLACEMENTS}')
        if not (np.isfinite(msg.x) and np.isfinite(msg.y)):
            raise PlacementError(f'region {msg.region}, {msg.placement}, mark ({msg.i}, '
                                 f'{msg.j}): the reading is NaN or infinite')
        by_region.setdefault(int(msg.region), {}).setdefault(msg.placement, []).append(
            ((int(msg.i), int(msg.j)), (float(msg.x), float(msg.y)), k))
    regions = {}
    full = len(grid.marks)
    for region in sorted(by_region):
        counts = {p: len(by_region[region].get(p, [])) for p in PLACEMENTS}
        if any(n < full for n in counts.values()):
            left_out.append(f'region {region} left out: incomplete ('
                            + ', '.join(f'{p} {n}/{full}' for p, n in counts.items()) + ')')
            continue
        as_arrays = {p: (np.array([row[0] for row in rows]), np.array([row[1] for row in rows]))
                     for p, rows in by_region[region].items()}
        # Each reading's covariates of the run, where it has them (all stamped).
        covariates = {p: {name: values[[row[2] for row in rows]]
                          for name, values in run.items()}
                      for p, rows in by_region[region].items()} if run else None
        regions[region] = region_from_readings(grid, as_arrays, f'region {region}', covariates)
    return regions, left_out
