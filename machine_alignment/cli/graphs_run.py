"""The work of the subcommands ``graphs.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

from calib_core.errors import CalibrationError
from machine_alignment.demo import run_demo
from machine_alignment.launcher import (
    Graph, describe_exit, five_axis_graph, grid_graph, hexapod_graph, platform_graph,
    printer_graph, stage_graph, stop_on_sigterm)


def cmd_launch(args) -> int:
    described = {'hexapod': 'hexapod_calib.core.description',
                 'platform': 'platform_calib.core.description',
                 'five-axis': 'dispenser_calib.core.description',
                 'printer': 'printer_alignment.core.vision_description',
                 'stage': 'printer_alignment.core.stage_description',
                 'grid': 'grid_calib.core.description'}
    description = ''
    if args.description:
        # Read here first: a file the nodes would refuse is refused before any starts.
        reader = importlib.import_module(described[args.graph])
        reader.read_description(args.description)
        description = str(Path(args.description).resolve())
    spec = {'printer': lambda: printer_graph(args.scene, args.output_dir, args.record_dir,
                                             description=description),
            'stage': lambda: stage_graph(args.output_dir, args.record_dir,
                                         description=description),
            'hexapod': lambda: hexapod_graph(args.output_dir, args.record_dir, description),
            'grid': lambda: grid_graph(args.output_dir, args.record_dir,
                                       description=description),
            'platform': lambda: platform_graph(args.output_dir, args.record_dir,
                                               description=description),
            'five-axis': lambda: five_axis_graph(args.output_dir, args.record_dir,
                                                 description=description)}[args.graph]()
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
