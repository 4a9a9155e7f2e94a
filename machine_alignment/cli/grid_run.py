"""The work of the subcommands ``grid.py`` registers (its docstring says what they do),
imported only when one of them runs, so that their parsers and ``--help`` stay light."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from calib_core.bags import decode_bag  # noqa: E402
from calib_core.errors import MachineAlignmentError  # noqa: E402
from calib_core.figures import arrow_key  # noqa: E402
from grid_calib.core.data import read_marks  # noqa: E402
from grid_calib.core.description import read_description  # noqa: E402
from grid_calib.core.records import (  # noqa: E402
    PLACEMENT_TOPIC, READINGS_TOPIC, RESULT_TOPIC, grid_from_placements, regions_from_readings)
from grid_calib.core.reference_map import write_reference  # noqa: E402
from grid_calib.core.travel import calibrate_travel  # noqa: E402
from machine_alignment.cli.common import (  # noqa: E402
    bag_temperature_log, read_in_si, read_run, write_report)


def _vectors(ax, where_mm, vectors_m, spacing_mm, title):
    um = vectors_m * 1e6
    longest = max(np.linalg.norm(um, axis=1).max(), 1e-9)
    arrows = ax.quiver(where_mm[:, 0], where_mm[:, 1], um[:, 0], um[:, 1], angles='xy',
                       scale_units='xy', scale=longest / (0.8 * spacing_mm))
    arrow_key(ax, arrows, longest / 2, 'um', 'above')     # a panel lies below
    ax.set_title(f'{title} (longest {longest:.3g} um)', loc='left', fontsize=10)
    ax.set_xlabel('x (mm)')
    ax.set_ylabel('y (mm)')
    ax.set_aspect('equal')


def _plot(path: Path, calibration) -> None:
    """Stage error and plate error vectors (each with its key), residuals per placement
    over all regions, and the per-site 1-sigma uncertainty of G."""
    grid, stitched = calibration.grid, calibration.stitched
    pitch_mm = grid.pitch * 1e3
    fig, axes = plt.subplots(2, 2, figsize=(12, 10.5))
    _vectors(axes[0, 0], stitched.site_positions * 1e3, stitched.stage_error, pitch_mm,
             f'stage error G, {len(calibration.results)} region(s), {stitched.method}')
    _vectors(axes[0, 1], grid.marks * grid.pitch * 1e3, calibration.plate_errors, pitch_mm,
             'plate mark errors A')
    for name in calibration.results[min(calibration.results)].residuals:
        nm = np.concatenate([np.linalg.norm(r.residuals[name], axis=1)
                             for r in calibration.results.values()]) * 1e9
        axes[1, 0].hist(nm, bins=30, alpha=0.6, label=name)
    axes[1, 0].set_xlabel('residual per mark (nm)')
    axes[1, 0].set_ylabel('marks (all regions)')
    axes[1, 0].legend(title='placement')
    ax = axes[1, 1]
    stitched = calibration.stitched
    if stitched.uncertainty is not None:
        xy = stitched.site_positions * 1e3
        dots = ax.scatter(xy[:, 0], xy[:, 1], s=12, cmap='viridis',
                          c=np.linalg.norm(stitched.uncertainty, axis=1) * 1e9)
        fig.colorbar(dots, ax=ax, label='1-sigma of G per site, |(sx, sy)| (nm)')
        ax.set_title('uncertainty of G through the stitching', loc='left', fontsize=10)
    else:
        ax.text(0.5, 0.5, 'uncertainty not propagated', ha='center', transform=ax.transAxes)
    ax.set_xlabel('x (mm)')
    ax.set_ylabel('y (mm)')
    ax.set_aspect('equal')
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def grid_run(bag):
    """The grid and regions of a run recorded by grid_calibrator (each reading with its
    time and, where the run logged one, its temperature), the regions a cut run left
    incomplete named, and the live run's report (None if it ended without one)."""
    readings, recorded = read_run(bag, READINGS_TOPIC, 'alignment_msgs/msg/GridMarkReading',
                                  lambda msg: msg, 'grid mark readings', RESULT_TOPIC)
    grid = grid_from_placements([m for _, _, m in decode_bag(bag, [PLACEMENT_TOPIC])])
    regions, left_out = regions_from_readings(grid, readings, bag_temperature_log(bag))
    for line in left_out:
        print(line)
    if not regions:
        raise MachineAlignmentError(f'{bag}: no region was measured completely; nothing to '
                                    'solve')
    return grid, regions, recorded


