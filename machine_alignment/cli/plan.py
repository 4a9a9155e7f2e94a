"""``machine-align plan platform|hexapod|five-axis|stage``: the poses to measure for an
identification, chosen before anything moves, with what they are predicted to give."""
from __future__ import annotations

from dispenser_calib.core.planning import DEPTH_OF_FIELD
from machine_alignment.cli import command_help, deferred
from machine_alignment.cli.common import ranged
from printer_alignment.core.stage import CAMERA_NOISE, LANDING_SIGMA


def add_parser(sub) -> None:
    plan = sub.add_parser('plan', help=command_help('plan'))
    what = plan.add_subparsers(dest='what', required=True)
    _add_platform(what)
    _add_hexapod(what)
    _add_five_axis(what)
    _add_stage(what)


def _add_platform(what) -> None:
    platform = what.add_parser('platform', help='poses for the platform\'s identification')
    platform.add_argument('--poses', type=ranged(int, 6, 10000), required=True,
                          help='how many poses to measure (at least 6 for 18 parameters)')
    platform.add_argument('--geometry', help='nominal geometry YAML (default: the built-in)')
    platform.add_argument('--description', help="your machine's description YAML: poses in its "
                                                'workspace, predicted at its tracker\'s and '
                                                "feeds' noise")
    platform.add_argument('--working', help='CSV x, y (m), theta (rad): the poses the '
                                            'platform will work at (default: 200 random '
                                            'within +-5 mm, +-5 deg)')
    platform.add_argument('--criterion', choices=('I', 'D'), default='I',
                          help='I: least predicted error at the working poses (default); '
                               'D: largest determinant of the information')
    platform.add_argument('--candidates', type=ranged(int, 10, 100000), default=3000,
                          help='random candidate poses to choose from')
    platform.add_argument('--margin', type=ranged(float, 0.0, 0.1, 'm'), default=2e-3,
                          help='keep the feeds this far inside the stroke (the true platform '
                               'is not the nominal one), m')
    platform.add_argument('--seed', type=ranged(int, 0), default=0)
    platform.add_argument('--out', required=True, help='plan CSV to write (x, y, theta)')
    platform.add_argument('--json', help='the prediction to write')
    platform.set_defaults(func=deferred('plan_run', 'cmd_plan_platform'))


def _add_hexapod(what) -> None:
    hexapod = what.add_parser('hexapod', help='poses for the hexapod\'s identification')
    hexapod.add_argument('--poses', type=ranged(int, 7, 10000), required=True,
                         help='how many poses to measure (at least 7; 13 or more)')
    hexapod.add_argument('--geometry', help='nominal geometry YAML (default: the built-in)')
    hexapod.add_argument('--description', help='your machine\'s description YAML: its '
                                               'geometry, workspace (home, box, strokes) and '
                                               'instrument noise plan the poses')
    hexapod.add_argument('--candidates', type=ranged(int, 20, 10000), default=400,
                         help='random candidate poses inside the strokes to choose from')
    hexapod.add_argument('--position-noise', type=ranged(float, 0.0, 0.01, 'm'),
                         help='pose sensor, m per axis (1 sigma; default the description\'s '
                              'or 0.6 um)')
    hexapod.add_argument('--angle-noise', type=ranged(float, 0.0, 0.1, 'rad'),
                         help='pose sensor, rad per axis (1 sigma; default the description\'s '
                              'or 6 urad)')
    hexapod.add_argument('--actuator-noise', type=ranged(float, 0.0, 1e-3, 'm'),
                         help='how far a leg stops from where it is sent, m (1 sigma; default '
                              'the description\'s or 0.5 um)')
    hexapod.add_argument('--criterion', choices=('greedy', 'I', 'D'), default='greedy',
                         help='greedy: each leg\'s information determinant (the calibrator\'s '
                              'default); I: least pose error over the box; D: largest '
                              'determinant, both by the shared exchange')
    hexapod.add_argument('--seed', type=ranged(int, 0), default=0)
    hexapod.add_argument('--out', required=True, help='plan CSV to write (x..yaw)')
    hexapod.add_argument('--json', help='the prediction to write')
    hexapod.set_defaults(func=deferred('plan_run', 'cmd_plan_hexapod'))


