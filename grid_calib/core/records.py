"""Reading a recorded grid self-calibration run into core values. Live messages and
messages decoded from a bag have the same fields (only attribute access is used), so the
node and the offline tools read a run with the same code. The topic names are the contract
between the node that records a run and the tools that replay it."""
from __future__ import annotations

import numpy as np

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


def _stamp(msg) -> float:
    """A reading's header stamp (s), NaN for a reading without one."""
    header = getattr(msg, 'header', None)
    return np.nan if header is None else header.stamp.sec + 1e-9 * header.stamp.nanosec


def regions_from_readings(grid: Grid, readings) -> tuple[dict, list[str]]:
    """Regions (region -> ``data.Region``) from GridMarkReading messages, and a sentence for
    each region left out because its run is incomplete (a run stopped or killed part way):
    what was measured is kept, nothing incomplete is solved. With every reading stamped,
    each carries its ``time`` (s since the run's first reading) for the closed loop.

    Raises
    ------
    PlacementError
        A reading with NaN or an unknown placement, or a complete region whose placements
        are not the method's."""
    by_region, stamps = {}, np.array([_stamp(msg) for msg in readings])
    start = np.min(stamps) if len(stamps) and np.all(np.isfinite(stamps)) else None
    for msg, stamp in zip(readings, stamps):
        if msg.placement not in PLACEMENTS:
            raise PlacementError(f'a reading names placement {msg.placement!r}; the method '
                                 f'uses {PLACEMENTS}')
        if not (np.isfinite(msg.x) and np.isfinite(msg.y)):
            raise PlacementError(f'region {msg.region}, {msg.placement}, mark ({msg.i}, '
                                 f'{msg.j}): the reading is NaN or infinite')
        by_region.setdefault(int(msg.region), {}).setdefault(msg.placement, []).append(
            ((int(msg.i), int(msg.j)), (float(msg.x), float(msg.y)),
             None if start is None else stamp - start))
    regions, left_out = {}, []
    full = len(grid.marks)
    for region in sorted(by_region):
        counts = {p: len(by_region[region].get(p, [])) for p in PLACEMENTS}
        if any(n < full for n in counts.values()):
            left_out.append(f'region {region} left out: incomplete ('
                            + ', '.join(f'{p} {n}/{full}' for p, n in counts.items()) + ')')
            continue
        as_arrays = {p: (np.array([m for m, _, _ in rows]), np.array([r for _, r, _ in rows]))
                     for p, rows in by_region[region].items()}
        times = None if start is None else {
            p: {'time': np.array([t for _, _, t in rows])}
            for p, rows in by_region[region].items()}
        regions[region] = region_from_readings(grid, as_arrays, f'region {region}', times)
    return regions, left_out
