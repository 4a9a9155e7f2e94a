"""``machine-align analyze <machine>``: the closed loop on a dataset. Find the effect the
model lacks, refit, report before and after on held-out rows; for an axis also the ISO
230-2 figures and a compensation table."""
from __future__ import annotations

from machine_alignment.cli import command_help
from machine_alignment.cli.common import ranged

# The length units a dataset may be read in: calib_core.description.LENGTH_UNITS's, listed
# here so that --help does not import the science stack (test_data_units holds them equal).
LENGTH_UNITS = ('m', 'mm', 'um', 'inch')

FORMATS = {'axis': 'CSV: command, measured (m), direction (+1/-1), or command, error '
                   '(measured - command) and direction; optional cycle, '
                   'sequence (approach number), block/setup/run (labels), time (s), '
                   'temperature (K)',
           'gantry': 'CSV: command_x, command_y, measured_x, measured_y (m); optional '
                     'direction_x, direction_y, time, temperature',
           'camera': 'CSV: view, model_x, model_y (m), u, v (px)',
           'stage': 'CSV: q1..q3 (m), mark1_x, mark1_y, mark2_x, mark2_y (m, plate '
                    'frame); optional direction1..3, time, temperature',
           'platform': 'CSV: feed1..feed3 (m), x, y (m), theta (rad); optional '
                       'direction1..direction3, time, temperature',
           'hexapod': 'CSV: x..yaw, meas_x..meas_yaw (m, rad); optional l1..l6 (m), '
                      'force1..force6 (N, compression positive), direction1..direction6, '
                      'time, temperature',
           'rotary': 'CSV: a, c (rad; other names with --a-column, --c-column), x, y, z (m, '
                     'target origin in the instrument frame), qw, qx, qy, qz (instrument to '
                     'target); optional time (s), temperature (K)'}


def cmd_analyze(args) -> int:
    from machine_alignment.cli.analyze_run import cmd_analyze as run
    return run(args)


def cmd_analyze_grid(args) -> int:
    from machine_alignment.cli.analyze_run import cmd_analyze_grid as run
    return run(args)


def add_parser(sub) -> None:
    analyze_parser = sub.add_parser('analyze', help=command_help('analyze'))
    machines = analyze_parser.add_subparsers(dest='machine', required=True)
    for name, help_text in FORMATS.items():
        machine = machines.add_parser(name, help=help_text)
        machine.add_argument('--data', required=True, help=help_text)
        machine.add_argument('--json', help='report to write; the plot goes beside it (.png), '
                                            'for an axis also the ISO 230-2 plot and the '
                                            'compensation table (CSV and LinuxCNC file)')
        machine.add_argument('--holdout', type=ranged(float, 0.05, 0.6), default=0.3,
                             help='fraction of rows kept out of every fit')
        machine.add_argument('--alpha', type=ranged(float, 1e-12, 0.5), default=1e-3, help='significance level')
        machine.add_argument('--max-effects', type=ranged(int, 0, 20), default=4, help='most effects the loop may add')
        machine.add_argument('--seed', type=ranged(int, 0), default=0, help='of the first hold-out split')
        machine.add_argument('--splits', type=ranged(int, 1, 50), default=5,
                             help='hold-out splits the selection is repeated over')
        machine.add_argument('--min-effect', type=ranged(float, 0), default=None,
                             help='smallest effect worth adding, RMS in the residual unit '
                                  '(m; px for the camera); default: the machine\'s')
        if name == 'camera':
            machine.add_argument('--image-size', help='WxH in px (default: inferred from the data)')
        if name in ('axis', 'gantry', 'rotary', 'camera'):
            machine.add_argument('--length-unit', choices=LENGTH_UNITS, default='m',
                                 help='the unit of the positions (the camera: the target\'s '
                                      'points) in --data (default: m, the format\'s); the '
                                      'report is in m')
        if name == 'axis':
            machine.add_argument('--error-unit', choices=LENGTH_UNITS, default=None,
                                 help='the unit of an error column (default: --length-unit)')
        if name == 'rotary':
            machine.add_argument('--angle-unit', choices=('rad', 'deg'), default='rad',
                                 help='the unit of the A and C columns (default: rad)')
        if name == 'axis':
            machine.add_argument('--machine-units', choices=('mm', 'inch'), default='mm',
                                 help='units of the LinuxCNC compensation file written beside '
                                      'the JSON (the machine\'s units)')
        if name == 'stage':
            machine.add_argument('--description', help='your stage\'s description YAML '
                                                       '(q1..q3 in its actuators\' unit)')
        if name == 'platform':
            described = machine.add_mutually_exclusive_group()
            described.add_argument('--geometry', help='nominal geometry YAML (default: built-in)')
            described.add_argument('--description', help='your machine\'s description YAML '
                                                          '(feed1..feed3 in its actuators\' unit)')
        if name == 'rotary':
            machine.add_argument('--a-column', default='a', help='the tilt axis A\'s column')
            machine.add_argument('--c-column', default='c', help='the rotary table C\'s column')
            machine.add_argument('--calibration',
                                 help='five-axis calibration YAML: --data is then a five-axis '
                                      'observations CSV of a sweep with the linear axes held '
                                      '(simulate five-axis --sweep), the board\'s pose in '
                                      'each image is the target pose')
            machine.add_argument('--lever', type=ranged(float, 1e-3, 10.0, 'm'), default=None,
                                 help='m: orientation errors count as the displacement of a '
                                      'point this far from the target origin (default: the '
                                      'rotary loop\'s, dispenser_calib.core.rotary.LEVER)')
        if name == 'hexapod':
            described = machine.add_mutually_exclusive_group(required=True)
            described.add_argument('--geometry', help='nominal geometry YAML')
            described.add_argument('--description', help='your machine\'s description YAML '
                                                          '(l1..l6 in its actuators\' unit)')
            machine.add_argument('--payload', type=float, nargs=4,
                                 metavar=('MASS', 'X', 'Y', 'Z'),
                                 help='payload mass (kg) and centre of mass (m, platform '
                                      'frame): leg forces for leg_play and compliance')
        machine.set_defaults(func=cmd_analyze)
    grid = machines.add_parser('grid', help='the closed loop on a grid self-calibration '
                                            '(marks CSV, optional time and temperature)')
    grid.add_argument('--data', required=True, help='marks CSV of calibrate grid, with time '
                                                    '(s) and temperature (K) if logged')
    plate = grid.add_mutually_exclusive_group(required=True)
    plate.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'),
                       help='nominal plate pitch, m')
    plate.add_argument('--description', help='your setup\'s description YAML: its plate and '
                                             'the unit x, y are in')
    grid.add_argument('--region', type=ranged(int, 0), help='one region (default: each)')
    grid.add_argument('--min-effect', type=ranged(float, 0), default=5e-9,
                      help='smallest effect worth adding, RMS over the readings, m')
    grid.add_argument('--json', help='report to write')
    grid.set_defaults(func=cmd_analyze_grid)
