"""machine-align: the command line of machine_alignment. It runs the same core code as
the nodes: subcommands read a dataset, image files or a recorded bag, print a human
report and write JSON (``--json PATH``, SI units)."""
from __future__ import annotations

import argparse
import sys

import cv2

from calib_core.errors import MachineAlignmentError
from machine_alignment.cli import (
    analyze, calibrate, call, detect, evaluate, export, five_axis, graphs, plan, platform,
    simulate)
from machine_alignment.cli.common import check_writable


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='machine-align', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True)
    for group in (detect, calibrate, evaluate, simulate, analyze, plan, export, call, graphs):
        group.add_parser(sub)
    platform.add_compensate_parser(sub)
    five_axis.add_locate_parser(sub)
    five_axis.add_needle_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run one subcommand. Every failure ends in one line ``machine-align: error: ...``
    naming the file or input and the cause, and exit status 2 (3 for a bug, which is
    reported the same way rather than as a traceback)."""
    args = build_parser().parse_args(argv)
    try:
        for option in ('json', 'out'):
            if getattr(args, option, None):
                check_writable(getattr(args, option), f'--{option}')
        return args.func(args)
    except MachineAlignmentError as exc:
        return _fail(str(exc))
    except OSError as exc:
        where = f'{exc.filename}: ' if exc.filename else ''
        return _fail(f'{where}{exc.strerror or exc}')
    except cv2.error as exc:
        return _fail(f'OpenCV refused the input: {exc.err or exc}')
    except Exception as exc:  # a bug: still one line, with what to report
        return _fail(f'internal error {exc!r}; please report it with the command line', 3)


def _fail(message: str, status: int = 2) -> int:
    print(f'machine-align: error: {message}', file=sys.stderr)
    return status
