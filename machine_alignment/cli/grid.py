"""``machine-align calibrate grid``: self-calibration of a 2-D stage's measuring system
with an imperfect grid plate at three placements, region by region, stitched into one
frame, from a marks CSV or a run recorded by grid_calibrator."""
from __future__ import annotations

from grid_calib.core.stitching import METHODS
from machine_alignment.cli import deferred
from machine_alignment.cli.common import ranged


def add_parser(what) -> None:
    grid = what.add_parser('grid', help='2-D stage error from an imperfect grid plate at '
                                        'three placements, region by region')
    source = grid.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: region, placement (initial / rotated / shifted), '
                                       'i, j (centred mark indices), x, y (stage reading, m)')
    source.add_argument('--bag', help='a run recorded by grid_calibrator (plate and pitch '
                                      'from the run)')
    plate = grid.add_mutually_exclusive_group()
    plate.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'),
                       help='nominal plate pitch, m (with --data)')
    plate.add_argument('--description',
                       help='your setup\'s description YAML: the plate, the unit x, y are '
                            'in, the gate from the declared camera and reading noise '
                            '(docs/machine_description.md)')
    grid.add_argument('--stitch', choices=METHODS, default='joint',
                      help='regions in one fit (joint) or pairwise along a chain')
    grid.add_argument('--certified-pitch',
                      type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'),
                      help="the plate's certified mean pitch, m: fixes the stage's "
                           'isotropic scale, otherwise undetermined')
    grid.add_argument('--json', help='report to write (JSON, SI units); the plot and the map table (_map.csv) go beside it')
    grid.set_defaults(func=deferred('grid_run', 'cmd_calibrate_grid'))
