"""``machine-align launch`` and ``machine-align demo``: the simulated machine graphs as
separate processes, and the end-to-end demo on them."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred


def add_parser(sub) -> None:
    launch = sub.add_parser('launch', help=command_help('launch'))
    launch.add_argument('graph', choices=['printer', 'stage', 'hexapod', 'grid', 'platform',
                                          'five-axis'],
                        help='printer: vision chain; stage: the printer with its stage; '
                             'hexapod; grid: the camera gantry over a grid plate; platform: '
                             'the screen-registration platform; five-axis: the dispenser')
    launch.add_argument('--scene', default='dot_plate', choices=['dot_plate', 'substrate', 'stencil'], help='what the simulated camera looks at')
    launch.add_argument('--output-dir', default='calibration', help='where the calibrators write calibration files')
    launch.add_argument('--record-dir', default='runs', help='where runs are recorded (MCAP bags)')
    launch.add_argument('--description',
                        help="your machine's description YAML (hexapod, platform, five-axis, "
                             "grid, stage; printer: its camera gantry's, for the vision "
                             'calibrator); the simulated machine, its instrument and the '
                             'calibrator take it')
    launch.set_defaults(func=deferred('graphs_run', 'cmd_launch'))

    demo = sub.add_parser('demo', help=command_help('demo'))
    demo.add_argument('--out', default='out/demo', help="folder for the demo's calibrations, bags, logs and figures")
    demo.add_argument('--low-noise', action='store_true',
                      help="the simulated instruments ten times quieter than the sources' "
                           '(by default they run at the noise the sources report)')
    demo.set_defaults(func=deferred('graphs_run', 'cmd_demo'))
