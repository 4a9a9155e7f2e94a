"""``machine-align simulate hexapod|stage|axis|gantry|camera|grid|platform|five-axis``: datasets measured on a simulated
machine, in the formats the calibrate and analyze subcommands read."""
from __future__ import annotations

from machine_alignment.cli import command_help, deferred
from machine_alignment.cli import five_axis, platform
from machine_alignment.cli.common import ranged


def add_parser(sub) -> None:
    simulate = sub.add_parser('simulate', help=command_help('simulate'))
    simulated = simulate.add_subparsers(dest='what', required=True)
    platform.add_simulate_parser(simulated)
    five_axis.add_simulate_parser(simulated)
    _add_hexapod(simulated)
    _add_stage(simulated)
    _add_gantry(simulated)
    _add_camera(simulated)
    _add_grid(simulated)
    _add_axis(simulated)


def _add_hexapod(simulated) -> None:
    hexapod_sim = simulated.add_parser('hexapod', help='pose files from the simulated hexapod')
    hexapod_sim.add_argument('--out', required=True, help='directory')
    hexapod_sim.add_argument('--poses', type=ranged(int, 1, 100000), default=30, help='calibration poses to measure')
    hexapod_sim.add_argument('--evaluation', type=ranged(int, 0, 100000), default=30, help='separate poses measured for the evaluation only')
    hexapod_sim.add_argument('--seed', type=ranged(int, 0), default=2, help='random seed: the same seed gives the same data')
    hexapod_sim.add_argument('--description', help='your machine\'s description YAML: its '
                                                   'geometry, workspace, strokes, instrument '
                                                   'and actuator noise and unit')
    hexapod_sim.add_argument('--joint-error', type=ranged(float, 0.0, 0.05, 'm'), default=None,
                             help='1-sigma error of the true joints and leg offsets from the '
                                  'nominal, m (default 0.1 mm)')
    hexapod_sim.add_argument('--lead-ratio', type=ranged(float, 0.5, 2.0), nargs=6,
                             metavar='R', help='true over nominal lead per leg (1.06: 6 %% '
                                               'long)')
    hexapod_sim.add_argument('--no-play', action='store_true', help='legs without joint play')
    hexapod_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_hexapod'))


def _add_stage(simulated) -> None:
    stage_sim = simulated.add_parser('stage', help='a calibration run of the simulated '
                                                    'XY-Theta stage (stage CSV)')
    stage_sim.add_argument('--out', required=True, help='CSV to write')
    stage_sim.add_argument('--no-backlash', action='store_true',
                           help='a stage without backlash (clean data for the closed loop)')
    stage_sim.add_argument('--plan', help='a planned run (plan stage\'s CSV: q1, q2, q3 m) '
                                          'instead of the sweeps and the grid')
    stage_sim.add_argument('--seed', type=ranged(int, 0), default=0, help='random seed: the same seed gives the same data')
    stage_sim.add_argument('--description',
                           help='your stage\'s description YAML: a stage of its size with '
                                'errors drawn by --seed, its stroke, Marks, camera and landing '
                                'noise; q1..q3 written in its actuators\' unit')
    stage_sim.add_argument('--truth', help='also write the true geometry (YAML, SI units)')
    stage_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_stage'))


def _add_gantry(simulated) -> None:
    gantry_sim = simulated.add_parser('gantry', help='camera gantry positions measured by the '
                                                      'calibrated camera (gantry CSV)')
    gantry_sim.add_argument('--out', required=True, help='CSV to write')
    gantry_sim.add_argument('--count', type=ranged(int, 1, 100000), default=200, help='random positions')
    gantry_sim.add_argument('--ideal', action='store_true',
                            help='a gantry without errors (clean data for the closed loop)')
    gantry_sim.add_argument('--seed', type=ranged(int, 0), default=0, help='random seed: the same seed gives the same data')
    gantry_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_gantry'))


