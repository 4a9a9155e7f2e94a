"""Stage benchmark: the paper's alignment evaluation on the simulated stage, before
calibration, after the stepwise and after the parametric method, and the stage's ISO 9283
repeatability through the camera. Writes bench_results/stage.{json,md}."""
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from calib_core.figures import save_figure  # noqa: E402
from calib_core.storage import write_atomic  # noqa: E402
from machine_alignment.bench import main_with_out, write_results
from printer_alignment.core.stage import NOMINAL_STAGE
from printer_alignment.core.stage_calibration import ParametricModel, calibrate_stage
from printer_alignment.sim.stage import (
    evaluate_alignment, measure_repeatability, simulate_calibration_run)

ARCSEC = np.pi / 180 / 3600
PAPER_ORIENTATION = 0.720 * ARCSEC     # the paper's maximum after calibration, rad


def plot_alignment(path: Path, by_model: dict, rp_position: float, rp_angle: float) -> None:
    """Position and orientation error of every alignment, each model on one logarithmic
    scale, against the stage's repeatability RP and the paper's maxima."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.4))
    for ax, key, factor, unit, rp, paper in (
            (axes[0], 'position_m', 1e6, 'um', rp_position, 12.3e-6),
            (axes[1], 'orientation_rad', 1 / ARCSEC, 'arcsec', rp_angle, PAPER_ORIENTATION)):
        values = {name: r[key] * factor for name, r in by_model.items()}
        low = max(min(v[v > 0].min() for v in values.values()), 1e-3)
        bins = np.geomspace(low, max(v.max() for v in values.values()) * 1.1, 50)
        for (name, v), colour in zip(values.items(), ('tab:red', 'tab:orange', 'tab:green')):
            ax.hist(v, bins=bins, alpha=0.6, color=colour, label=f'{name}: max {v.max():.3g}')
        ax.axvline(rp * factor, color='k', ls='-', label=f'repeatability RP: {rp * factor:.3g}')
        ax.axvline(paper * factor, color='k', ls='--', label=f'paper, max: {paper * factor:.3g}')
        ax.set_xscale('log')
        ax.set_xlabel(f'{key.split("_")[0]} error after one move ({unit}, log scale)')
        ax.set_ylabel('alignments')
        ax.legend(fontsize=8)
    fig.suptitle(f'XY-Theta stage: {len(next(iter(values.values())))} alignments on the '
                 'simulated stage, error against truth')
    fig.tight_layout()
    save_figure(fig, path, [__file__], dpi=100)
    plt.close(fig)


def run(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    models, report = calibrate_stage(simulate_calibration_run(seed=1))
    models = {'before (nominal)': ParametricModel(NOMINAL_STAGE), **models}
    rows = {}
    for label, (poses, repeats) in {'8 poses x 5': (8, 5), '200 poses x 5': (200, 5)}.items():
        rows[label] = {name: evaluate_alignment(model, poses=poses, repeats=repeats, seed=0)
                       for name, model in models.items()}
    repeatability = measure_repeatability(cycles=30, seed=2)
    u, m, v = (repeatability[k] for k in ('unidirectional', 'multidirectional', 'variation'))
    # One move cannot beat the stage's own repeatability measured by the same camera: the
    # result is stated against it (the paper states 12.3 um and 0.720" as maxima).
    rp_position, rp_angle = u['RP_l_m'], u['RP_a_rad'][0]
    for by_model in rows.values():
        for r in by_model.values():
            r['position_max_over_RP_l'] = r['position_max_m'] / rp_position
            r['orientation_max_over_RP_a'] = r['orientation_max_rad'] / rp_angle
    plot_alignment(out / 'stage_alignment.png', rows['200 poses x 5'], rp_position, rp_angle)
    for by_model in rows.values():       # the per-alignment errors are in the figure only
        for r in by_model.values():
            del r['position_m'], r['orientation_rad']
    result = {'alignment': rows, 'repeatability': repeatability, 'calibration': report}
    write_results(Path(out), 'stage', result)
    lines = ['| poses | model | position max | position mean | orientation max | orientation mean '
             '| position max / RP_l | orientation max / RP_a |',
             '|---|---|---|---|---|---|---|---|']
    for label, by_model in rows.items():
        for name, r in by_model.items():
            lines.append(f'| {label} | {name} | {r["position_max_m"] * 1e6:.2f} um | '
                         f'{r["position_mean_m"] * 1e6:.2f} um | '
                         f'{r["orientation_max_rad"] / ARCSEC:.2f}" | '
                         f'{r["orientation_mean_rad"] / ARCSEC:.2f}" | '
                         f'{r["position_max_over_RP_l"]:.2f} | '
                         f'{r["orientation_max_over_RP_a"]:.2f} |')
    lines += ['', f'ISO 9283 repeatability (30 cycles, through the camera): unidirectional '
              f'RP_l {rp_position * 1e6:.2f} um, RP_a {rp_angle / ARCSEC:.2f}"; '
              f'three directions pooled RP_l {m["RP_l_m"] * 1e6:.2f} um; vAP '
              f'{v["vAP_m"] * 1e6:.2f} um. The paper\'s maxima after calibration: 12.3 um and '
              f'0.720" (its stage\'s repeatability: 3-6 um).']
    write_atomic(Path(out) / 'stage.md', '\n'.join(lines) + '\n')
    print('\n'.join(lines))


def main(argv=None) -> int:
    return main_with_out(run, __doc__, argv)


if __name__ == '__main__':
    raise SystemExit(main())
