"""``machine-align calibrate vision|stage|hexapod`` (and ``camera``, in camera.py): rerun
a calibration offline from a recorded run or a dataset, with the code the nodes use."""
from __future__ import annotations

from machine_alignment.cli import camera, five_axis, grid, platform
from machine_alignment.cli import command_help, deferred
from machine_alignment.cli.common import ranged


def add_parser(sub) -> None:
    calibrate = sub.add_parser('calibrate', help=command_help('calibrate'))
    what = calibrate.add_subparsers(dest='what', required=True)
    camera.add_parser(what)
    grid.add_parser(what)
    platform.add_calibrate_parser(what)
    five_axis.add_calibrate_parser(what)
    vision = what.add_parser('vision', help='pixel size and gantry model from a recorded run')
    vision.add_argument('--bag', required=True, help='a run recorded by vision_calibrator/calibrate')
    plate = vision.add_mutually_exclusive_group()
    plate.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'),
                       help='dot pitch, m (default: the live run\'s, or the description\'s)')
    plate.add_argument('--description',
                       help='your camera gantry\'s description YAML: the lens, screws and dot '
                            'plate the run is solved and gated with (default: what the live '
                            'run recorded)')
    vision.add_argument('--json', help='report to write (JSON, SI units)')
    vision.set_defaults(func=deferred('calibrate_run', 'cmd_calibrate_vision'))

    stage = what.add_parser('stage', help='XY-Theta stage: stepwise and parametric, from a '
                                          'recorded run or a stage CSV')
    stage_source = stage.add_mutually_exclusive_group(required=True)
    stage_source.add_argument('--bag', help='a run recorded by stage_calibrator')
    stage_source.add_argument('--data', help='CSV: q1..q3 (m), direction1..3, mark1_x, '
                                             'mark1_y, mark2_x, mark2_y (m)')
    stage.add_argument('--description', help='your stage\'s description YAML: q1..q3 read in '
                                             'its actuators\' unit, the gate from its camera '
                                             'and landing noise (docs/machine_description.md)')
    stage.add_argument('--json', help='report to write (JSON, SI units)')
    stage.set_defaults(func=deferred('calibrate_run', 'cmd_calibrate_stage'))

    hexapod = what.add_parser('hexapod', help='42-parameter hexapod geometry from measured poses')
    hexapod_source = hexapod.add_mutually_exclusive_group(required=True)
    hexapod_source.add_argument('--data', help='CSV: x..yaw, meas_x..meas_yaw (m, rad), '
                                               'optional l1..l6 (m)')
    hexapod_source.add_argument('--bag', help='a run recorded by hexapod_calibrator')
    hexapod.add_argument('--geometry', help='nominal geometry YAML (with --bag: default the '
                                            'one the run recorded)')
    hexapod.add_argument('--description', help='your machine\'s description YAML (geometry, '
                                               'instrument, actuators and their unit, '
                                               'repeatability): the gate then checks against '
                                               'it; l1..l6 in the actuators\' unit')
    hexapod.add_argument('--out', help='calibrated geometry YAML to write')
    hexapod.add_argument('--fix', nargs='*', help='parameter names to keep at their nominal value')
    hexapod.add_argument('--json', help='report to write (JSON, SI units)')
    hexapod.set_defaults(func=deferred('calibrate_run', 'cmd_calibrate_hexapod'))