def _add_camera(simulated) -> None:
    camera_sim = simulated.add_parser('camera', help='a tilted grid target seen by a camera '
                                                      '(correspondence CSV)')
    camera_sim.add_argument('--out', required=True, help='CSV to write')
    camera_sim.add_argument('--focal', type=ranged(float, 1.0, 1e6, 'px'), default=800.0, help='px')
    for name, default in (('k1', -0.25), ('k2', 0.08), ('p1', 0.0), ('p2', 0.0)):
        camera_sim.add_argument(f'--{name}', type=float, default=default,
                                help='OpenCV distortion coefficient (1)')
    camera_sim.add_argument('--views', type=ranged(int, 2, 1000), default=12, help='views of the target')
    camera_sim.add_argument('--noise', type=ranged(float, 0.0), default=0.05, help='px, 1 sigma')
    camera_sim.add_argument('--seed', type=ranged(int, 0), default=0, help='random seed: the same seed gives the same data')
    camera_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_camera'))


def _add_grid(simulated) -> None:
    grid_sim = simulated.add_parser('grid', help='an imperfect grid plate measured at three '
                                                  'placements on a stage (marks CSV)')
    grid_sim.add_argument('--out', required=True, help='CSV to write')
    grid_sim.add_argument('--truth', help='CSV to write the true stage error to (x, y, '
                                          'error_x, error_y in m; evaluate grid reads it)')
    grid_sim.add_argument('--half', type=ranged(int, 1, 50, 'sites', 'a (2 x 50 + 1)-site square plate is the largest simulated (memory and time)'), default=5, help='K: the plate has 2K+1 marks a side')
    grid_sim.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'), default=0.01, help='m')
    grid_sim.add_argument('--plate-error', type=ranged(float, 0.0, 1e-3, 'm'), default=1e-6, help='m RMS')
    grid_sim.add_argument('--noise', type=ranged(float, 0.0), default=20e-9, help='m, 1 sigma')
    grid_sim.add_argument('--regions', type=ranged(int, 1, 10), nargs=2, default=(1, 1),
                          metavar=('COLUMNS', 'ROWS'), help='regions over the travel')
    grid_sim.add_argument('--isotropic-scale', type=float, default=0.0,
                          help="the stage's isotropic scale error (1, e.g. 5e-6)")
    grid_sim.add_argument('--warm-up', type=float, default=1 / 3600,
                          help='the machine warms by this much during the run, K/s '
                               '(logged per reading with the time)')
    grid_sim.add_argument('--expansion', type=float, default=0.0,
                          help='thermal expansion of the stage\'s scale, 1/K (an effect the '
                               'self-calibration lacks; e.g. 10e-6)')
    grid_sim.add_argument('--seed', type=ranged(int, 0), default=0, help='random seed: the same seed '
                                                             'gives the same data')
    grid_sim.add_argument('--description',
                          help='your setup\'s description YAML: its plate, regions and '
                               'reading noise (--half, --pitch, --noise, --regions then come '
                               'from it); x, y written in its unit')
    grid_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_grid'))


def _add_axis(simulated) -> None:
    axis_sim = simulated.add_parser('axis', help='an ISO 230-2 laser-interferometer test of '
                                                  'a simulated axis')
    axis_sim.add_argument('--out', required=True, help='CSV to write')
    axis_sim.add_argument('--backlash', type=ranged(float, 0.0, 1e-3, 'm'), default=0.0, help='m')
    axis_sim.add_argument('--periodic', type=ranged(float, 0.0, 1e-3, 'm'), default=0.0, help='amplitude, m')
    axis_sim.add_argument('--pitch', type=ranged(float, 1e-6, 1.0, 'm', 'the format is SI metres'), default=0.016, help='period, m')
    axis_sim.add_argument('--expansion', type=float, default=0.0, help='1/K')
    axis_sim.add_argument('--temperature-rise', type=float, default=0.0, help='K over the test')
    axis_sim.add_argument('--travel', type=ranged(float, 1e-3, 10.0, 'm'), default=0.2, help='m')
    axis_sim.add_argument('--targets', type=ranged(int, 2, 10000), default=41, help='target positions along the travel')
    axis_sim.add_argument('--cycles', type=ranged(int, 1, 1000), default=5, help='bidirectional measurement cycles')
    axis_sim.add_argument('--seed', type=ranged(int, 0), default=0, help='random seed: the same seed gives the same data')
    axis_sim.set_defaults(func=deferred('simulate_run', 'cmd_simulate_axis'))
