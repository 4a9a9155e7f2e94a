"""``machine-align simulate|calibrate|compensate platform``: the 3-DOF screen-registration
platform (issue 22): pose data from the simulated platform, the 18-parameter
identification, and the feed compensation by the exact inverse, Levenberg-Marquardt or
the source's particle swarm, with plots."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred
from machine_alignment.cli.common import ranged


def add_simulate_parser(simulated) -> None:
    platform = simulated.add_parser('platform', help='poses of the simulated screen-'
                                                     'registration platform (tracker, feeds)')
    platform.add_argument('--out', required=True, help='poses CSV to write')
    platform.add_argument('--poses', type=ranged(int, 1, 100000), default=20,
                          help='random poses within +-5 mm, +-5 deg')
    platform.add_argument('--plan', help='measure these targets instead (CSV x, y, theta: '
                                         'machine-align plan platform writes one)')
    platform.add_argument('--seed', type=ranged(int, 0), default=0)
    platform.add_argument('--scale', type=ranged(float, 0.0, 10.0, '', 'of the simulated geometry errors (1: up to 1 mm, 0.5 deg)'), default=0.15,
                          help='size of the true parameter errors (1: 0.2-1 mm, 0.5 deg)')
    platform.add_argument('--truth', help='also write the true geometry (YAML)')
    platform.add_argument('--screw', type=ranged(float, 0.0, 1e-3, 'm'), default=0.0,
                          help='ball-screw periodic error of every feed, m (5 mm lead; an '
                               'effect the model lacks, e.g. 10e-6)')
    platform.add_argument('--backlash', type=ranged(float, 0.0, 1e-3, 'm'), default=0.0,
                          help='backlash of every feed, m (e.g. 8e-6)')
    platform.add_argument('--lead-ratio', type=ranged(float, 0.5, 2.0), nargs=3,
                          default=(1.0, 1.0, 1.0), metavar=('R1', 'R2', 'R3'),
                          help="each feed's true lead over its nominal (1.06: 6 %% long; the "
                               'sensors read the nominal)')
    platform.add_argument('--description', help="your machine's description YAML (geometry, "
                                                'tracker, feeds\' unit, workspace; '
                                                'docs/machine_description.md)')
    platform.set_defaults(func=deferred('platform_run', 'cmd_simulate_platform'))


def add_calibrate_parser(what) -> None:
    platform = what.add_parser('platform', help='the 18 parameters of the screen-registration '
                                                'platform from tracker poses and feeds')
    source = platform.add_mutually_exclusive_group(required=True)
    source.add_argument('--data', help='CSV: feed1..feed3 (m), x, y (m), theta (rad)')
    source.add_argument('--bag', help='a run recorded by platform_calibrator')
    platform.add_argument('--geometry', help='nominal geometry YAML (default: the built-in)')
    platform.add_argument('--description', help="your machine's description YAML: its geometry, "
                                                "and the gate from its tracker's and feeds' "
                                                "noise; feeds read in the actuators' unit")
    platform.add_argument('--out', help='identified geometry YAML to write')
    platform.add_argument('--json', help='report to write')
    platform.set_defaults(func=deferred('platform_run', 'cmd_calibrate_platform'))


def add_compensate_parser(sub) -> None:
    # Imported here: only `compensate` needs the compensation's methods.
    from platform_calib.core.compensation import METHODS
    compensate_parser = sub.add_parser('compensate', help=command_help('compensate'))
    what = compensate_parser.add_subparsers(dest='what', required=True)
    platform = what.add_parser('platform', help='the screen-registration platform')
    platform.add_argument('--geometry', required=True, help='identified geometry YAML')
    platform.add_argument('--nominal', help='nominal geometry YAML (the controller\'s; '
                                            'default: the built-in)')
    platform.add_argument('--method', choices=METHODS, default='exact')
    platform.add_argument('--targets', help='CSV: x, y (m), theta (rad); default: random '
                                            'targets over the workspace')
    platform.add_argument('--count', type=ranged(int, 1, 100000), default=50, help='random targets')
    platform.add_argument('--swarm', choices=('source', 'stable'), default='source',
                          help='source: 40 particles, c1 = c2 = 2, w = 0.8; stable: Clerc')
    platform.add_argument('--iterations', type=ranged(int, 1, 100000), help='swarm iterations (source 4, stable 200)')
    platform.add_argument('--seed', type=ranged(int, 0), default=0)
    platform.add_argument('--json', help='report to write; the plot goes beside it')
    platform.add_argument('--csv', help='feeds per target to write (x_m, y_m, theta_rad, '
                                        'feed1_m, feed2_m, feed3_m, converged)')
    platform.set_defaults(func=deferred('platform_run', 'cmd_compensate_platform'))
