"""``make bench``: the benchmarks, one module per machine or method, each writing its
results files (JSON and Markdown, figures) into the folder given with ``--out``."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable

from calib_core.storage import write_atomic


def main_with_out(run: Callable[[Path], object], description: str, argv=None) -> int:
    """The command line of a bench that takes only the results folder."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--out', default='bench_results', help='folder for the results files')
    run(Path(parser.parse_args(argv).out))
    return 0


def write_table(out: Path, name: str, lines: list) -> None:
    """``lines`` as ``<out>/<name>.md`` (atomic), and printed for the one running it."""
    write_atomic(out / f'{name}.md', '\n'.join(lines) + '\n')
    print('\n'.join(lines))
