"""`make bench` (hexapod part): calibration accuracy on the simulated hexapod against the
paper, recovery of all 42 parameters, ISO 9283 style repeatability, identification time
against the number of poses and forward-kinematics speed. Writes ``<out>/hexapod.json``,
``<out>/hexapod.md`` and PNG plots. Simulation truth is used only to evaluate."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from calib_core.figures import save_figure  # noqa: E402
from hexapod_calib.core.calibration import PoseData, identify, pose_errors  # noqa: E402
from hexapod_calib.core.geometry import nominal_geometry  # noqa: E402
from hexapod_calib.core.kinematics import forward_kinematics, inverse_kinematics  # noqa: E402
from hexapod_calib.core.procedure import HexapodPlan, run_hexapod_calibration  # noqa: E402
from hexapod_calib.sim.hexapod import HexapodSim, HexapodTruth, PoseSensorSim  # noqa: E402
from machine_alignment.bench import write_results  # noqa: E402

PAPER = {'before_max_displacement_m': 0.35e-3, 'before_max_angle_rad': 0.0073,
         'after_max_displacement_m': 0.0121e-3, 'after_max_angle_rad': 0.0011}


def _box(rng, n, plan=HexapodPlan()):
    half = np.array(plan.translation + plan.rotation)
    return np.array(plan.home) + rng.uniform(-1, 1, (n, 6)) * half


def accuracy(seeds, num_poses, num_evaluation=100):
    """Calibration runs on differently built hexapods: before/after on separate poses."""
    nominal, rows = nominal_geometry(), []
    for seed in seeds:
        truth = HexapodTruth.default(nominal, seed)
        sim, sensor = HexapodSim(truth, nominal, seed=seed + 100), PoseSensorSim(seed=seed + 200)
        calibration = run_hexapod_calibration(
            HexapodPlan(num_poses=num_poses, num_evaluation=num_evaluation, seed=seed),
            nominal, sim.move_legs, lambda: sensor.measure(sim.pose))
        rows.append({'seed': seed, **calibration.report['evaluation']})
        if seed == seeds[0]:
            first = (truth, calibration)
    return rows, first


def recovery(truth, calibration):
    report = calibration.report['identification']
    nominal = nominal_geometry().parameters().as_dict()
    table = []
    for name, true_value in truth.geometry.parameters().as_dict().items():
        estimate, sigma = report['parameters'][name], report['std_devs'][name]
        table.append({'name': name, 'true_error_m': true_value - nominal[name],
                      'estimated_error_m': estimate - nominal[name], 'std_dev_m': sigma,
                      'z': (estimate - true_value) / sigma})
    return table


def repeatability(num_points=8, visits=30, seed=3):
    """ISO 9283 style: each point approached ``visits`` times from random other poses, the
    pose measured by the sensor. Per axis +-3 sigma and radial RP = mean(l) + 3 S_l (m)."""
    rng = np.random.default_rng(seed)
    nominal = nominal_geometry()
    sim, sensor = HexapodSim(HexapodTruth.default(nominal), nominal, seed=seed), PoseSensorSim(seed=seed)
    points, results = _box(rng, num_points), []
    for point in points:
        legs = inverse_kinematics(nominal, point)[0]
        measured = []
        for _ in range(visits):
            sim.move_legs(inverse_kinematics(nominal, _box(rng, 1))[0])
            sim.move_legs(legs)
            measured.append(sensor.measure(sim.pose))
        measured = np.array(measured)
        spread = measured[:, :3] - measured[:, :3].mean(0)
        distance = np.linalg.norm(spread, axis=1)
        _, angle = pose_errors(np.tile(measured.mean(0), (visits, 1)), measured)
        results.append({'x_m': float(3 * spread[:, 0].std(ddof=1)),
                        'y_m': float(3 * spread[:, 1].std(ddof=1)),
                        'z_m': float(3 * spread[:, 2].std(ddof=1)),
                        'radial_RP_m': float(distance.mean() + 3 * distance.std(ddof=1)),
                        'angle_RP_rad': float(angle.mean() + 3 * angle.std(ddof=1))})
    worst = {k: max(r[k] for r in results) for k in results[0]}
    return {'num_points': num_points, 'visits': visits, 'per_point': results, 'worst': worst}


def identification_time(counts=(13, 50, 200, 1000), repeats=3, seed=5):
    rng = np.random.default_rng(seed)
    nominal = nominal_geometry()
    truth = HexapodTruth.default(nominal).geometry
    rows = []
    for n in counts:
        poses = _box(rng, n)
        data = PoseData(poses, poses + rng.normal(0, 1e-6, poses.shape),
                        inverse_kinematics(truth, poses))
        identify(data, nominal)  # warm-up: the first call pays for imports and caches
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            identify(data, nominal)
            times.append(time.perf_counter() - start)
        rows.append({'num_poses': n, 'seconds': min(times)})
    slope = np.polyfit(np.log([r['num_poses'] for r in rows]), np.log([r['seconds'] for r in rows]), 1)[0]
    return rows, float(slope)


def forward_kinematics_rate(n=2000, seed=6):
    rng = np.random.default_rng(seed)
    geometry = nominal_geometry()
    poses = _box(rng, n)
    legs = inverse_kinematics(geometry, poses)
    start = time.perf_counter()
    forward_kinematics(geometry, legs)
    batched = n / (time.perf_counter() - start)
    start = time.perf_counter()
    for k in range(200):
        forward_kinematics(geometry, legs[k], initial=HexapodPlan().home)
    single = 200 / (time.perf_counter() - start)
    return {'batched_per_s': batched, 'one_at_a_time_per_s': single}


def plot_calibration(out: Path, rows: list, table: list) -> None:
    """Before and after on one (logarithmic) scale, counted in whole hexapods, and the
    identified parameters against truth in units of their sigma."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.4), gridspec_kw={'width_ratios': [1.1, 1]})
    before = [r['before']['max_displacement_m'] * 1e6 for r in rows]
    after = [r['after']['max_displacement_m'] * 1e6 for r in rows]
    bins = np.geomspace(min(after) * 0.9, max(before) * 1.1, 40)
    axes[0].hist(before, bins=bins, color='tab:red', alpha=0.7, label='before (nominal model)')
    axes[0].hist(after, bins=bins, color='tab:green', alpha=0.7, label='after (42 parameters)')
    axes[0].axvline(PAPER['after_max_displacement_m'] * 1e6, color='k', ls='--',
                    label='paper, after: 12.1 um')
    axes[0].set_xscale('log')
    axes[0].yaxis.set_major_locator(MaxNLocator(integer=True))
    axes[0].set_xlabel('max displacement error on 100 separate poses (um, log scale)')
    axes[0].set_ylabel(f'simulated hexapods (of {len(rows)})')
    axes[0].legend(fontsize=9)
    z = np.array([t['z'] for t in table])
    axes[1].bar(range(len(z)), z, color=np.where(np.abs(z) < 3, 'tab:blue', 'tab:red'))
    axes[1].axhline(3, color='k', ls='--')
    axes[1].axhline(-3, color='k', ls='--')
    axes[1].set_xlabel('parameter (leg 1 ... leg 6: offset, base xyz, platform xyz)')
    axes[1].set_ylabel('(estimate - truth) / sigma (1)')
    fig.suptitle('Hexapod calibration with 30 poses: accuracy over '
                 f'{len(rows)} simulated hexapods, and parameter recovery (seed 1)')
    fig.tight_layout()
    save_figure(fig, out / 'hexapod_calibration.png', [__file__], dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--out', default='bench_results')
    parser.add_argument('--seeds', type=int, default=20)
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(1, args.seeds + 1))
    results = {'paper': PAPER}
    for count in (13, 30):
        rows, first = accuracy(seeds, count)
        results[f'accuracy_{count}_poses'] = {
            'runs': rows,
            'worst_after_max_displacement_m': max(r['after']['max_displacement_m'] for r in rows),
            'worst_after_max_angle_rad': max(r['after']['max_angle_rad'] for r in rows),
            'median_before_max_displacement_m': float(np.median([r['before']['max_displacement_m'] for r in rows])),
            'median_before_max_angle_rad': float(np.median([r['before']['max_angle_rad'] for r in rows])),
            'median_after_max_displacement_m': float(np.median([r['after']['max_displacement_m'] for r in rows])),
            'median_after_rms_displacement_m': float(np.median([r['after']['rms_displacement_m'] for r in rows])),
            'median_after_max_angle_rad': float(np.median([r['after']['max_angle_rad'] for r in rows]))}
        if count == 30:
            table = recovery(*first)
            results['recovery_seed_1'] = {'table': table,
                                          'inside_3_sigma': float(np.mean([abs(t['z']) < 3 for t in table]))}
            plot_calibration(out, rows, table)
    results['repeatability'] = repeatability()
    rows, slope = identification_time()
    results['identification_time'] = {'rows': rows, 'growth_exponent': slope}
    results['forward_kinematics'] = forward_kinematics_rate()
    write_results(out, 'hexapod', results)
    (out / 'hexapod.md').write_text(markdown(results) + '\n')
    print(markdown(results))
    print(f'wrote {out}/hexapod.json, hexapod.md, hexapod_calibration.png')


