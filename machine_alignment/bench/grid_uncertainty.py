"""`make bench` part: the grid's per-site uncertainty at full size and through the
stitching (issue 34). Writes bench_results/grid_uncertainty.{json,md}.

- Time and peak memory of one region's solve with and without the per-site sigma, each in
  a fresh process: N = 41 with the exact propagation (the baseline: one solve per site and
  component) and with the sampled one (noise drawn through the solve), N = 101 sampled
  (the exact route would take minutes); the sampled sigmas against the exact ones at
  N = 41.
- The stitched map's sigma against the spread of 200 repeated runs (3 x 2 regions of 7 x 7
  sites, 20 nm), joint and chained stitching."""
from __future__ import annotations

import resource
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from grid_calib.core import selfcal
from grid_calib.core.data import Region
from grid_calib.core.model import Grid
from grid_calib.core.selfcal import self_calibrate
from grid_calib.core.travel import calibrate_travel
from grid_calib.sim.plate import default_travel, default_truth, measure_placements, measure_travel
from machine_alignment.bench import main_with_out, write_results, write_table

SIGMA = 20e-9
MONTE_CARLO_RUNS = 200


def _timed(half: int, route: str) -> dict:
    """In a fresh process: one region's solve (``route``: 'none', 'exact' or 'sampled'),
    its time, the process's peak memory, and the sigmas."""
    grid = Grid(half, 0.1 / half)
    placements = measure_placements(grid, default_truth(grid, 1), SIGMA, 1)
    # Each route forced, whatever the default threshold picks at this size.
    selfcal.MAX_PROPAGATED = {'exact': np.inf, 'sampled': 0}.get(route, selfcal.MAX_PROPAGATED)
    start = time.perf_counter()
    result = self_calibrate(grid, placements, propagate=route != 'none')
    seconds = time.perf_counter() - start
    return {'N': 2 * half + 1, 'route': route, 'seconds': seconds,
            'peak_memory_mib': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            'method': result.uncertainty_method,
            'sigma': None if result.noise_gain is None else result.noise_gain.tolist()}


def timing() -> list:
    rows = []
    for half, route in ((20, 'none'), (20, 'exact'), (20, 'sampled'), (50, 'none'),
                        (50, 'sampled')):
        with ProcessPoolExecutor(1, mp_context=get_context('spawn')) as pool:
            rows.append(pool.submit(_timed, half, route).result())
        print(f'  N = {rows[-1]["N"]}, sigma {route}: {rows[-1]["seconds"]:.2f} s, peak '
              f'{rows[-1]["peak_memory_mib"]:.0f} MiB', flush=True)
    return rows


def stitched_against_monte_carlo(method: str) -> dict:
    grid = Grid(half=3, pitch=0.01)
    truth = default_travel(grid, 3, 2, seed=3)

    def run(seed):
        return calibrate_travel(grid, {r: Region(truth.origins[r], p) for r, p in measure_travel(
            grid, truth, SIGMA, seed).items()}, method)
    start = time.perf_counter()
    first = run(0)
    seconds = time.perf_counter() - start
    predicted = np.mean([run(seed).stitched.uncertainty for seed in range(8)], axis=0)
    spread = np.std([run(100 + seed).stitched.stage_error for seed in range(MONTE_CARLO_RUNS)],
                    axis=0)
    ratio = spread / predicted
    print(f'  stitched ({method}): spread / predicted median {np.median(ratio):.3f}', flush=True)
    return {'method': method, 'sites': len(predicted), 'runs': MONTE_CARLO_RUNS,
            'median_ratio': float(np.median(ratio)),
            'ratio_5_95': [float(q) for q in np.quantile(ratio, [0.05, 0.95])],
            'predicted_median_m': float(np.median(predicted)),
            'predicted_max_m': float(predicted.max()),
            'one_region_median_m': float(np.median([r.uncertainty for r in first.results.values()])),
            'seconds_per_calibration': seconds}


def run(out: Path) -> dict:
    print('grid uncertainty bench: time and memory', flush=True)
    rows = timing()
    exact = np.array(next(r['sigma'] for r in rows if r['N'] == 41 and r['route'] == 'exact'))
    sampled = np.array(next(r['sigma'] for r in rows if r['N'] == 41 and r['route'] == 'sampled'))
    agreement = sampled / exact
    print('grid uncertainty bench: stitched sigma against Monte Carlo', flush=True)
    stitched = [stitched_against_monte_carlo(m) for m in ('joint', 'chained')]
    results = {'timing': [{k: v for k, v in r.items() if k != 'sigma'} for r in rows],
               'sampled_over_exact_n41': {'median': float(np.median(agreement)),
                                          'min': float(agreement.min()),
                                          'max': float(agreement.max())},
               'stitched': stitched}
    write_results(out, 'grid_uncertainty', results)
    base = {r['N']: r['seconds'] for r in rows if r['route'] == 'none'}
    lines = [f'One region, {SIGMA * 1e9:g} nm noise, each row in a fresh process (time of the '
             'solve with the per-site sigma; the ratio to the solve without it, same run).', '',
             '| N | sigma per site | time | x the solve alone | peak memory |',
             '|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["N"]} | {r["route"]} | {r["seconds"]:.2f} s | '
                     f'{r["seconds"] / base[r["N"]]:.1f} | {r["peak_memory_mib"]:.0f} MiB |')
    lines += ['', f'Sampled over exact sigma at N = 41, per site and component: median '
                  f'{np.median(agreement):.3f}, range {agreement.min():.2f} to '
                  f'{agreement.max():.2f}.', '',
              f'Stitched map (3 x 2 regions of 7 x 7 sites): predicted sigma (mean over 8 '
              f'datasets) against the spread of {MONTE_CARLO_RUNS} repeated runs.', '',
              '| stitching | sites | spread / predicted, median | 5 % to 95 % of sites | '
              'predicted median | predicted max | one region alone, median |',
              '|---|---|---|---|---|---|---|']
    for s in stitched:
        lines.append(f'| {s["method"]} | {s["sites"]} | {s["median_ratio"]:.3f} | '
                     f'{s["ratio_5_95"][0]:.2f} to {s["ratio_5_95"][1]:.2f} | '
                     f'{s["predicted_median_m"] * 1e9:.1f} nm | '
                     f'{s["predicted_max_m"] * 1e9:.1f} nm | '
                     f'{s["one_region_median_m"] * 1e9:.1f} nm |')
    write_table(out, 'grid_uncertainty', lines)
    return results


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
