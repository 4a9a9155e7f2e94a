"""``make bench``: the benchmarks, one module per machine or method, each writing its
results files (JSON and Markdown, figures) into the folder given with ``--out``."""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from calib_core.figures import RUN_VARIABLE
from calib_core.storage import write_atomic

# The run the figures a bench draws name (calib_core.figures.save_figure), unless the one
# running it named it.
os.environ.setdefault(RUN_VARIABLE, time.strftime('make bench %Y-%m-%dT%H:%M:%SZ',
                                                  time.gmtime()))


def main_with_out(run: Callable[[Path], object], description: str, argv=None) -> int:
    """The command line of a bench that takes only the results folder."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--out', default='bench_results', help='folder for the results files')
    run(Path(parser.parse_args(argv).out))
    return 0


def write_results(out: Path, name: str, content) -> None:
    """``content`` as ``<out>/<name>.json`` (atomic, indented; the folder made if needed)."""
    write_atomic(out / f'{name}.json', json.dumps(content, indent=2) + '\n')


def write_table(out: Path, name: str, lines: list) -> None:
    """``lines`` as ``<out>/<name>.md`` (atomic), and printed for the one running it."""
    write_atomic(out / f'{name}.md', '\n'.join(lines) + '\n')
    print('\n'.join(lines))


def detection_case(case: str, seeds, analyse: Callable[[int], dict],
                   judge: Callable[[dict], dict], clean_after: dict) -> dict:
    """One case of a closed-loop detection bench: per seed, ``analyse(seed)`` (the loop's
    report, CPU timed) judged by ``judge(report)`` (a dict with ``found``,
    ``wrong_claims``, ``rms_after``), and its held-out RMS after over the clean run's of
    the same seed (``clean_after``, filled while ``case`` is ``'clean'``, which runs first).
    Returns the runs, the counts and the medians."""
    runs, cpu = [], []
    for seed in seeds:
        start = time.process_time()
        report = analyse(seed)
        cpu.append(time.process_time() - start)
        judged = judge(report)
        if case == 'clean':
            clean_after[seed] = report['rms_after']
        judged['after_over_floor'] = judged['rms_after'] / clean_after[seed]
        runs.append(judged)
        print(f'{case}, seed {seed}: found {judged["found"]}, wrong claims '
              f'{judged["wrong_claims"]}', flush=True)
    return {'runs': len(runs), 'found': sum(r['found'] for r in runs),
            'wrong_claims': sum(r['wrong_claims'] for r in runs),
            'median_after_over_floor': float(np.median([r['after_over_floor'] for r in runs])),
            'median_cpu_s': float(np.median(cpu)), 'per_run': runs}