def markdown(r) -> str:
    um, urad = 1e6, 1e6
    lines = ['### Hexapod calibration (simulated 6-SPS, 100 separate poses per run)', '',
             '| poses | hexapods | before max (median) | after max (median) | after max (worst) | after RMS (median) |',
             '|---|---|---|---|---|---|']
    for count in (13, 30):
        a = r[f'accuracy_{count}_poses']
        lines.append(f'| {count} | {len(a["runs"])} | '
                     f'{a["median_before_max_displacement_m"] * um:.0f} um / {a["median_before_max_angle_rad"] * urad:.0f} urad | '
                     f'{a["median_after_max_displacement_m"] * um:.1f} um / {a["median_after_max_angle_rad"] * urad:.0f} urad | '
                     f'{a["worst_after_max_displacement_m"] * um:.1f} um / {a["worst_after_max_angle_rad"] * urad:.0f} urad | '
                     f'{a["median_after_rms_displacement_m"] * um:.1f} um |')
    lines.append('| paper (13) | 1 | 350 um / 7300 urad | 12.1 um / 1100 urad | | |')
    rep = r['repeatability']['worst']
    lines += ['', f'Repeatability (ISO 9283 style, {r["repeatability"]["num_points"]} points x '
              f'{r["repeatability"]["visits"]} visits from random poses, worst point): '
              f'X {rep["x_m"] * um:.1f} um, Y {rep["y_m"] * um:.1f} um, Z {rep["z_m"] * um:.1f} um (+-3 sigma), '
              f'radial RP {rep["radial_RP_m"] * um:.1f} um, orientation RP {rep["angle_RP_rad"] * urad:.0f} urad.',
              '', f'Parameter recovery (30 poses, seed 1): {r["recovery_seed_1"]["inside_3_sigma"] * 100:.0f} % '
              'of the 42 true values inside 3 sigma of the estimate.', '',
              '| poses | identification time |', '|---|---|']
    for row in r['identification_time']['rows']:
        lines.append(f'| {row["num_poses"]} | {row["seconds"] * 1e3:.1f} ms |')
    fk = r['forward_kinematics']
    lines += ['', f'Time grows as poses^{r["identification_time"]["growth_exponent"]:.2f}. '
              f'Forward kinematics: {fk["batched_per_s"]:.0f} solves/s batched, '
              f'{fk["one_at_a_time_per_s"]:.0f} solves/s one at a time.']
    return '\n'.join(lines)


if __name__ == '__main__':
    main()
