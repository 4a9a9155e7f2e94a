"""machine-align: the command line of machine_alignment. It runs the same core code as
the nodes: subcommands read a dataset, image files or a recorded bag, print a human
report and write JSON (``--json PATH``, SI units).

Only the subcommand asked for is imported (its science stack with it): ``--help`` and a
subcommand's own help start at once."""
from __future__ import annotations

import argparse
import importlib
import sys

from calib_core.errors import MachineAlignmentError

# subcommand -> (module under machine_alignment.cli, its function registering the parser,
# the one-line help listed by ``machine-align --help``)
COMMANDS = {
    'detect': ('detect', 'add_parser', 'Mark centres (px) in image files'),
    'calibrate': ('calibrate', 'add_parser', 'run a calibration offline'),
    'evaluate': ('evaluate', 'add_parser', 'check a calibration on data not used to fit it'),
    'simulate': ('simulate', 'add_parser', 'write datasets measured on a simulated machine'),
    'analyze': ('analyze', 'add_parser', 'closed loop: find the effect a model lacks, refit, '
                                         'report before/after on held-out data'),
    'plan': ('plan', 'add_parser', 'choose the measurements for a calibration and predict '
                                   'their result before anything moves'),
    'export': ('export', 'add_parser', 'a recorded calibration run as the CSV that analyze '
                                       'and calibrate --data read'),
    'recover': ('recover', 'add_parser', 'a run cut by a kill written as a complete bag for '
                                         'Foxglove and ros2 bag'),
    'call': ('call', 'add_parser', 'trigger a service on a running graph (calibrate, '
                                   'analyze_residuals, align, confirm a plate placement), '
                                   'showing its progress'),
    'launch': ('graphs', 'add_parser', 'start a simulated machine graph from the venv'),
    'demo': ('graphs', 'add_parser', 'calibrate every simulated machine end to end (printer, '
                                     'stage, hexapod, grid plate, platform, five-axis '
                                     'dispenser)'),
    'compensate': ('platform', 'add_compensate_parser', 'feeds that put the marks on target'),
    'locate': ('five_axis', 'add_locate_parser', 'a workpiece\'s features through the '
                                                 'calibrated chain'),
    'needle': ('five_axis', 'add_needle_parser', 'the needle tip from dispensed test dots '
                                                 'imaged through the calibrated chain'),
}


def deferred(module: str, function: str):
    """Subcommand function ``function`` of ``machine_alignment.cli.<module>``, imported when
    the subcommand runs: the parsers (and ``--help``) never load the science stack behind
    it."""
    def run(args):
        return getattr(importlib.import_module(f'machine_alignment.cli.{module}'),
                       function)(args)
    run.__name__ = run.__qualname__ = function
    return run


def command_help(name: str) -> str:
    """The one-line help of subcommand ``name``: the same in ``--help``'s list, whether the
    subcommand's module was imported or not."""
    return COMMANDS[name][2]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with ``command``'s subcommand in full (its module imported) and every
    other listed by name and help only; every subcommand in full with ``command`` 'all'."""
    parser = argparse.ArgumentParser(prog='machine-align', description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    wanted = list(COMMANDS) if command == 'all' else [command] if command in COMMANDS else []
    for name in wanted:
        if name not in sub.choices:
            module, register, _ = COMMANDS[name]
            getattr(importlib.import_module(f'machine_alignment.cli.{module}'), register)(sub)
    for name, (_, _, help_text) in COMMANDS.items():
        if name not in sub.choices:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser


def _command(argv) -> str | None:
    """The subcommand named in ``argv`` (its first word that is not an option)."""
    return next((word for word in argv if not word.startswith('-')), None)


def main(argv=None) -> int:
    """Run one subcommand. Every failure ends in one line ``machine-align: error: ...``
    naming the file or input and the cause, and exit status 2 (3 for a bug, which is
    reported the same way rather than as a traceback)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command(argv)).parse_args(argv)
    import cv2
    from machine_alignment.cli.common import check_writable
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
    except KeyboardInterrupt:
        return _fail('interrupted (Ctrl-C)', 130)
    except Exception as exc:  # a bug: still one line, with what to report
        return _fail(f'internal error {exc!r}; please report it with the command line', 3)


def _fail(message: str, status: int = 2) -> int:
    print(f'machine-align: error: {message}', file=sys.stderr)
    return status
