"""``machine-align launch`` and ``machine-align demo``: the simulated machine graphs as
separate processes, and the end-to-end demo on them."""
from __future__ import annotations

import time
from pathlib import Path

from machine_alignment.demo import run_demo
from machine_alignment.launcher import (
    Graph, five_axis_graph, grid_graph, hexapod_graph, platform_graph, printer_graph, stage_graph,
    stop_on_sigterm)


def cmd_launch(args) -> int:
    spec = {'printer': lambda: printer_graph(args.scene, args.output_dir, args.record_dir),
            'stage': lambda: stage_graph(args.output_dir, args.record_dir),
            'hexapod': lambda: hexapod_graph(args.output_dir, args.record_dir),
            'grid': lambda: grid_graph(args.output_dir, args.record_dir),
            'platform': lambda: platform_graph(args.output_dir, args.record_dir),
            'five-axis': lambda: five_axis_graph(args.output_dir, args.record_dir)}[args.graph]()
    stop_on_sigterm()
    with Graph(spec) as graph:
        print(f'{args.graph} graph running (Ctrl-C or SIGTERM to stop)', flush=True)
        try:
            while all(graph.alive()):
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
    return 0


def cmd_demo(args) -> int:
    stop_on_sigterm()
    return run_demo(Path(args.out))


def add_parser(sub) -> None:
    launch = sub.add_parser('launch', help='start a simulated machine graph from the venv')
    launch.add_argument('graph', choices=['printer', 'stage', 'hexapod', 'grid', 'platform',
                                          'five-axis'],
                        help='printer: vision chain; stage: the printer with its stage; '
                             'hexapod; grid: the camera gantry over a grid plate; platform: '
                             'the screen-registration platform; five-axis: the dispenser')
    launch.add_argument('--scene', default='dot_plate', choices=['dot_plate', 'substrate', 'stencil'], help='what the simulated camera looks at')
    launch.add_argument('--output-dir', default='calibration', help='where the calibrators write calibration files')
    launch.add_argument('--record-dir', default='runs', help='where runs are recorded (MCAP bags)')
    launch.set_defaults(func=cmd_launch)

    demo = sub.add_parser('demo', help='calibrate the simulated printer end to end')
    demo.add_argument('--out', default='out/demo', help="folder for the demo's calibrations, bags, logs and figures")
    demo.set_defaults(func=cmd_demo)
