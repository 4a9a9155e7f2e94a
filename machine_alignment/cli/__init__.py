"""machine-align: the command line of machine_alignment. It runs the same core code as
the nodes: subcommands read a dataset, image files or a recorded bag, print a human
report and write JSON (``--json PATH``, SI units)."""
from __future__ import annotations

import argparse
import sys

from calib_core.errors import MachineAlignmentError
from machine_alignment.cli import analyze, calibrate, detect, evaluate, graphs, simulate


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='machine-align', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True)
    for group in (detect, calibrate, evaluate, simulate, analyze, graphs):
        group.add_parser(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except MachineAlignmentError as exc:
        print(f'machine-align: error: {exc}', file=sys.stderr)
        return 2