def cmd_calibrate_grid(args) -> int:
    recorded = None
    described = read_description(args.description) if args.description else None
    if args.bag:
        grid, regions, recorded = grid_run(args.bag)
    elif described:
        grid, regions = described.read(args.data)
    else:
        if args.pitch is None:
            raise MachineAlignmentError('--data needs --pitch (the plate\'s nominal pitch, m) '
                                        'or --description')
        grid, regions = read_in_si(read_marks, args.data, args.pitch, actuators=('x', 'y'))
    certified = (args.certified_pitch if args.certified_pitch is not None
                 else described.certified_pitch if described else None)
    calibration = calibrate_travel(grid, regions, args.stitch, certified, described)
    report = calibration.report()
    if described:
        report['description'] = described.gate_report()
        print(f'  machine description {described.source}: {described.expected_text()}; '
              f'readings in {described.measurement.actuators.unit}')
    stitched = calibration.stitched
    print(f'{len(stitched.sites)} sites from {len(regions)} region(s) of a '
          f'{2 * grid.half + 1} x {2 * grid.half + 1} plate, pitch {grid.pitch * 1e3:g} mm; '
          f'non-orthogonality {report["non_orthogonality_rad"] * 1e6:.3f} urad, x/y scale '
          f'difference {report["scale_difference"] * 1e6:.3f} ppm over the travel')
    print(f'  stage error G: RMS {np.sqrt(np.mean(stitched.stage_error ** 2)) * 1e6:.3f} um, '
          f'max {np.abs(stitched.stage_error).max() * 1e6:.3f} um; plate errors A: RMS '
          f'{np.sqrt(np.mean(calibration.plate_errors ** 2)) * 1e6:.3f} um')
    for r, result in calibration.results.items():
        rms = ', '.join(f'{k} {v * 1e9:.2f}' for k, v in report['regions'][str(r)]
                        ['residual_rms_m'].items())
        sigma = ('not propagated' if result.uncertainty is None else
                 f'up to {result.uncertainty.max() * 1e9:.2f} nm ({result.uncertainty_method})')
        print(f'  region {r} at {tuple(calibration.origins[r])} pitches: residual RMS (nm) '
              f'{rms}; noise {result.noise * 1e9:.2f} nm; 1-sigma of G {sigma}')
    if stitched.overlap_rms is not None:
        print(f'  stitched ({stitched.method}): regions disagree at shared sites by '
              f'{stitched.overlap_rms * 1e9:.2f} nm RMS')
    if stitched.uncertainty is not None:
        print(f'  1-sigma of the stitched G: median {np.median(stitched.uncertainty) * 1e9:.2f} '
              f'nm, up to {stitched.uncertainty.max() * 1e9:.2f} nm (each region\'s noise '
              f'drawn through the stitching)')
    print('  isotropic scale: ' + ('undetermined without an external length (0 in G; '
                                   'give --certified-pitch)'
                                   if calibration.isotropic_scale is None else
                                   f'{calibration.isotropic_scale * 1e6:.4f} ppm from the '
                                   'certified pitch'))
    if recorded is not None:
        live = np.array([[p['error_x'], p['error_y']] for p in recorded['sites']])
        if live.shape == stitched.stage_error.shape:
            report['max_difference_to_live_m'] = float(np.abs(live - stitched.stage_error).max())
            print(f'  same as the live run: max |G difference| '
                  f'{report["max_difference_to_live_m"]:.3g} m')
    write_report(args.json, report, lambda png: _plot(png, calibration))
    if args.json:
        table = Path(args.json).with_name(Path(args.json).stem + '_map.csv')
        write_reference(table, stitched.site_positions, stitched.stage_error,
                        stitched.uncertainty)
        print(f'wrote {table} (x, y, error_x, error_y, sigma_x, sigma_y in m: the stage error '
              f'map per site; a reading minus the error there is the true position)')
    return 0
