"""``machine-align evaluate hexapod|platform|five-axis|alignment``: check a calibration on data not
used to fit it (a pose file, or the truth a simulation wrote), or plan recorded alignments
again from their bag."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred
from machine_alignment.cli.common import ranged


def add_parser(sub) -> None:
    evaluate = sub.add_parser('evaluate', help=command_help('evaluate'))
    evaluated = evaluate.add_subparsers(dest='what', required=True)
    hexapod_eval = evaluated.add_parser('hexapod', help='pose errors of a geometry on a pose file')
    hexapod_eval.add_argument('--data', required=True, help='pose CSV (as for calibrate hexapod)')
    hexapod_eval.add_argument('--geometry', required=True, help='calibrated geometry YAML')
    hexapod_eval.add_argument('--nominal', help='geometry the controller used, when the CSV has '
                                                'no l1..l6 columns')
    hexapod_eval.add_argument('--description', help='your machine\'s description YAML: l1..l6 '
                                                    'in its actuators\' unit')
    hexapod_eval.add_argument('--json', help='report to write (JSON, SI units)')
    hexapod_eval.set_defaults(func=deferred('evaluate_run', 'cmd_evaluate_hexapod'))
    platform_eval = evaluated.add_parser(
        'platform', help='mark errors of an identified platform against a true geometry '
                         '(what simulate platform --truth writes)')
    platform_eval.add_argument('--geometry', required=True, help='identified geometry YAML')
    platform_eval.add_argument('--truth', required=True, help='the true geometry YAML')
    platform_eval.add_argument('--nominal', help='nominal geometry YAML (default: the built-in)')
    platform_eval.add_argument('--working', help='CSV x, y (m), theta (rad) of the working '
                                                 'poses (default: random within +-5 mm, +-5 deg)')
    platform_eval.add_argument('--count', type=ranged(int, 1, 100000), default=200,
                               help='random working poses')
    platform_eval.add_argument('--seed', type=ranged(int, 0), default=0)
    platform_eval.add_argument('--json', help='report to write (JSON, SI units)')
    platform_eval.set_defaults(func=deferred('evaluate_run', 'cmd_evaluate_platform'))
    five_axis_eval = evaluated.add_parser(
        'five-axis', help='reprojection of a five-axis calibration against a true model '
                          '(what simulate five-axis --truth writes)')
    five_axis_eval.add_argument('--calibration', required=True, help='calibrated model YAML')
    five_axis_eval.add_argument('--truth', required=True, help='the true model YAML')
    five_axis_eval.add_argument('--count', type=ranged(int, 1, 10000), default=50,
                                help='stops with A and C turned')
    five_axis_eval.add_argument('--seed', type=ranged(int, 0), default=0)
    five_axis_eval.add_argument('--description', help='machine description YAML (kind: '
                                                      'five_axis): its nominal, camera and '
                                                      'strokes')
    five_axis_eval.add_argument('--json', help='report to write (JSON)')
    five_axis_eval.set_defaults(func=deferred('evaluate_run', 'cmd_evaluate_five_axis'))
    grid_eval = evaluated.add_parser(
        'grid', help='a grid self-calibration\'s stage error map against a reference map '
                     '(an interferometer\'s, or what simulate grid --truth writes)')
    grid_eval.add_argument('--report', required=True, help='JSON report of calibrate grid')
    grid_eval.add_argument('--reference', required=True,
                           help='CSV x, y, error_x, error_y (m) of the reference map')
    grid_eval.add_argument('--json', help='report to write (JSON, SI units)')
    grid_eval.set_defaults(func=deferred('evaluate_run', 'cmd_evaluate_grid'))
    alignment_eval = evaluated.add_parser(
        'alignment', help='plan recorded alignments again from their bag (aligner runs)')
    alignment_eval.add_argument('--bag', required=True, help='an alignment_<stamp> bag')
    alignment_eval.add_argument('--json', help='report to write (JSON, SI units)')
    alignment_eval.set_defaults(func=deferred('evaluate_run', 'cmd_evaluate_alignment'))
