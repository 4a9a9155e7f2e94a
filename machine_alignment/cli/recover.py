"""``machine-align recover BAG``: a run cut by a kill or a power loss (its bag directory
holds the journal, no metadata.yaml) written as a complete MCAP bag beside it, for the
tools that read only complete bags (Foxglove, ``ros2 bag play``). This suite's own
commands read the cut run as it is."""
from __future__ import annotations

from calib_core.bags import cut_run_count, recover_cut_run
from machine_alignment.cli import command_help


def add_parser(sub) -> None:
    parser = sub.add_parser('recover', help=command_help('recover'))
    parser.add_argument('bag', help='the cut run\'s bag directory')
    parser.add_argument('--out', help='the complete bag to write (default <bag>_recovered)')
    parser.set_defaults(func=cmd_recover)


def cmd_recover(args) -> int:
    count = cut_run_count(args.bag)
    out = recover_cut_run(args.bag, args.out)
    print(f'{count} messages of the cut run {args.bag} written to {out}')
    return 0
