"""``machine-align export stage|platform|hexapod|five-axis|grid``: a calibrator's recorded run
(MCAP bag) as the CSV that ``machine-align analyze`` (and ``calibrate --data``) reads, so
the closed loop can be run, repeated and shared offline on any live run. A cut run gives
the stops it recorded. Each row gets a ``time`` column (s since the run's first stop, from
the stops' header stamps) and, where the run recorded the machine's temperature, a
``temperature`` column (K), so a drift during the run can be tested, as the calibrator's
own loop tests it. A five-axis bag (a
calibration run or the sweep ``analyze_residuals`` records) gives the observations CSV of
its images, which ``analyze rotary --calibration`` reads for a sweep; a grid bag the marks
CSV of its complete regions, which ``analyze grid`` reads."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred


def add_parser(sub) -> None:
    parser = sub.add_parser('export', help=command_help('export'))
    machines = parser.add_subparsers(dest='machine', required=True)
    for name, recorder in (('stage', 'stage_calibrator'), ('platform', 'platform_calibrator'),
                           ('hexapod', 'hexapod_calibrator'),
                           ('five-axis', 'five_axis_calibrator'), ('grid', 'grid_calibrator')):
        machine = machines.add_parser(name, help=f'a run recorded by {recorder}')
        machine.add_argument('--bag', required=True, help=f'a run recorded by {recorder}')
        machine.add_argument('--out', required=True, help='CSV to write (SI units)')
        machine.set_defaults(func=deferred('export_run', 'cmd_export'))
