"""``machine-align simulate|calibrate five-axis`` and ``machine-align locate``: the
five-axis dispenser's vision calibration from board images (observations CSV) and the
localisation of a workpiece's features through the calibrated chain (issue 23)."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred
from machine_alignment.cli.common import ranged


def add_simulate_parser(simulated) -> None:
    p = simulated.add_parser('five-axis', help='board images of the simulated five-axis '
                                               'dispenser (observations CSV)')
    p.add_argument('--out', required=True)
    p.add_argument('--seed', type=ranged(int, 0), default=0)
    p.add_argument('--description', help='machine description YAML (kind: five_axis): its '
                                         'camera, working distance, strokes and dot noise; '
                                         'poses written in its actuators\' units')
    p.add_argument('--noise', type=ranged(float, 0.0, 50.0, 'px'),
                   help='dot-centre noise, px (default: the description\'s, else 0.1)')
    p.add_argument('--bad-fraction', type=ranged(float, 0.0, 0.5, '', 'RANSAC needs most images good'), default=0.05,
                   help='images with a mis-detected dot')
    p.add_argument('--plan', help='CSV of the stops to image (machine-align plan five-axis; '
                                  'default: the stepwise plan)')
    p.add_argument('--truth', help='also write the true model (YAML)')
    p.add_argument('--features', help='also write the views of a part\'s features that locate '
                                      'reads (CSV), its CAD and path beside them')
    p.add_argument('--needle', help='also write the views of test dots the needle dispensed '
                                    '(CSV) and the poses they were dispensed at beside them')
    p.add_argument('--sweep', action='store_true',
                   help='the rotary sweep with the linear axes held (for analyze rotary '
                        '--calibration) instead of the calibration stops')
    p.add_argument('--worm', type=float, nargs=2, metavar=('AMPLITUDE', 'ORDER'),
                   help='C turns AMPLITUDE cos(ORDER c) rad beyond its reading')
    p.set_defaults(func=deferred('five_axis_run', 'cmd_simulate'))


def add_calibrate_parser(what) -> None:
    p = what.add_parser('five-axis', help='the dispenser\'s camera and kinematic chain from '
                                          'board images')
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: image, x, y, z (m), a, c (rad), i, j, u, v (px)')
    source.add_argument('--bag', help='a run recorded by five_axis_calibrator')
    sized = p.add_mutually_exclusive_group()
    sized.add_argument('--image-size', help='WxH px (default 2448x2048)')
    sized.add_argument('--description',
                       help='machine description YAML (kind: five_axis): the camera, the '
                            'units the --data poses are in, and the gate from the declared '
                            'dot noise (docs/machine_description.md)')
    p.add_argument('--out', help='calibration YAML to write')
    p.add_argument('--json', help='report to write; the plot goes beside it')
    p.set_defaults(func=deferred('five_axis_run', 'cmd_calibrate'))


def add_locate_parser(sub) -> None:
    p = sub.add_parser('locate', help=command_help('locate'))
    p.add_argument('--calibration', required=True, help='five-axis calibration YAML')
    p.add_argument('--data', required=True, help='CSV: feature, x, y, z (m), a, c (rad), u, v (px)')
    p.add_argument('--cad', help='CSV name, x_m, y_m, z_m: the features in the part\'s frame '
                                 '(fits the part\'s pose)')
    p.add_argument('--path', help='CSV name, x_m, y_m, z_m: the dispensing path in the part\'s '
                                  'frame (places it; needs --cad and --tip)')
    p.add_argument('--tip', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   help='the needle tip in the calibrated camera frame (m)')
    p.add_argument('--path-angles', type=float, nargs=2, metavar=('A', 'C'), default=(0.17, 0.8),
                   help='the table\'s tilt and turn while dispensing (rad; default 0.17 0.8)')
    p.add_argument('--csv', help='the path poses to write as a labelled CSV')
    p.add_argument('--gcode', help='the path poses to write as G-code (RS274/NGC)')
    p.add_argument('--machine-units', choices=('mm', 'inch'), default='mm',
                   help='the G-code\'s linear units (default mm)')
    p.add_argument('--feed', type=ranged(float, 1e-6, 1e6, 'units/min'), default=300.0,
                   help='the G-code\'s feed, machine units per minute (default 300)')
    p.add_argument('--json', help='positions (and the part\'s pose and path poses) to write')
    p.set_defaults(func=deferred('five_axis_run', 'cmd_locate'))


def add_needle_parser(sub) -> None:
    p = sub.add_parser('needle', help=command_help('needle'))
    p.add_argument('--calibration', required=True, help='five-axis calibration YAML')
    p.add_argument('--data', required=True,
                   help='CSV: feature (the dot), x, y, z (m), a, c (rad), u, v (px)')
    p.add_argument('--dispensed', required=True,
                   help='CSV point, x_m, y_m, z_m, a_rad, c_rad: where each dot was dispensed')
    p.add_argument('--json', help='the tip and the dots to write')
    p.set_defaults(func=deferred('five_axis_run', 'cmd_needle'))
