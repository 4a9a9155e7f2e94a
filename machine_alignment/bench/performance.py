"""How long each job takes and how much memory, and how that grows with its size (issue
34): every job at two sizes, each in a fresh process (its own peak resident memory), the
growth as the exponent of time against size. Detection's own table against OpenCV is
bench_results/results.md; the closed loop's, bench_results/closed_loop_speed.md; the
grid's against the source's route, bench_results/grid.md. Writes
bench_results/performance.{md,json}."""
import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from machine_alignment.bench import write_results, write_table


def _hexapod(size: int):
    from hexapod_calib.core.calibration import identify
    from hexapod_calib.core.geometry import nominal_geometry
    from hexapod_calib.sim.hexapod import HexapodTruth, measure_random_poses
    data, _ = measure_random_poses(HexapodTruth.default(), size, seed=1)
    return lambda: identify(data, nominal_geometry())


def _platform(size: int):
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.identification import identify
    from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
    data = measure_poses(PlatformSim(true_geometry(0)), plan_poses(size, 0), nominal_geometry())
    return lambda: identify(data, nominal_geometry())


def _compensation(size: int):
    from platform_calib.core.compensation import PSOSettings, compensate
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.sim.platform import plan_poses, true_geometry
    targets = plan_poses(size, 1)
    model, nominal = true_geometry(0), nominal_geometry()
    return lambda: [compensate(model, nominal, t, 'pso', pso=PSOSettings.stable())
                    for t in targets]


def _plan(size: int):
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.planning import plan_platform
    return lambda: plan_platform(nominal_geometry(), 12, candidates=size)


def _grid(size: int):
    from grid_calib.core.model import Grid
    from grid_calib.core.travel import calibrate_travel
    from grid_calib.sim.plate import default_travel, measure_travel
    half = (size - 1) // 2
    grid = Grid(half, 0.01 * 5 / half)           # a 100 mm plate whatever N
    truth = default_travel(grid, 1, 1, seed=1)
    from grid_calib.core.data import Region
    regions = {r: Region(truth.origins[r], p)
               for r, p in measure_travel(grid, truth, 20e-9, 1).items()}
    return lambda: calibrate_travel(grid, regions)


def _five_axis(size: int):
    from dispenser_calib.core.calibration import calibrate
    from dispenser_calib.core.model import nominal_model
    from dispenser_calib.core.procedure import evaluation_stops, plan_stops
    from dispenser_calib.sim.machine import IMAGE_SIZE, observe, true_model
    stops = np.vstack([plan_stops(nominal_model(), 0),
                       evaluation_stops(nominal_model(), max(size - 27, 0), 5)])[:size]
    images, _ = observe(true_model(0), stops, seed=1)
    return lambda: calibrate(images, IMAGE_SIZE)


def _stage(size: int):
    """The paper's 130-stop run (its plan fixes the size)."""
    from printer_alignment.core.stage_calibration import calibrate_stage
    from printer_alignment.sim.stage import simulate_calibration_run
    data = simulate_calibration_run(seed=1)
    return lambda: calibrate_stage(data)


def _platform_loop(size: int):
    from calib_core.closed_loop import analyze
    from platform_calib.core.geometry import nominal_geometry
    from platform_calib.core.loop_model import PlatformLoopModel
    from platform_calib.sim.platform import PlatformSim, measure_poses, plan_poses, true_geometry
    sim = PlatformSim(true_geometry(0), screw_amplitude=(0.0, 10e-6, 0.0))
    data = measure_poses(sim, plan_poses(size, 0), nominal_geometry())
    return lambda: analyze(PlatformLoopModel(data, nominal_geometry()))


# job -> (what, size unit, the two sizes, the function building the job at a size)
JOBS = {
    'hexapod identification': ('42 parameters', 'poses', (13, 200), _hexapod),
    'platform identification': ('18 parameters', 'poses', (20, 200), _platform),
    'platform compensation, stable swarm': ('per batch of targets', 'targets', (2, 8),
                                            _compensation),
    'platform plan (12 poses, I-optimal)': ('exchange over candidates', 'candidates',
                                            (1000, 4000), _plan),
    'grid self-calibration, one region': ('3 placements, per-site uncertainty (to N = 41)',
                                          'marks a side (N)', (11, 41), _grid),
    'five-axis calibration (RANSAC)': ('31 parameters', 'images', (27, 60), _five_axis),
    'stage calibration (stepwise + parametric)': ('the paper\'s plan', 'stops', (130,), _stage),
    'closed loop, platform': ('screw error on feed 2', 'poses', (100, 200), _platform_loop),
}


def measure(job: str, size: int) -> dict:
    """In this process: build the job at ``size``, then time it; peak resident memory
    before and after (MiB)."""
    work = JOBS[job][3](size)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start, cpu = time.perf_counter(), time.process_time()
    work()
    return {'seconds': time.perf_counter() - start, 'cpu_seconds': time.process_time() - cpu,
            'peak_mib_before': before,
            'peak_mib': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def run(out: Path) -> list:
    rows = []
    for job, (what, unit, sizes, _) in JOBS.items():
        results = []
        for size in sorted(set(sizes)):
            done = subprocess.run([sys.executable, '-m', 'machine_alignment.bench.performance',
                                   '--job', job, '--size', str(size)],
                                  capture_output=True, text=True, check=True)
            results.append({'size': size, **json.loads(done.stdout.strip().splitlines()[-1])})
            print(f'{job} at {size} {unit}: {results[-1]["seconds"]:.3f} s, peak '
                  f'{results[-1]["peak_mib"]:.0f} MiB', flush=True)
        growth = None
        if len(results) == 2 and results[0]['seconds'] > 0:
            growth = float(np.log(results[1]['seconds'] / results[0]['seconds'])
                           / np.log(results[1]['size'] / results[0]['size']))
        rows.append({'job': job, 'what': what, 'unit': unit, 'results': results,
                     'growth_exponent': growth})
    lines = ['Each job at two sizes, each in a fresh process on this 2-core machine; time of the '
             'job alone (wall), peak resident memory of the process (in brackets: before the job, '
             'the imports and the data); growth: the exponent of time against size.', '',
             '| job | what | size | time | peak memory (before the job) | growth |',
             '|---|---|---|---|---|---|']
    for row in rows:
        for k, r in enumerate(row['results']):
            growth = (f't ~ size^{row["growth_exponent"]:.2f}'
                      if k == 0 and row['growth_exponent'] is not None else '')
            lines.append(f'| {row["job"] if k == 0 else ""} | {row["what"] if k == 0 else ""} | '
                         f'{r["size"]} {row["unit"]} | {r["seconds"]:.3g} s | '
                         f'{r["peak_mib"]:.0f} MiB ({r["peak_mib_before"]:.0f}) | {growth} |')
    lines += ['', 'Elsewhere: Mark detection against OpenCV\'s blob detector '
              '(`results.md`), the closed loop of every machine against full fits '
              '(`closed_loop_speed.md`), the grid solver up to N = 101 against the source\'s '
              'route (`grid.md`).']
    write_results(out, 'performance', rows)
    write_table(out, 'performance', lines)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--out', default='bench_results', help='folder for the results files')
    parser.add_argument('--job', choices=sorted(JOBS), help='(internal) one job, one size')
    parser.add_argument('--size', type=int)
    args = parser.parse_args(argv)
    if args.job:
        print(json.dumps(measure(args.job, args.size)))
    else:
        run(Path(args.out))
    return 0


if __name__ == '__main__':
    main()
