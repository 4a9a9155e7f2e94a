"""Grid-plate self-calibration benchmark (issue 21): exactness of both solvers, the error
against the measurement noise over Monte-Carlo runs (perfect plate and a plate 20x worse
than the stage), the propagated uncertainty against the observed spread, error growth
with the number of stitched regions (joint against chained), and solve time and memory
for N = 11, 41, 101 marks a side against SuperLU on the whole constrained system (the
route before the bordered factor) in the same run.
Writes bench_results/grid.{json,md} and grid_stitching.png."""
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from grid_calib.core import selfcal  # noqa: E402
from grid_calib.core.bordered import factor_whole_kkt  # noqa: E402
from grid_calib.core.data import Region  # noqa: E402
from grid_calib.core.model import Grid, without_similarity  # noqa: E402
from grid_calib.core.reference import solve_by_differences  # noqa: E402
from grid_calib.core.selfcal import self_calibrate  # noqa: E402
from grid_calib.core.travel import calibrate_travel  # noqa: E402
from grid_calib.sim.plate import (  # noqa: E402
    default_travel, default_truth, measure_placements, measure_travel)
from machine_alignment.bench import main_with_out, write_results, write_table  # noqa: E402

GRID = Grid(5, 0.01)
SIGMA = 20e-9
BORDERED, WHOLE = 'bordered', 'whole KKT'


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def noise_free() -> dict:
    worst = {'global': 0.0, 'reference': 0.0}
    for seed in range(5):
        truth = default_truth(GRID, seed)
        placements = measure_placements(GRID, truth, 0.0, seed)
        g = truth.stage_error(GRID)
        for name, solve in (('global', self_calibrate), ('reference', solve_by_differences)):
            error = np.abs(solve(GRID, placements).stage_error - g).max() / np.abs(g).max()
            worst[name] = max(worst[name], float(error))
    return {'seeds': 5, 'max_error_over_max_G': worst}


def monte_carlo(runs: int, sigma: float, plate_error: float) -> dict:
    """RMS(G - true) / sigma per run for both solvers; the propagated 1-sigma per site over
    sigma (the uncertainty propagation ratio) and the observed spread per site."""
    ratios = {'global': [], 'reference': []}
    errors, gains = [], None
    for seed in range(runs):
        truth = default_truth(GRID, seed, plate_error=plate_error)
        placements = measure_placements(GRID, truth, sigma, seed)
        g = truth.stage_error(GRID)
        result = self_calibrate(GRID, placements)
        errors.append(result.stage_error - g)
        gains = result.noise_gain
        ratios['global'].append(_rms(result.stage_error - g) / sigma)
        ratios['reference'].append(_rms(solve_by_differences(GRID, placements).stage_error - g)
                                   / sigma)
        if (seed + 1) % 50 == 0:
            print(f'  Monte Carlo sigma {sigma * 1e9:g} nm, plate {plate_error * 1e6:g} um: '
                  f'{seed + 1}/{runs}', flush=True)
    spread = np.std(errors, axis=0)
    return {'runs': runs, 'sigma_m': sigma, 'plate_error_m': plate_error,
            'error_over_sigma': {k: {'mean': float(np.mean(v)), 'p95': float(np.percentile(v, 95)),
                                     'max': float(np.max(v))} for k, v in ratios.items()},
            'propagation_ratio_rms': _rms(gains),
            'observed_spread_over_propagated': float(np.mean(spread / (gains * sigma)))}


