"""`make figures`: the figures docs/ embeds, drawn by one named run of the current code.

The run is named ``figures <UTC time> at <commit>``. It runs make demo's job into
``out/figures/demo`` (its output, progress lines left out, becomes
``bench_results/demo_run.log``), the hexapod loop route of docs/demo.md and run a of the
real ISO 230-2 data (docs/closed_loop_real_data.md), and copies their figures into
``docs/figures``. Every figure carries its run and a hash of the code that drew it in its
PNG text (:func:`calib_core.figures.save_figure`); ``test/test_figures.py`` checks each
figure a page embeds against today's tree, and the demo's against the run its log names.
The figures ``make bench`` draws into ``bench_results/`` are stamped the same way.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from calib_core.figures import ROOT, RUN_VARIABLE

DEMO_LOG = ROOT / 'bench_results' / 'demo_run.log'
FIGURES = ROOT / 'docs' / 'figures'
REAL_RUN_A = ROOT / 'test' / 'data' / 'measured' / 'ecmc_iso230_2' / 'mcu1025_run_a.csv'
PROGRESS_LINE = re.compile(r'^\s+\d+/\d+ ')      # "      5/21 position 5/20: ..."
# docs/figures name -> where the run leaves it (a glob in the run's folder)
COPIES = {
    'vision_evaluation.png': 'demo/vision_evaluation.png',
    'vision_closed_loop.png': 'demo/calibration/analysis/vision_*.png',
    'stage_closed_loop.png': 'demo/calibration/analysis/stage_*.png',
    'five_axis_evaluation.png': 'demo/five_axis_evaluation.png',
    'hexapod_closed_loop.png': 'hexapod/loop.png',
    'iso230_2_run_a.png': 'iso/run_a_iso230_2.png',
}


def run_name() -> str:
    """``figures <UTC time> at <commit>``, the commit marked when the tree has changes."""
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, text=True,
                                capture_output=True, check=True).stdout.strip()
        changed = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'],
                                 cwd=ROOT, text=True, capture_output=True).stdout.strip()
        commit += ' with uncommitted changes' if changed else ''
    except (OSError, subprocess.CalledProcessError):
        commit = 'an unknown commit (no git)'
    return time.strftime('figures %Y-%m-%dT%H:%M:%SZ', time.gmtime()) + f' at {commit}'


def _command(args: list[str], env: dict, show: bool = True) -> list[str]:
    """``machine-align ARGS`` in a child process, its lines echoed (progress shown as it
    comes) and returned; a failure ends `make figures` with the command named."""
    process = subprocess.Popen([sys.executable, '-m', 'machine_alignment.cli', *args],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env=env)
    lines = []
    for line in process.stdout:
        lines.append(line.rstrip('\n'))
        if show:
            print(line, end='', flush=True)
    if process.wait():
        sys.exit(f'make figures: machine-align {" ".join(args)} failed (exit '
                 f'{process.returncode})')
    return lines


def make_figures(out: Path) -> int:
    name = run_name()
    env = {**os.environ, RUN_VARIABLE: name}
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    print(f'run: {name}', flush=True)
    demo = _command(['demo', '--out', str(out / 'demo')], env)
    kept = [line for line in demo if not PROGRESS_LINE.match(line) and line.strip()]
    DEMO_LOG.write_text(f"# make demo's job (machine-align demo), run \"{name}\" by make "
                        f"figures on {os.cpu_count()} cores, the simulated instruments at the "
                        "sources' noise; progress lines left out.\n" + '\n'.join(kept) + '\n')
    print(f'wrote {DEMO_LOG}')
    hexapod = out / 'hexapod'
    _command(['simulate', 'hexapod', '--out', str(hexapod), '--poses', '100'], env, False)
    _command(['analyze', 'hexapod', '--data', str(hexapod / 'calibration.csv'), '--geometry',
              str(hexapod / 'nominal.yaml'), '--payload', '25', '0.03', '-0.02', '0.08',
              '--json', str(hexapod / 'loop.json')], env, False)
    (out / 'iso').mkdir()
    _command(['analyze', 'axis', '--data', str(REAL_RUN_A), '--json',
              str(out / 'iso' / 'run_a.json')], env, False)
    for target, pattern in COPIES.items():
        found = sorted(out.glob(pattern))
        if len(found) != 1:
            sys.exit(f'make figures: {pattern} matched {len(found)} files in {out}, not one')
        shutil.copyfile(found[0], FIGURES / target)
        print(f'wrote {FIGURES / target}')
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m machine_alignment.figures',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='out/figures', help='where the runs are made')
    return make_figures(Path(parser.parse_args(argv).out).resolve())


if __name__ == '__main__':
    sys.exit(main())
