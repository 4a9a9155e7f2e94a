"""``machine-align launch`` and ``machine-align demo``: the simulated machine graphs as
separate processes, and the end-to-end demo on them."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from calib_core.errors import CalibrationError
from machine_alignment.cli import command_help
from machine_alignment.demo import run_demo
from machine_alignment.launcher import (
    Graph, describe_exit, five_axis_graph, grid_graph, hexapod_graph, platform_graph,
    printer_graph, stage_graph, stop_on_sigterm)


def cmd_launch(args) -> int:
    spec = {'printer': lambda: printer_graph(args.scene, args.output_dir, args.record_dir),
            'stage': lambda: stage_graph(args.output_dir, args.record_dir),
            'hexapod': lambda: hexapod_graph(args.output_dir, args.record_dir),
            'grid': lambda: grid_graph(args.output_dir, args.record_dir),
            'platform': lambda: platform_graph(args.output_dir, args.record_dir),
            'five-axis': lambda: five_axis_graph(args.output_dir, args.record_dir)}[args.graph]()
    stop_on_sigterm()
    graph = Graph(spec)
    dead = []
    try:
        print(f'{args.graph} graph running: {", ".join(graph.names)} (Ctrl-C or SIGTERM to '
              'stop)', flush=True)
        while not (dead := graph.exited()):
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        graph.stop()
    for line in graph.escalations:
        print(f'machine-align launch: {line}', file=sys.stderr)
    if dead:
        # A graph with a node missing cannot calibrate: stop all of it and say which died.
        raise CalibrationError(
            'the ' + args.graph + ' graph stopped because '
            + '; '.join(f'{name} ended ({describe_exit(code)})' for name, code in dead)
            + '; the other nodes were stopped. See that node\'s output above.')
    return 0


def cmd_demo(args) -> int:
    stop_on_sigterm()
    return run_demo(Path(args.out), args.low_noise)


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
    launch.set_defaults(func=cmd_launch)

    demo = sub.add_parser('demo', help=command_help('demo'))
    demo.add_argument('--out', default='out/demo', help="folder for the demo's calibrations, bags, logs and figures")
    demo.add_argument('--low-noise', action='store_true',
                      help="the simulated instruments ten times quieter than the sources' "
                           '(by default they run at the noise the sources report)')
    demo.set_defaults(func=cmd_demo)