def stitching(layouts, seeds: int, sigma: float) -> list:
    rows = []
    for columns, count_rows in layouts:
        out = {'joint': [], 'chained': []}
        for seed in range(seeds):
            truth = default_travel(GRID, columns, count_rows, seed=seed)
            regions = {r: Region(truth.origins[r], p)
                       for r, p in measure_travel(GRID, truth, sigma, seed).items()}
            for method in out:
                calibration = calibrate_travel(GRID, regions, method)
                positions = calibration.stitched.site_positions
                g = without_similarity(positions, truth.error_at(positions))
                error = calibration.stitched.stage_error - g
                out[method].append((_rms(error), float(np.abs(error).max())))
        rows.append({'regions': f'{columns} x {count_rows}', 'count': columns * count_rows,
                     **{f'{m}_rms_over_sigma': float(np.mean([e[0] for e in v]) / sigma)
                        for m, v in out.items()},
                     **{f'{m}_max_over_sigma': float(np.mean([e[1] for e in v]) / sigma)
                        for m, v in out.items()}})
        print(f'  stitching {columns} x {count_rows}: joint {rows[-1]["joint_rms_over_sigma"]:.2f}, '
              f'chained {rows[-1]["chained_rms_over_sigma"]:.2f} sigma RMS', flush=True)
    return rows


def _timed_solve(half: int, factorisation: str, propagate: bool) -> dict:
    """In a fresh process: one noise-free solve (with or without the per-site uncertainty),
    its time and the process's peak memory before and after. ``factorisation``: 'bordered'
    (the suite's) or 'whole KKT' (SuperLU on the whole constrained system, the route before)."""
    if factorisation == 'whole KKT':
        selfcal.factor_kkt = factor_whole_kkt
    grid = Grid(half, 0.1 / half)
    truth = default_truth(grid, 1)
    placements = measure_placements(grid, truth, 0.0, 1)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.perf_counter()
    result = self_calibrate(grid, placements, propagate=propagate)
    seconds = time.perf_counter() - start
    g = truth.stage_error(grid)
    return {'N': 2 * half + 1, 'marks_x_placements': 3 * (2 * half + 1) ** 2,
            'factorisation': factorisation, 'uncertainty': propagate, 'seconds': seconds,
            'peak_memory_mib': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            'memory_before_solve_mib': before,
            'error_over_max_G': float(np.abs(result.stage_error - g).max() / np.abs(g).max())}


def timing() -> list:
    rows = []
    for half, factorisation, propagate in (
            (5, BORDERED, False), (5, WHOLE, False), (20, BORDERED, False), (20, WHOLE, False),
            (50, BORDERED, False), (50, WHOLE, False), (5, BORDERED, True), (20, BORDERED, True),
            (50, BORDERED, True)):
        with ProcessPoolExecutor(1, mp_context=get_context('spawn')) as pool:
            rows.append(pool.submit(_timed_solve, half, factorisation, propagate).result())
        print(f'  N = {rows[-1]["N"]} ({factorisation}, uncertainty {propagate}): '
              f'{rows[-1]["seconds"]:.2f} s, peak '
              f'{rows[-1]["peak_memory_mib"]:.0f} MiB', flush=True)
    return rows


