"""``make bench``: the benchmarks, one module per machine or method, each writing its
results files (JSON and Markdown, figures) into the folder given with ``--out``."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable


def main_with_out(run: Callable[[Path], object], description: str, argv=None) -> int:
    """The command line of a bench that takes only the results folder."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--out', default='bench_results', help='folder for the results files')
    run(Path(parser.parse_args(argv).out))
    return 0