def _add_five_axis(what) -> None:
    five_axis = what.add_parser('five-axis', help='stops for the five-axis dispenser\'s '
                                                  'vision calibration')
    five_axis.add_argument('--stops', type=ranged(int, 8, 124), required=True,
                           help='how many stops to image (at least 8: the stepwise start\'s '
                                '4 linear and 2 for each rotary axis alone)')
    five_axis.add_argument('--calibration', help='five-axis calibration YAML to plan about '
                                                 '(default: the nominal model)')
    sized = five_axis.add_mutually_exclusive_group()
    sized.add_argument('--image-size', help='WxH px (default 2448x2048)')
    sized.add_argument('--description', help='machine description YAML (kind: five_axis): '
                                             'its camera, working distance, strokes and dot '
                                             'noise')
    five_axis.add_argument('--criterion', choices=('I', 'D'), default='I',
                           help='I: least predicted placement error of the part at the '
                                'working poses (default); D: largest determinant')
    five_axis.add_argument('--noise-px', type=ranged(float, 1e-4, 10.0, 'px'),
                           help='dot detection noise, px (1 sigma per coordinate; default: '
                                'the description\'s, else 0.1)')
    five_axis.add_argument('--depth-of-field', type=ranged(float, 0.0, 0.05, 'm'),
                           default=DEPTH_OF_FIELD,
                           help='how far Z may take the board from focus either way, m '
                                '(the lens\'s depth of field; the simulation has none)')
    five_axis.add_argument('--seed', type=ranged(int, 0), default=0,
                           help='draw of the working poses')
    five_axis.add_argument('--out', required=True,
                           help='plan CSV to write (stop, x_m, y_m, z_m, a_rad, c_rad)')
    five_axis.add_argument('--json', help='the prediction to write')
    five_axis.set_defaults(func=deferred('plan_run', 'cmd_plan_five_axis'))


def _add_stage(what) -> None:
    stage = what.add_parser('stage', help='stops for the XY-Theta stage\'s calibration run')
    stage.add_argument('--stops', type=ranged(int, 1, 729), required=True,
                       help='stops to choose beside home and the sweeps')
    stage.add_argument('--sweep-points', type=ranged(int, 3, 50), default=3,
                       help='points of each sweep each way (the stepwise start needs them)')
    stage.add_argument('--marks', type=float, nargs=4, metavar=('X1', 'Y1', 'X2', 'Y2'),
                       help='the calibration Marks\' plate positions with the stage at home, '
                            'm (the calibrator\'s calibration_marks; default 0.0351 0.0791 '
                            '0.1551 0.0797, or the description\'s Marks)')
    stage.add_argument('--description', help='your stage\'s description YAML: its guides, '
                                             'Marks, stroke, camera and landing noise')
    stage.add_argument('--criterion', choices=('I', 'D'), default='I',
                       help='I: least Mark error at the working inputs; D: D-optimal')
    stage.add_argument('--landing-sigma', type=ranged(float, 0.0, 1e-3, 'm'),
                       help=f'a chain\'s landing repeatability, m (default: the '
                            f'description\'s, else {LANDING_SIGMA:g})')
    stage.add_argument('--camera-noise', type=ranged(float, 1e-9, 1e-3, 'm'),
                       help=f'a measured Mark coordinate\'s noise, m (default: the '
                            f'description\'s, else {CAMERA_NOISE:g})')
    stage.add_argument('--out', required=True, help='plan CSV to write (q1, q2, q3)')
    stage.add_argument('--json', help='the prediction to write')
    stage.set_defaults(func=deferred('plan_run', 'cmd_plan_stage'))