def plot_stitching(path: Path, rows: list) -> None:
    """Error against the number of regions, joint and chained, for regions in one row and
    for square layouts (where chaining has loops to ignore), on one log scale."""
    fig, ax = plt.subplots(figsize=(7.5, 4.4))
    layouts = {'one row': [r for r in rows if r['regions'].endswith(' x 1')],
               'square': [r for r in rows if r['regions'].split(' x ')[0]
                          == r['regions'].split(' x ')[1]]}
    for (shape, group), marker in zip(layouts.items(), ('o', 's')):
        counts = [r['count'] for r in group]
        for method, colour in (('joint', 'C2'), ('chained', 'C3')):
            ax.plot(counts, [r[f'{method}_rms_over_sigma'] for r in group], marker + '-',
                    color=colour, label=f'{method}, {shape}: RMS')
            ax.plot(counts, [r[f'{method}_max_over_sigma'] for r in group], marker + ':',
                    color=colour, alpha=0.5, label=f'{method}, {shape}: max')
    ax.set_xlabel('regions stitched (one row: 1..5 x 1; square: 1 x 1 .. 4 x 4)')
    ax.set_ylabel('error of G against truth / noise sigma (1)')
    ax.set_yscale('log')
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f'Stitching, {2 * GRID.half + 1} x {2 * GRID.half + 1} plate per region, '
                 f'sigma {SIGMA * 1e9:g} nm, 10 seeds', loc='left', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    print('grid bench: noise-free exactness', flush=True)
    result = {'noise_free': noise_free()}
    print('grid bench: Monte Carlo (200 runs at 20 nm, perfect plate and 20x worse plate)',
          flush=True)
    result['monte_carlo'] = [monte_carlo(200, SIGMA, 1e-6), monte_carlo(200, SIGMA, 3e-6),
                             monte_carlo(200, SIGMA, 0.0), monte_carlo(50, 5e-9, 1e-6),
                             monte_carlo(50, 50e-9, 1e-6)]
    layouts = [(1, 1), (2, 1), (3, 1), (4, 1), (5, 1), (2, 2), (3, 3), (4, 4)]   # 1 x 1 is both
    result['stitching'] = stitching(layouts, 10, SIGMA)
    plot_stitching(out / 'grid_stitching.png', result['stitching'])
    print('grid bench: time and memory', flush=True)
    result['timing'] = timing()
    write_results(out, 'grid', result)
    lines = [f'Noise-free (5 seeds, N = 11): max |G - true| / max |G| = '
             f'{result["noise_free"]["max_error_over_max_G"]["global"]:.2g} (global solver), '
             f'{result["noise_free"]["max_error_over_max_G"]["reference"]:.2g} (reference '
             'solver).', '',
             '| runs | sigma | plate error (RMS) | RMS(G - true) / sigma, global: mean (p95) '
             '| reference: mean (p95) | propagation ratio u(G) / sigma | observed spread / '
             'propagated |', '|---|---|---|---|---|---|---|']
    for m in result['monte_carlo']:
        e = m['error_over_sigma']
        lines.append(f'| {m["runs"]} | {m["sigma_m"] * 1e9:g} nm | {m["plate_error_m"] * 1e6:g} um '
                     f'| {e["global"]["mean"]:.3f} ({e["global"]["p95"]:.3f}) | '
                     f'{e["reference"]["mean"]:.3f} ({e["reference"]["p95"]:.3f}) | '
                     f'{m["propagation_ratio_rms"]:.3f} | '
                     f'{m["observed_spread_over_propagated"]:.3f} |')
    lines += ['', '| regions | joint: RMS / sigma | joint: max / sigma | chained: RMS / sigma '
              '| chained: max / sigma |', '|---|---|---|---|---|']
    for r in result['stitching']:
        lines.append(f'| {r["regions"]} | {r["joint_rms_over_sigma"]:.2f} | '
                     f'{r["joint_max_over_sigma"]:.2f} | {r["chained_rms_over_sigma"]:.2f} | '
                     f'{r["chained_max_over_sigma"]:.2f} |')
    lines += ['', '| N | marks x placements | factorisation | per-site uncertainty | solve time '
              '| peak memory | before the solve | noise-free error / max G |',
              '|---|---|---|---|---|---|---|---|']
    for r in result['timing']:
        lines.append(f'| {r["N"]} | {r["marks_x_placements"]} | {r["factorisation"]} | '
                     f'{"yes" if r["uncertainty"] else "no"} | '
                     f'{r["seconds"]:.2f} s | {r["peak_memory_mib"]:.0f} MiB | '
                     f'{r["memory_before_solve_mib"]:.0f} MiB | {r["error_over_max_G"]:.2g} |')
    by = {(r['N'], r['factorisation']): r['seconds'] for r in result['timing']
          if not r['uncertainty']}
    lines += ['', 'Solve time of SuperLU on the whole constrained system over the bordered '
              'factor used (grid_calib/core/bordered.py), same run: '
              + ', '.join(f'N = {n}: {by[(n, WHOLE)] / by[(n, BORDERED)]:.1f}x'
                          for n in (11, 41, 101)) + '.']
    write_table(out, 'grid', lines)


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    main()
